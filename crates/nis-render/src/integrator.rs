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
        mut ray: Ray,
        rng: &mut Pcg32,
        guide: &G,
        stats: &mut PathStats,
        records: Option<&mut Vec<GuideRecord>>,
    ) -> Rgb {
        let mut pending: Vec<PendingRecord> = Vec::new();
        let mut l = Rgb::ZERO;
        let mut beta = Rgb::ONE;
        let mut eta = 1.0f32;
        let mut prev_pdf = 0.0f32;
        let mut prev_delta = true;
        // The previous vertex itself (not the offset ray origin), for light densities that
        // must match the ones next-event estimation computed there.
        let mut prev_p = ray.origin;
        let lights = &scene.lights;
        let mut depth = 0u32;
        loop {
            stats.rays += 1;
            let Some(hit) = scene.intersect(&ray, f32::INFINITY) else {
                if let Some(env) = lights.environment {
                    if !(depth == 0 && self.hide_emitters) {
                        let w = self.emitter_weight(prev_delta, prev_pdf, lights.pdf_environment());
                        let c = beta * env * w;
                        l += c;
                        credit(&mut pending, c);
                    }
                }
                break;
            };
            let wo_world = -ray.dir;
            if hit.light != NO_LIGHT && !(depth == 0 && self.hide_emitters) {
                let cos_light = hit.ns.dot(wo_world);
                if cos_light > 0.0 {
                    let light = &lights.area[hit.light as usize];
                    let w = if self.strategy == Strategy::Mis && !prev_delta {
                        power_heuristic(
                            prev_pdf,
                            lights.pdf_area(
                                hit.light as usize,
                                (hit.p - prev_p).length(),
                                cos_light,
                            ),
                        )
                    } else {
                        self.emitter_weight(prev_delta, prev_pdf, 0.0)
                    };
                    let c = beta * light.radiance * w;
                    l += c;
                    credit(&mut pending, c);
                }
            }
            if self.max_depth >= 0 && depth as i64 + 1 >= i64::from(self.max_depth) {
                break;
            }
            let material = &scene.materials[hit.material as usize];
            let frame = Frame::from_normal(hit.ns);
            let wo = frame.to_local(wo_world);
            let delta = material.is_delta();
            let vertex = GuideVertex {
                p: hit.p,
                n: hit.ns,
                wo: wo_world,
            };
            let alpha = if delta {
                0.0
            } else {
                guide.selection_probability(&vertex, material)
            };
            let mixture_pdf = |wi_world: Vec3, bsdf_pdf: f32| {
                if alpha > 0.0 {
                    alpha * guide.pdf(&vertex, wi_world) + (1.0 - alpha) * bsdf_pdf
                } else {
                    bsdf_pdf
                }
            };

            // Next-event estimation.
            if !delta && self.strategy != Strategy::Bsdf && !lights.is_empty() {
                let u_light = uniform(rng);
                if let Some(ls) = lights.sample(hit.p, u_light, uniform2(rng)) {
                    let wi = frame.to_local(ls.wi);
                    let f = material.f(wo, wi);
                    if f != Rgb::ZERO {
                        stats.shadow_rays += 1;
                        // Aim from the offset origin at the light point, and stop short of
                        // it by the same kind of offset, so neither surface occludes.
                        let origin = offset_origin(hit.p, hit.ng, ls.wi);
                        let (shadow, t_max) = if ls.dist.is_finite() {
                            let to = ls.point - origin;
                            let d = to.length();
                            let margin = RAY_EPSILON * (1.0 + ls.point.abs().max_element());
                            (Ray::new(origin, to / d), d - margin)
                        } else {
                            (Ray::new(origin, ls.wi), f32::INFINITY)
                        };
                        if !scene.occluded(&shadow, t_max) {
                            let w = if self.strategy == Strategy::Mis {
                                power_heuristic(ls.pdf, mixture_pdf(ls.wi, material.pdf(wo, wi)))
                            } else {
                                1.0
                            };
                            let c = beta * f * wi.z.abs() * ls.radiance * (w / ls.pdf);
                            l += c;
                            credit(&mut pending, c);
                        }
                    }
                }
            }

            // Continue the path: guide with probability α, BSDF otherwise.
            let u_select = uniform(rng);
            let u_lobe = uniform(rng);
            let u_dir = uniform2(rng);
            let (wi_world, f, pdf, sampled_delta, sample_eta) = if alpha > 0.0 && u_select < alpha {
                let Some((wi_world, _)) = guide.sample(&vertex, u_dir) else {
                    break;
                };
                let wi = frame.to_local(wi_world);
                let pdf = mixture_pdf(wi_world, material.pdf(wo, wi));
                (wi_world, material.f(wo, wi), pdf, false, 1.0)
            } else {
                let Some(s) = material.sample(wo, u_lobe, u_dir) else {
                    break;
                };
                let wi_world = frame.to_world(s.wi);
                let pdf = if s.delta {
                    s.pdf
                } else {
                    mixture_pdf(wi_world, s.pdf)
                };
                (wi_world, s.f, pdf, s.delta, s.eta)
            };
            if pdf <= 0.0 || f == Rgb::ZERO {
                break;
            }
            let cos = frame.n.dot(wi_world).abs();
            let weight = f * (cos / pdf);
            beta *= weight;
            eta *= sample_eta;
            if records.is_some() && !sampled_delta {
                pending.push(PendingRecord {
                    record: GuideRecord {
                        vertex,
                        wi: wi_world,
                        pdf,
                        bsdf_cos: f * cos,
                        radiance: Rgb::ZERO,
                    },
                    throughput: beta,
                });
            }
            prev_pdf = pdf;
            prev_p = hit.p;
            prev_delta = sampled_delta;
            depth += 1;
            if depth >= self.rr_depth {
                let q = (beta.max_element() * eta * eta).min(0.95);
                if uniform(rng) >= q {
                    break;
                }
                // Pending records keep the throughput from before this division: the 1/q
                // belongs to the radiance estimate of the path after them.
                beta /= q;
            }
            ray = Ray::new(offset_origin(hit.p, hit.ng, wi_world), wi_world);
        }
        if let Some(out) = records {
            out.extend(pending.into_iter().map(|p| p.record));
        }
        l
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
