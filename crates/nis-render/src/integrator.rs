//! Unidirectional path tracing with next-event estimation, BSDF (or guided) sampling, multiple
//! importance sampling and Russian roulette.
//!
//! This is the standard estimator of Kajiya's rendering equation as described by Veach (thesis,
//! 1997, ch. 9) and Pharr et al. (*PBR* 4th ed., §13.4): at every non-delta vertex one light
//! sample and one BSDF sample are taken and weighted with the power heuristic. Depth counting,
//! `max_depth` and `rr_depth` follow Mitsuba 3's `path` integrator: `max_depth = 1` shows only
//! directly visible emitters, `2` adds direct lighting, `-1` is unbounded; Russian roulette
//! continues with probability `min(max(throughput · η²), 0.95)` once `rr_depth` bounces are done.
//! [`Strategy::Nee`] and [`Strategy::Bsdf`] switch one of the two techniques off; all three are
//! unbiased estimators of the same image, which the tests check.

use glam::{Vec2, Vec3};
use rand::RngCore;
use rand_pcg::Pcg32;

use crate::geometry::{offset_origin, Frame, Ray, Rgb, RAY_EPSILON};
use crate::guiding::{Guide, GuideRecord, GuideVertex};
use crate::sampling::power_heuristic;
use crate::scene::{Scene, NO_LIGHT};

/// Which techniques estimate the light arriving at a vertex.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Strategy {
    /// Light sampling and BSDF sampling combined by the power heuristic.
    #[default]
    Mis,
    /// Light sampling only (emitters hit by BSDF samples count only after delta bounces).
    Nee,
    /// BSDF sampling only (no shadow rays).
    Bsdf,
}

/// Path-tracing parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Integrator {
    /// Longest path in segments, camera segment included; `-1` is unbounded.
    pub max_depth: i32,
    /// Bounces after which Russian roulette may end a path.
    pub rr_depth: u32,
    /// Hide directly visible emitters.
    pub hide_emitters: bool,
    /// Estimation techniques.
    pub strategy: Strategy,
}

/// Counters a render thread keeps.
#[derive(Clone, Copy, Debug, Default)]
pub struct PathStats {
    /// Closest-hit rays traced.
    pub rays: u64,
    /// Shadow rays traced.
    pub shadow_rays: u64,
    /// Camera paths (samples) traced.
    pub paths: u64,
    /// Samples dropped because they were NaN or infinite.
    pub invalid: u64,
}

impl PathStats {
    /// Add another thread's counters.
    pub fn merge(&mut self, o: &PathStats) {
        self.rays += o.rays;
        self.shadow_rays += o.shadow_rays;
        self.paths += o.paths;
        self.invalid += o.invalid;
    }
}

/// A uniform number in `[0, 1)` with 24 random bits.
#[inline]
pub fn uniform(rng: &mut Pcg32) -> f32 {
    (rng.next_u32() >> 8) as f32 * (1.0 / 16_777_216.0)
}

#[inline]
fn uniform2(rng: &mut Pcg32) -> Vec2 {
    Vec2::new(uniform(rng), uniform(rng))
}

/// A vertex kept while a path is traced so that guides can learn from it afterwards.
struct PendingRecord {
    record: GuideRecord,
    /// Path throughput after scattering at this vertex.
    throughput: Rgb,
}

/// Credit `contribution` (already multiplied by the path throughput) to every pending vertex
/// in `pending`, as radiance arriving along its sampled direction.
fn credit(pending: &mut [PendingRecord], contribution: Rgb) {
    for v in pending {
        let t = v.throughput;
        let safe = |c: f32, t: f32| if t > 0.0 { c / t } else { 0.0 };
        v.record.radiance += Rgb::new(
            safe(contribution.x, t.x),
            safe(contribution.y, t.y),
            safe(contribution.z, t.z),
        );
    }
}

/// A path being traced.
struct PathState {
    ray: Ray,
    l: Rgb,
    beta: Rgb,
    eta: f32,
    prev_pdf: f32,
    prev_delta: bool,
    /// The previous vertex itself (not the offset ray origin), for light densities that must
    /// match the ones next-event estimation computed there.
    prev_p: Vec3,
    depth: u32,
    alive: bool,
    pending: Vec<PendingRecord>,
}

impl PathState {
    fn new(ray: Ray) -> Self {
        PathState {
            ray,
            l: Rgb::ZERO,
            beta: Rgb::ONE,
            eta: 1.0,
            prev_pdf: 0.0,
            prev_delta: true,
            prev_p: ray.origin,
            depth: 0,
            alive: true,
            pending: Vec::new(),
        }
    }

    /// Add a contribution (already multiplied by the throughput) to the estimate and credit it
    /// to the vertices waiting for training data.
    fn add(&mut self, c: Rgb) {
        self.l += c;
        credit(&mut self.pending, c);
    }
}

