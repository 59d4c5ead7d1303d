//! Unidirectional path tracing with next-event estimation, BSDF (or guided) sampling, multiple
//! importance sampling and Russian roulette.
//!
//! This is the standard estimator of Kajiya's rendering equation as described by Veach (thesis,
//! 1997, ch. 9) and Pharr et al. (*PBR* 4th ed., §13.4): at every non-delta vertex one light
//! sample and one BSDF sample are taken and weighted with the power heuristic. A path guide
//! replaces the BSDF sample by one from a guide–BSDF mixture at the vertices it serves (its
//! first [`Guide::guided_bounces`] non-delta ones, but for lobes narrower than
//! [`Guide::narrowest_lobe`]), and learns from those vertices alone; the
//! weights stay those of light against BSDF sampling (see `PathTracer::sample_light`).
//! Depth counting, `max_depth` and `rr_depth` follow Mitsuba 3's `path` integrator:
//! `max_depth = 1` shows only directly visible emitters, `2` adds direct lighting, `-1` is
//! unbounded; Russian roulette continues with probability `min(max(throughput · η²), 0.95)`
//! once `rr_depth` bounces are done.
//! [`Strategy::Nee`] and [`Strategy::Bsdf`] switch one of the two techniques off; all three are
//! unbiased estimators of the same image, which the tests check.

use glam::Vec2;
use rand::RngCore;
use rand_pcg::Pcg32;

use crate::bsdf::Material;
use crate::bump::BumpShading;
use crate::geometry::{luminance, offset_origin, Frame, Ray, Rgb, RAY_EPSILON};
use crate::guiding::{Guide, GuideRecord, GuideVertex};
use crate::sampling::power_heuristic;
use crate::scene::{Scene, SurfaceHit, NO_LIGHT};
use guide_batch::GuideBatch;
use path::{Bounce, Emission, PathState, PendingRecord, Scatter, Technique};

mod guide_batch;
mod path;

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
pub struct PathTracer {
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

/// Camera rays traced together, each with its random stream, and where their radiance
/// estimates go.
pub struct Wavefront<'a> {
    /// Camera rays.
    pub rays: &'a [Ray],
    /// One random stream per ray.
    pub rngs: &'a mut [Pcg32],
    /// One radiance estimate per ray (written).
    pub radiance: &'a mut [Rgb],
}

/// Which vertices the guide serves: non-delta ones among a path's first `bounces`, but for
/// glossy lobes narrower than `narrowest_lobe` ([`Guide::narrowest_lobe`]).
#[derive(Clone, Copy)]
struct Served {
    bounces: u32,
    narrowest_lobe: f32,
}

/// A wavefront between bounces: its paths, the live ones, this bounce's vertices and the guide
/// queries they make.
struct WaveState<G: Guide + ?Sized> {
    paths: Vec<PathState>,
    live: Vec<usize>,
    bounces: Vec<Bounce>,
    batch: GuideBatch<G>,
}

