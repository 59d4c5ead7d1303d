//! The state of a path while it is traced, and of the vertex it is at: what next-event
//! estimation, the choice of technique and scattering read and write.

use glam::Vec3;

use crate::bsdf::{BsdfSample, Material};
use crate::bump::BumpShading;
use crate::geometry::{Frame, Ray, Rgb};
use crate::guiding::{GuideRecord, GuideVertex};
use crate::scene::{Scene, SurfaceHit};

/// A vertex kept while a path is traced so that guides can learn from it afterwards.
pub(super) struct PendingRecord {
    pub(super) record: GuideRecord,
    /// Path throughput after scattering at this vertex.
    pub(super) throughput: Rgb,
}

/// Credit `contribution` (already multiplied by the path throughput) to every pending vertex
/// in `pending`, as radiance arriving along its sampled direction.
pub(super) fn credit(pending: &mut [PendingRecord], contribution: Rgb) {
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
pub(super) struct PathState {
    pub(super) ray: Ray,
    pub(super) l: Rgb,
    pub(super) beta: Rgb,
    pub(super) eta: f32,
    /// The BSDF's density of the direction the path left its previous vertex in, which MIS
    /// weighs against light sampling (guided or not: see [`PathTracer::sample_light`]).
    pub(super) prev_bsdf_pdf: f32,
    pub(super) prev_delta: bool,
    /// The previous vertex itself (not the offset ray origin), for light densities that must
    /// match the ones next-event estimation computed there.
    pub(super) prev_p: Vec3,
    pub(super) depth: u32,
    /// Vertices with a non-delta BSDF the path scattered at so far (what
    /// [`Guide::guided_bounces`] counts).
    pub(super) bounces: u32,
    pub(super) alive: bool,
    pub(super) pending: Vec<PendingRecord>,
}

impl PathState {
    pub(super) fn new(ray: Ray) -> Self {
        PathState {
            ray,
            l: Rgb::ZERO,
            beta: Rgb::ONE,
            eta: 1.0,
            prev_bsdf_pdf: 0.0,
            prev_delta: true,
            prev_p: ray.origin,
            depth: 0,
            bounces: 0,
            alive: true,
            pending: Vec::new(),
        }
    }

    /// Add a contribution (already multiplied by the throughput) to the estimate and credit it
    /// to the vertices waiting for training data.
    pub(super) fn add(&mut self, c: Rgb) {
        self.l += c;
        credit(&mut self.pending, c);
    }
}

/// Emitted radiance a path's ray reached, and its MIS weight (kept apart: the estimator
/// multiplies throughput, radiance and weight in that order).
#[derive(Clone, Copy, Debug)]
pub(super) struct Emission {
    pub(super) radiance: Rgb,
    pub(super) weight: f32,
}

/// How a vertex continues its path: the sampled direction and what the estimator needs of it.
#[derive(Clone, Copy, Debug)]
pub(super) struct Scatter {
    /// Direction (world).
    pub(super) wi: Vec3,
    /// BSDF value (for a delta lobe, its weight divided by `|cos θi|`).
    pub(super) f: Rgb,
    /// Density the direction was drawn with: the guide–BSDF mixture's, or a delta lobe's
    /// probability.
    pub(super) pdf: f32,
    /// The BSDF's own density of `wi`.
    pub(super) bsdf_pdf: f32,
    /// Whether `wi` came from a delta lobe.
    pub(super) delta: bool,
    /// Relative index of refraction crossed.
    pub(super) eta: f32,
}

/// One scattering vertex of one path during a wavefront step.
pub(super) struct Bounce {
    pub(super) path: usize,
    pub(super) hit: SurfaceHit,
    pub(super) frame: Frame,
    pub(super) wo: Vec3,
    pub(super) vertex: GuideVertex,
    /// The material at the hit's texture coordinates, where it is textured.
    pub(super) textured: Option<Box<Material>>,
    /// The normals of a bump-mapped vertex (`frame` is the bumped one's).
    pub(super) bump: Option<BumpShading>,
    /// Whether the material is a delta BSDF (no light sampling, never guided).
    pub(super) delta: bool,
    /// Index of the vertex in the step's guide batch (`None` where the guide does not serve
    /// the vertex: at delta vertices, at lobes narrower than [`Guide::narrowest_lobe`], and
    /// beyond [`Guide::guided_bounces`]).
    pub(super) guided: Option<usize>,
    /// Selection probability of the guide here.
    pub(super) alpha: f32,
    pub(super) technique: Technique,
}

impl Bounce {
    /// The BSDF value for world direction `wi` (local `wi_local`), with a bump map's
    /// shadowing.
    pub(super) fn f(&self, material: &Material, wi_local: Vec3, wi: Vec3) -> Rgb {
        let f = material.f(self.wo, wi_local);
        match &self.bump {
            Some(s) => f * s.factor(wi),
            None => f,
        }
    }

    /// The BSDF's sampling density for world direction `wi` (local `wi_local`); zero across a
    /// bump map's two normals.
    pub(super) fn bsdf_pdf(&self, material: &Material, wi_local: Vec3, wi: Vec3) -> f32 {
        match &self.bump {
            Some(s) if !s.same_side(wi) => 0.0,
            _ => material.pdf(self.wo, wi_local),
        }
    }

    /// The material at this vertex: its textured instance, or the scene's.
    pub(super) fn material<'a>(&'a self, scene: &'a Scene) -> &'a Material {
        match &self.textured {
            Some(m) => m,
            None => &scene.materials[self.hit.material as usize],
        }
    }

    /// Density of the one-sample guide–BSDF mixture, given the guide's and the BSDF's.
    pub(super) fn mixture_pdf(&self, guide_pdf: f32, bsdf_pdf: f32) -> f32 {
        if self.alpha > 0.0 {
            self.alpha * guide_pdf + (1.0 - self.alpha) * bsdf_pdf
        } else {
            bsdf_pdf
        }
    }
}

/// How a vertex continues its path.
pub(super) enum Technique {
    /// Not decided yet.
    Pending,
    /// A direction from the guide: the index of its sample query.
    Guide(usize),
    /// The BSDF's sample (`None`: it drew nothing), and the index of the guide-density query of
    /// its direction (`None` when the guide is off here or the sample is a delta).
    Bsdf(Option<BsdfSample>, Option<usize>),
}