/// One scattering vertex of one path during a wavefront step.
struct Bounce {
    path: usize,
    hit: crate::scene::SurfaceHit,
    frame: Frame,
    wo: Vec3,
    vertex: GuideVertex,
    /// Selection probability of the guide here.
    alpha: f32,
    /// An unoccluded light sample: (direction, light pdf, radiance, BSDF value, BSDF pdf).
    nee: Option<(Vec3, f32, Rgb, Rgb, f32)>,
    /// Index of the guide-density query for the light sample's direction.
    nee_query: Option<usize>,
    technique: Technique,
}

/// How a vertex continues its path.
enum Technique {
    /// Not decided yet.
    Pending,
    /// A direction from the guide: the index of its sample query.
    Guide(usize),
    /// The BSDF's sample (`None`: it drew nothing), and the index of the guide-density query of
    /// its direction (`None` when the guide is off here or the sample is a delta).
    Bsdf(Option<crate::bsdf::BsdfSample>, Option<usize>),
}

/// The guide queries of one wavefront step, answered in one batch call each.
#[derive(Default)]
struct Queries {
    pdf_vertices: Vec<GuideVertex>,
    pdf_directions: Vec<Vec3>,
    pdfs: Vec<f32>,
    sample_vertices: Vec<GuideVertex>,
    sample_u: Vec<Vec2>,
    samples: Vec<Option<(Vec3, f32)>>,
}

impl Queries {
    fn clear(&mut self) {
        self.pdf_vertices.clear();
        self.pdf_directions.clear();
        self.sample_vertices.clear();
        self.sample_u.clear();
    }

    /// Queue the guide's density of `wi` at `vertex`; returns the query's index.
    fn pdf(&mut self, vertex: GuideVertex, wi: Vec3) -> usize {
        self.pdf_vertices.push(vertex);
        self.pdf_directions.push(wi);
        self.pdf_vertices.len() - 1
    }

    /// Queue a guide sample at `vertex` from `u`; returns the query's index.
    fn sample(&mut self, vertex: GuideVertex, u: Vec2) -> usize {
        self.sample_vertices.push(vertex);
        self.sample_u.push(u);
        self.sample_vertices.len() - 1
    }

    /// Answer all queued queries.
    fn run<G: Guide + ?Sized>(&mut self, guide: &G) {
        self.pdfs.clear();
        self.pdfs.resize(self.pdf_vertices.len(), 0.0);
        if !self.pdfs.is_empty() {
            guide.pdf_batch(&self.pdf_vertices, &self.pdf_directions, &mut self.pdfs);
        }
        self.samples.clear();
        self.samples.resize(self.sample_vertices.len(), None);
        if !self.samples.is_empty() {
            guide.sample_batch(&self.sample_vertices, &self.sample_u, &mut self.samples);
        }
    }
}

impl Integrator {
    /// The settings a scene was described with, estimated by `strategy`.
    pub fn from_scene(scene: &Scene, strategy: Strategy) -> Self {
        Integrator {
            max_depth: scene.settings.max_depth,
            rr_depth: scene.settings.rr_depth,
            hide_emitters: scene.settings.hide_emitters,
            strategy,
        }
    }

    /// One-sample estimate of the radiance arriving along `ray`. When `records` is given, the
    /// path's vertices are appended to it as guide training data.
    pub fn radiance<G: Guide + ?Sized>(
        &self,
        scene: &Scene,
        ray: Ray,
        rng: &mut Pcg32,
        guide: &G,
        stats: &mut PathStats,
        records: Option<&mut Vec<GuideRecord>>,
    ) -> Rgb {
        let mut out = [Rgb::ZERO];
        self.trace(
            scene,
            &[ray],
            std::slice::from_mut(rng),
            guide,
            stats,
            records,
            &mut out,
        );
        out[0]
    }