impl PathTracer {
    /// The settings a scene was described with, estimated by `strategy`.
    pub fn from_scene(scene: &Scene, strategy: Strategy) -> Self {
        PathTracer {
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
        let paths = Wavefront {
            rays: &[ray],
            rngs: std::slice::from_mut(rng),
            radiance: &mut out,
        };
        self.trace(scene, paths, guide, stats, records);
        out[0]
    }

    /// One-sample radiance estimates of a batch of camera rays, traced as a wavefront: all
    /// live paths advance one bounce at a time, so the guide is queried in batches (per bounce,
    /// one preparation and selection call for all guided vertices, one call for directions and
    /// one for densities). Path `i` draws its random numbers from `rngs[i]` in the same order
    /// as a path traced alone, so the result of a path does not depend on the batch it is
    /// traced in. Records of finished paths are appended path by path, in batch order.
    pub fn trace<G: Guide + ?Sized>(
        &self,
        scene: &Scene,
        paths: Wavefront<'_>,
        guide: &G,
        stats: &mut PathStats,
        mut records: Option<&mut Vec<GuideRecord>>,
    ) {
        let Wavefront {
            rays,
            rngs,
            radiance,
        } = paths;
        assert!(rays.len() == rngs.len() && rays.len() == radiance.len());
        let want_records = records.is_some();
        let served = Served {
            bounces: guide.guided_bounces(),
            narrowest_lobe: guide.narrowest_lobe(),
        };
        let mut wave = WaveState {
            paths: rays.iter().map(|&r| PathState::new(r)).collect(),
            live: (0..rays.len()).collect(),
            bounces: Vec::new(),
            batch: GuideBatch::<G>::new(),
        };
        while !wave.live.is_empty() {
            self.intersect(scene, &mut wave, served, stats);
            // 2. Selection probabilities of the guide, for all guided vertices at once.
            wave.batch.select(guide);
            self.choose_techniques(scene, &mut wave, rngs, stats);
            wave.batch.run(guide);
            self.scatter_all(scene, &mut wave, rngs, want_records);
            let paths = &wave.paths;
            wave.live.retain(|&i| paths[i].alive);
        }
        let mut paths = wave.paths;
        for (o, path) in radiance.iter_mut().zip(&mut paths) {
            *o = path.l;
            if let Some(records) = records.as_deref_mut() {
                records.extend(path.pending.drain(..).map(|p| p.record));
            }
        }
    }

    /// Step 1 of a bounce in [`PathTracer::trace`]: intersects every live path's ray, collects emission, and sets up the
    /// vertices that scatter; those the guide serves (`served`) join the guide batch.
    fn intersect<G: Guide + ?Sized>(
        &self,
        scene: &Scene,
        wave: &mut WaveState<G>,
        served: Served,
        stats: &mut PathStats,
    ) {
        let WaveState {
            paths,
            live,
            bounces,
            batch,
        } = wave;
        bounces.clear();
        batch.vertices.clear();
        for &i in live.iter() {
            let path = &mut paths[i];
            stats.rays += 1;
            let hit = scene.intersect(&path.ray, f32::INFINITY);
            if let Some(e) = self.emitted(scene, path, hit.as_ref()) {
                path.add(path.beta * e.radiance * e.weight);
            }
            let Some(hit) = hit else {
                path.alive = false;
                continue;
            };
            if self.max_depth >= 0 && path.depth as i64 + 1 >= i64::from(self.max_depth) {
                path.alive = false;
                continue;
            }
            let wo_world = -path.ray.dir;
            let base = &scene.materials[hit.material as usize];
            let mut hit = hit;
            let mut bump = None;
            if let Some(b) = &base.bump {
                if let Some(d) = scene.uv_derivatives(&hit) {
                    let n = b.normal(hit.uv, hit.ns, hit.ng, d, wo_world);
                    bump = Some(BumpShading::new(hit.ns, n));
                    hit.ns = n;
                }
            }
            let textured = base
                .at_hit(hit.uv, scene.attributes(&hit).as_ref())
                .map(Box::new);
            let material = textured.as_deref().unwrap_or(base);
            // Anisotropic roughness is oriented by Mitsuba's tangent; others keep the old frame.
            let frame = if base.is_anisotropic() {
                Frame::from_normal_tangent(hit.ns, scene.dpdu(&hit))
            } else {
                Frame::from_normal(hit.ns)
            };
            let vertex = GuideVertex {
                p: hit.p,
                n: hit.ns,
                wo: wo_world,
                transmissive: material.transmits(),
            };
            let delta = material.is_delta();
            let guided = !delta
                && path.bounces < served.bounces
                && material
                    .bsdf
                    .lobe_half_angle()
                    .is_none_or(|a| a >= served.narrowest_lobe);
            bounces.push(Bounce {
                path: i,
                wo: frame.to_local(wo_world),
                frame,
                hit,
                vertex,
                textured,
                bump,
                delta,
                guided: guided.then(|| batch.push(vertex)),
                alpha: 0.0,
                technique: Technique::Pending,
            });
        }
    }

    /// Step 3 (after the guide's selection probabilities): next-event estimation up to the
    /// shadow ray, the choice of technique and BSDF sampling at every vertex; queues the guide
    /// densities and samples these need.
    fn choose_techniques<G: Guide + ?Sized>(
        &self,
        scene: &Scene,
        wave: &mut WaveState<G>,
        rngs: &mut [Pcg32],
        stats: &mut PathStats,
    ) {
        let WaveState {
            paths,
            bounces,
            batch,
            ..
        } = wave;
        for b in bounces.iter_mut() {
            if let Some(g) = b.guided {
                b.alpha = batch.alphas[g];
            }
            let material = b.material(scene);
            let rng = &mut rngs[b.path];
            if !b.delta {
                let path = &mut paths[b.path];
                if let Some(c) = self.sample_light(scene, b, material, path.beta, rng, stats) {
                    path.add(c);
                }
            }
            let u_select = uniform(rng);
            let u_lobe = uniform(rng);
            let u_dir = uniform2(rng);
            let technique = match b.guided {
                Some(g) if b.alpha > 0.0 && u_select < b.alpha => {
                    Technique::Guide(batch.sample(g, u_dir))
                }
                _ => {
                    let sample = material.sample(b.wo, u_lobe, u_dir);
                    let query = b
                        .guided
                        .filter(|_| b.alpha > 0.0)
                        .zip(sample.filter(|s| !s.delta))
                        .map(|(g, s)| batch.pdf(g, b.frame.to_world(s.wi)));
                    Technique::Bsdf(sample, query)
                }
            };
            b.technique = technique;
        }
    }

    /// Step 4 (after the guide's queries): finishes next-event estimation and continues, or
    /// ends, every path; keeps the vertices guides learn from when `want_records`.
    fn scatter_all<G: Guide + ?Sized>(
        &self,
        scene: &Scene,
        wave: &mut WaveState<G>,
        rngs: &mut [Pcg32],
        want_records: bool,
    ) {
        let WaveState {
            paths,
            bounces,
            batch,
            ..
        } = wave;
        for b in bounces.iter() {
            let material = b.material(scene);
            let path = &mut paths[b.path];
            let Some(scatter) = Self::scatter(b, material, batch) else {
                path.alive = false;
                continue;
            };
            if scatter.pdf <= 0.0 || scatter.f == Rgb::ZERO {
                path.alive = false;
                continue;
            }
            let cos = b.frame.n.dot(scatter.wi).abs();
            let arriving = luminance(path.beta);
            path.beta *= scatter.f * (cos / scatter.pdf);
            path.eta *= scatter.eta;
            if want_records && !scatter.delta && b.guided.is_some() {
                path.pending.push(PendingRecord {
                    record: GuideRecord {
                        vertex: b.vertex,
                        wi: scatter.wi,
                        pdf: scatter.pdf,
                        bsdf_pdf: scatter.bsdf_pdf,
                        bsdf_cos: scatter.f * cos,
                        radiance: Rgb::ZERO,
                        throughput: arriving,
                    },
                    throughput: path.beta,
                });
            }
            path.prev_bsdf_pdf = scatter.bsdf_pdf;
            path.prev_p = b.hit.p;
            path.prev_delta = scatter.delta;
            path.depth += 1;
            path.bounces += u32::from(!b.delta);
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
            path.ray = Ray::new(offset_origin(b.hit.p, b.hit.ng, scatter.wi), scatter.wi);
        }
    }

    /// What `path` receives from what its ray reached: the environment when `hit` is `None`,
    /// an area light's emission if it hit one from the front, with the MIS weight against
    /// light sampling at the previous vertex. `None` when nothing emits, or emitters seen
    /// directly are hidden.
    fn emitted(
        &self,
        scene: &Scene,
        path: &PathState,
        hit: Option<&SurfaceHit>,
    ) -> Option<Emission> {
        if path.depth == 0 && self.hide_emitters {
            return None;
        }
        let lights = &scene.lights;
        let Some(hit) = hit else {
            let env = lights.environment_radiance(path.ray.dir)?;
            let weight = self.emitter_weight(
                path.prev_delta,
                path.prev_bsdf_pdf,
                lights.pdf_environment(path.ray.dir),
            );
            return Some(Emission {
                radiance: env,
                weight,
            });
        };
        if hit.light == NO_LIGHT {
            return None;
        }
        let cos_light = hit.ns.dot(-path.ray.dir);
        if cos_light <= 0.0 {
            return None;
        }
        let light = &lights.area[hit.light as usize];
        let weight = if self.strategy == Strategy::Mis && !path.prev_delta {
            let distance = (hit.p - path.prev_p).length();
            let light_pdf = lights.pdf_area(hit.light as usize, distance, cos_light);
            power_heuristic(path.prev_bsdf_pdf, light_pdf)
        } else {
            self.emitter_weight(path.prev_delta, path.prev_bsdf_pdf, 0.0)
        };
        Some(Emission {
            radiance: light.radiance,
            weight,
        })
    }

    /// Next-event estimation at a non-delta vertex (pbrt's `SampleLd`): the contribution of one
    /// light sample to a path of throughput `beta`, if the strategy uses light sampling, the
    /// BSDF value is non-zero and the sample is unoccluded. Draws three random numbers whenever
    /// the strategy samples lights and the scene has any.
    ///
    /// The sample is weighted by the power heuristic against the BSDF's density of its
    /// direction, guided or not, and the emitter that a continuation reaches by the same two
    /// densities ([`PathTracer::emitted`]), so the two weights of every direction sum to one
    /// whatever density the continuation was drawn from: the guide–BSDF mixture only divides
    /// the continuation's throughput, and the guide's density of the light sample's direction
    /// (a network query per light sample for the neural guide) is never needed. Weighing
    /// against the mixture's density instead, as this renderer did before, gave the same error
    /// at equal samples in more time (docs/results/guiding.md, "MIS against the BSDF").
    fn sample_light(
        &self,
        scene: &Scene,
        b: &Bounce,
        material: &Material,
        beta: Rgb,
        rng: &mut Pcg32,
        stats: &mut PathStats,
    ) -> Option<Rgb> {
        let lights = &scene.lights;
        if self.strategy == Strategy::Bsdf || lights.is_empty() {
            return None;
        }
        let u_light = uniform(rng);
        let ls = lights.sample(b.hit.p, u_light, uniform2(rng))?;
        let wi = b.frame.to_local(ls.wi);
        let f = b.f(material, wi, ls.wi);
        if f == Rgb::ZERO {
            return None;
        }
        stats.shadow_rays += 1;
        // Aim from the offset origin at the light point, and stop short of it by the same kind
        // of offset, so neither surface occludes.
        let origin = offset_origin(b.hit.p, b.hit.ng, ls.wi);
        let (shadow, t_max) = if ls.dist.is_finite() {
            let to = ls.point - origin;
            let d = to.length();
            let margin = RAY_EPSILON * (1.0 + ls.point.abs().max_element());
            (Ray::new(origin, to / d), d - margin)
        } else {
            (Ray::new(origin, ls.wi), f32::INFINITY)
        };
        if scene.occluded(&shadow, t_max) {
            return None;
        }
        let w = if self.strategy == Strategy::Mis && !ls.delta {
            power_heuristic(ls.pdf, b.bsdf_pdf(material, wi, ls.wi))
        } else {
            1.0
        };
        Some(beta * f * wi.z.abs() * ls.radiance * (w / ls.pdf))
    }

    /// The direction a vertex continues in, from the technique it chose (`None`: the
    /// technique drew nothing).
    fn scatter<G: Guide + ?Sized>(
        b: &Bounce,
        material: &Material,
        batch: &GuideBatch<G>,
    ) -> Option<Scatter> {
        match b.technique {
            Technique::Bsdf(sample, query) => sample.map(|s| Scatter {
                wi: b.frame.to_world(s.wi),
                f: match &b.bump {
                    Some(bump) => s.f * bump.factor(b.frame.to_world(s.wi)),
                    None => s.f,
                },
                // A delta lobe of a mixed BSDF (plastic, mask) at a guided vertex is drawn only
                // when the BSDF is chosen: with probability 1 − α.
                pdf: if s.delta {
                    b.mixture_pdf(0.0, s.pdf)
                } else {
                    b.mixture_pdf(query.map_or(0.0, |q| batch.pdfs[q]), s.pdf)
                },
                bsdf_pdf: s.pdf,
                delta: s.delta,
                eta: s.eta,
            }),
            Technique::Guide(q) => batch.samples[q].map(|g| {
                let wi = b.frame.to_local(g.wi);
                let bsdf_pdf = b.bsdf_pdf(material, wi, g.wi);
                Scatter {
                    wi: g.wi,
                    f: b.f(material, wi, g.wi),
                    pdf: b.mixture_pdf(g.pdf, bsdf_pdf),
                    bsdf_pdf,
                    delta: false,
                    eta: 1.0,
                }
            }),
            Technique::Pending => unreachable!("every vertex chose a technique"),
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
