//! Light sources: emissive shapes (Mitsuba's one-sided `area` emitter) and a constant
//! environment, with the light-sampling strategy used for next-event estimation.
//!
//! A light is chosen with probability proportional to its power (area × luminance; the
//! environment, when there are also area lights, gets half of the choices), then a point is
//! chosen uniformly on its surface; densities are converted to solid angle at the shading
//! point so that they can be combined with BSDF sampling by multiple importance sampling
//! (Veach 1997, §9.2). Emission is one-sided: only the side the shading normal faces emits.

use std::f32::consts::PI;

use glam::{Vec2, Vec3};

use crate::geometry::{luminance, Rgb};
use crate::sampling::{square_to_triangle, square_to_uniform_sphere, Distribution1D};

/// The primitive an area light covers.
#[derive(Clone, Copy, Debug)]
pub enum LightPrimitive {
    /// A triangle of the scene's BVH: vertex, two edges, and its unit normal.
    Triangle {
        /// First vertex.
        p0: Vec3,
        /// `p1 - p0`.
        e1: Vec3,
        /// `p2 - p0`.
        e2: Vec3,
        /// Emitting side.
        n: Vec3,
    },
    /// A sphere; `inward` when it emits towards its center.
    Sphere {
        /// Center.
        center: Vec3,
        /// Radius.
        radius: f32,
        /// Normals point inwards.
        inward: bool,
    },
}

/// One emitting primitive.
#[derive(Clone, Copy, Debug)]
pub struct AreaLight {
    /// Geometry.
    pub primitive: LightPrimitive,
    /// Emitted radiance on the front side.
    pub radiance: Rgb,
    /// Surface area.
    pub area: f32,
}

/// A light sample seen from a shading point.
#[derive(Clone, Copy, Debug)]
pub struct LightSample {
    /// Unit direction from the shading point to the light.
    pub wi: Vec3,
    /// Distance to the sampled point (infinite for the environment).
    pub dist: f32,
    /// The sampled point on the light (unused for the environment).
    pub point: Vec3,
    /// Radiance arriving along `wi` if unoccluded.
    pub radiance: Rgb,
    /// Solid-angle density, including the choice of light.
    pub pdf: f32,
}

/// All lights of a scene.
#[derive(Clone, Debug, Default)]
pub struct Lights {
    /// Emitting primitives.
    pub area: Vec<AreaLight>,
    /// Constant environment radiance (Mitsuba `constant` emitter).
    pub environment: Option<Rgb>,
    selection: Option<Distribution1D>,
}

impl Lights {
    /// Collect lights and build the selection distribution.
    pub fn new(area: Vec<AreaLight>, environment: Option<Rgb>) -> Self {
        let weights: Vec<f32> = area
            .iter()
            .map(|l| l.area * luminance(l.radiance))
            .collect();
        let selection = Distribution1D::new(&weights);
        Lights {
            area,
            environment,
            selection,
        }
    }

    /// Probability of choosing the environment.
    fn env_probability(&self) -> f32 {
        match (self.environment.is_some(), self.selection.is_some()) {
            (false, _) => 0.0,
            (true, false) => 1.0,
            (true, true) => 0.5,
        }
    }

    /// Whether there is anything to sample.
    pub fn is_empty(&self) -> bool {
        self.selection.is_none() && self.environment.is_none()
    }

    /// Sample a light as seen from `p`; `None` if it is back-facing or has no lights.
    pub fn sample(&self, p: Vec3, u_select: f32, u: Vec2) -> Option<LightSample> {
        let p_env = self.env_probability();
        if u_select < p_env {
            let wi = square_to_uniform_sphere(u);
            return Some(LightSample {
                wi,
                dist: f32::INFINITY,
                point: Vec3::ZERO,
                radiance: self.environment?,
                pdf: p_env / (4.0 * PI),
            });
        }
        let selection = self.selection.as_ref()?;
        let u_select = ((u_select - p_env) / (1.0 - p_env)).min(1.0 - f32::EPSILON);
        let index = selection.sample(u_select);
        let light = &self.area[index];
        let (q, n) = match light.primitive {
            LightPrimitive::Triangle { p0, e1, e2, n } => {
                let b = square_to_triangle(u);
                (p0 + b.x * e1 + b.y * e2, n)
            }
            LightPrimitive::Sphere {
                center,
                radius,
                inward,
            } => {
                let d = square_to_uniform_sphere(u);
                (center + radius * d, if inward { -d } else { d })
            }
        };
        let to = q - p;
        let dist2 = to.length_squared();
        let dist = dist2.sqrt();
        let wi = to / dist;
        let cos_light = -n.dot(wi);
        if cos_light <= 0.0 || dist2 == 0.0 {
            return None;
        }
        let pmf = selection.pmf(index) * (1.0 - p_env);
        Some(LightSample {
            wi,
            dist,
            point: q,
            radiance: light.radiance,
            pdf: pmf / light.area * dist2 / cos_light,
        })
    }

    /// Solid-angle density with which [`Lights::sample`] picks area light `index` at a point
    /// at distance `dist` whose normal makes cosine `cos_light` with the direction.
    pub fn pdf_area(&self, index: usize, dist: f32, cos_light: f32) -> f32 {
        let Some(selection) = &self.selection else {
            return 0.0;
        };
        let pmf = selection.pmf(index) * (1.0 - self.env_probability());
        pmf / self.area[index].area * dist * dist / cos_light.abs().max(1e-12)
    }

    /// Solid-angle density of sampling the environment in any direction.
    pub fn pdf_environment(&self) -> f32 {
        self.env_probability() / (4.0 * PI)
    }
}