    /// One-sample radiance estimates of a batch of camera rays, traced as a wavefront: all
    /// live paths advance one bounce at a time, so the guide is queried in batches (one call
    /// per bounce for selection probabilities, one for directions and one for densities).
    /// Path `i` draws its random numbers from `rngs[i]` in the same order as a path traced
    /// alone, so the result of a path does not depend on the batch it is traced in. Records
    /// of finished paths are appended path by path, in batch order.
    #[allow(clippy::too_many_arguments)]
    pub fn trace<G: Guide + ?Sized>(
        &self,
        scene: &Scene,
        rays: &[Ray],
        rngs: &mut [Pcg32],
        guide: &G,
        stats: &mut PathStats,
        mut records: Option<&mut Vec<GuideRecord>>,
        out: &mut [Rgb],
    ) {
        assert!(rays.len() == rngs.len() && rays.len() == out.len());
        let want_records = records.is_some();
        let mut paths: Vec<PathState> = rays.iter().map(|&r| PathState::new(r)).collect();
        let mut live: Vec<usize> = (0..paths.len()).collect();
        let lights = &scene.lights;
        let mut vertices: Vec<Bounce> = Vec::new();
        let mut guide_vertices: Vec<GuideVertex> = Vec::new();
        let mut materials: Vec<&crate::bsdf::Material> = Vec::new();
        let mut alphas: Vec<f32> = Vec::new();
        let mut queries = Queries::default();
        while !live.is_empty() {
            // 1. Intersect, collect emission, and set up the vertices that scatter.
            vertices.clear();
            for &i in &live {
                let path = &mut paths[i];
                stats.rays += 1;
                let ray = path.ray;
                let Some(hit) = scene.intersect(&ray, f32::INFINITY) else {
                    if let Some(env) = lights.environment {
                        if !(path.depth == 0 && self.hide_emitters) {
                            let w = self.emitter_weight(
                                path.prev_delta,
                                path.prev_pdf,
                                lights.pdf_environment(),
                            );
                            path.add(path.beta * env * w);
                        }
                    }
                    path.alive = false;
                    continue;
                };
                let wo_world = -ray.dir;
                if hit.light != NO_LIGHT && !(path.depth == 0 && self.hide_emitters) {
                    let cos_light = hit.ns.dot(wo_world);
                    if cos_light > 0.0 {
                        let light = &lights.area[hit.light as usize];
                        let w = if self.strategy == Strategy::Mis && !path.prev_delta {
                            power_heuristic(
                                path.prev_pdf,
                                lights.pdf_area(
                                    hit.light as usize,
                                    (hit.p - path.prev_p).length(),
                                    cos_light,
                                ),
                            )
                        } else {
                            self.emitter_weight(path.prev_delta, path.prev_pdf, 0.0)
                        };
                        path.add(path.beta * light.radiance * w);
                    }
                }
                if self.max_depth >= 0 && path.depth as i64 + 1 >= i64::from(self.max_depth) {
                    path.alive = false;
                    continue;
                }
                let frame = Frame::from_normal(hit.ns);
                vertices.push(Bounce {
                    path: i,
                    wo: frame.to_local(wo_world),
                    frame,
                    hit,
                    vertex: GuideVertex {
                        p: hit.p,
                        n: hit.ns,
                        wo: wo_world,
                    },
                    alpha: 0.0,
                    nee: None,
                    nee_query: None,
                    technique: Technique::Pending,
                });
            }

            // 2. Selection probabilities of the guide, for all non-delta vertices at once.
            guide_vertices.clear();
            materials.clear();
            for b in &vertices {
                let material = &scene.materials[b.hit.material as usize];
                if !material.is_delta() {
                    guide_vertices.push(b.vertex);
                    materials.push(material);
                }
            }
            alphas.clear();
            alphas.resize(guide_vertices.len(), 0.0);
            if !guide_vertices.is_empty() {
                guide.selection_probabilities(&guide_vertices, &materials, &mut alphas);
            }

            // 3. Next-event estimation up to the shadow ray, technique selection and BSDF
            //    sampling; queue the guide densities and samples these need.
            queries.clear();
            let mut next_alpha = alphas.iter();
            for b in &mut vertices {
                let material = &scene.materials[b.hit.material as usize];
                let delta = material.is_delta();
                if !delta {
                    b.alpha = *next_alpha.next().expect("one alpha per non-delta vertex");
                }
                let rng = &mut rngs[b.path];
                if !delta && self.strategy != Strategy::Bsdf && !lights.is_empty() {
                    let u_light = uniform(rng);
                    if let Some(ls) = lights.sample(b.hit.p, u_light, uniform2(rng)) {
                        let wi = b.frame.to_local(ls.wi);
                        let f = material.f(b.wo, wi);
                        if f != Rgb::ZERO {
                            stats.shadow_rays += 1;
                            // Aim from the offset origin at the light point, and stop short
                            // of it by the same kind of offset, so neither surface occludes.
                            let origin = offset_origin(b.hit.p, b.hit.ng, ls.wi);
                            let (shadow, t_max) = if ls.dist.is_finite() {
                                let to = ls.point - origin;
                                let d = to.length();
                                let margin = RAY_EPSILON * (1.0 + ls.point.abs().max_element());
                                (Ray::new(origin, to / d), d - margin)
                            } else {
                                (Ray::new(origin, ls.wi), f32::INFINITY)
                            };
                            if !scene.occluded(&shadow, t_max) {
                                if self.strategy == Strategy::Mis && b.alpha > 0.0 {
                                    b.nee_query = Some(queries.pdf(b.vertex, ls.wi));
                                }
                                b.nee =
                                    Some((ls.wi, ls.pdf, ls.radiance, f, material.pdf(b.wo, wi)));
                            }
                        }
                    }
                }
                let u_select = uniform(rng);
                let u_lobe = uniform(rng);
                let u_dir = uniform2(rng);
                b.technique = if b.alpha > 0.0 && u_select < b.alpha {
                    Technique::Guide(queries.sample(b.vertex, u_dir))
                } else {
                    let sample = material.sample(b.wo, u_lobe, u_dir);
                    let query = sample
                        .filter(|s| !s.delta && b.alpha > 0.0)
                        .map(|s| queries.pdf(b.vertex, b.frame.to_world(s.wi)));
                    Technique::Bsdf(sample, query)
                };
            }
            queries.run(guide);

            // 4. Finish next-event estimation and continue (or end) every path.
            for b in &vertices {
                let material = &scene.materials[b.hit.material as usize];
                let path = &mut paths[b.path];
                let mixture = |guide_pdf: f32, bsdf_pdf: f32| {
                    if b.alpha > 0.0 {
                        b.alpha * guide_pdf + (1.0 - b.alpha) * bsdf_pdf
                    } else {
                        bsdf_pdf
                    }
                };
                if let Some((wi_world, light_pdf, radiance, f, bsdf_pdf)) = b.nee {
                    let w = if self.strategy == Strategy::Mis {
                        let guide_pdf = b.nee_query.map_or(0.0, |q| queries.pdfs[q]);
                        power_heuristic(light_pdf, mixture(guide_pdf, bsdf_pdf))
                    } else {
                        1.0
                    };
                    let wi = b.frame.to_local(wi_world);
                    path.add(path.beta * f * wi.z.abs() * radiance * (w / light_pdf));
                }
                let continued = match b.technique {
                    Technique::Bsdf(sample, query) => sample.map(|s| {
                        let wi_world = b.frame.to_world(s.wi);
                        let pdf = if s.delta {
                            s.pdf
                        } else {
                            mixture(query.map_or(0.0, |q| queries.pdfs[q]), s.pdf)
                        };
                        (wi_world, s.f, pdf, s.pdf, s.delta, s.eta)
                    }),
                    Technique::Guide(q) => queries.samples[q].map(|(wi_world, guide_pdf)| {
                        let wi = b.frame.to_local(wi_world);
                        let bsdf_pdf = material.pdf(b.wo, wi);
                        let pdf = mixture(guide_pdf, bsdf_pdf);
                        (wi_world, material.f(b.wo, wi), pdf, bsdf_pdf, false, 1.0)
                    }),
                    Technique::Pending => unreachable!("every vertex chose a technique"),
                };
                let Some((wi_world, f, pdf, bsdf_pdf, sampled_delta, sample_eta)) = continued
                else {
                    path.alive = false;
                    continue;
                };
                if pdf <= 0.0 || f == Rgb::ZERO {
                    path.alive = false;
                    continue;
                }
                let cos = b.frame.n.dot(wi_world).abs();
                path.beta *= f * (cos / pdf);
                path.eta *= sample_eta;
                if want_records && !sampled_delta {
                    path.pending.push(PendingRecord {
                        record: GuideRecord {
                            vertex: b.vertex,
                            wi: wi_world,
                            pdf,
                            bsdf_pdf,
                            bsdf_cos: f * cos,
                            radiance: Rgb::ZERO,
                        },
                        throughput: path.beta,
                    });
                }
                path.prev_pdf = pdf;
                path.prev_p = b.hit.p;
                path.prev_delta = sampled_delta;
                path.depth += 1;
                if path.depth >= self.rr_depth {
                    let q = (path.beta.max_element() * path.eta * path.eta).min(0.95);
                    if uniform(&mut rngs[b.path]) >= q {
                        path.alive = false;
                        continue;
                    }
                    // Pending records keep the throughput from before this division: the 1/q
                    // belongs to the radiance estimate of the path after them.
                    path.beta /= q;
                }
                path.ray = Ray::new(offset_origin(b.hit.p, b.hit.ng, wi_world), wi_world);
            }
            live.retain(|&i| paths[i].alive);
        }
        for (o, path) in out.iter_mut().zip(&mut paths) {
            *o = path.l;
            if let Some(records) = records.as_deref_mut() {
                records.extend(path.pending.drain(..).map(|p| p.record));
            }
        }
    }

    /// MIS weight of an emitter reached by a BSDF sample whose light-sampling density is
    /// `light_pdf` (0 when unknown).
    fn emitter_weight(&self, prev_delta: bool, prev_pdf: f32, light_pdf: f32) -> f32 {
        if prev_delta {
            return 1.0;
        }
        match self.strategy {
            Strategy::Mis => power_heuristic(prev_pdf, light_pdf),
            Strategy::Nee => 0.0,
            Strategy::Bsdf => 1.0,
        }
    }
}
