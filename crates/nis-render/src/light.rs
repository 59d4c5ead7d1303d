//! Light sources: emissive shapes (Mitsuba's one-sided `area` emitter), a constant or mapped
//! environment or Mitsuba's sun and sky, and delta lights (`directional`, `point`, `spot`, optionally
//! projecting a texture, and `projector`), with the light-sampling strategy used for
//! next-event estimation.
//!
//! Each kind present (the environment, the area lights, the delta lights) gets an equal share of
//! the choices; an area light is then chosen with probability proportional to its power
//! (area × luminance), a delta one to its irradiance's or intensity's luminance, and a point is
//! chosen uniformly on its surface; densities are converted to solid angle at the shading
//! point so that they can be combined with BSDF sampling by multiple importance sampling
//! (Veach 1997, §9.2). Emission is one-sided: only the side the shading normal faces emits.

use std::f32::consts::PI;

use std::sync::Arc;

use glam::{Mat3, Mat4, Vec2, Vec3};

use crate::envmap::{EnvMap, EnvSample};
use crate::geometry::{luminance, Rgb};
use crate::sampling::{square_to_triangle, square_to_uniform_sphere, Distribution1D};
use crate::sunsky::SunSky;
use crate::texture::Texture;

/// An environment whose radiance varies with direction, importance-sampled.
#[derive(Debug)]
pub enum EnvironmentLight {
    /// An image (Mitsuba `envmap`).
    Map(EnvMap),
    /// The sun and sky (Mitsuba `sunsky`).
    SunSky(Box<SunSky>),
}

impl EnvironmentLight {
    /// Radiance arriving from world direction `dir` (pointing away from the scene).
    pub fn eval(&self, dir: Vec3) -> Rgb {
        match self {
            EnvironmentLight::Map(m) => m.eval(dir),
            EnvironmentLight::SunSky(s) => s.eval(dir),
        }
    }

    /// Solid-angle density of [`EnvironmentLight::sample`] for world direction `dir`.
    pub fn pdf(&self, dir: Vec3) -> f32 {
        match self {
            EnvironmentLight::Map(m) => m.pdf(dir),
            EnvironmentLight::SunSky(s) => s.pdf(dir),
        }
    }

    /// Draw a direction from two uniform numbers.
    pub fn sample(&self, u: Vec2) -> Option<EnvSample> {
        match self {
            EnvironmentLight::Map(m) => m.sample(u),
            EnvironmentLight::SunSky(s) => s.sample(u),
        }
    }
}

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
    /// Solid-angle density, including the choice of light; for a delta light (directional),
    /// the discrete probability of its choice.
    pub pdf: f32,
    /// Whether the light is a Dirac delta in direction (no BSDF sample can reach it).
    pub delta: bool,
}

/// A light infinitely far away in one direction (Mitsuba `directional`).
#[derive(Clone, Copy, Debug)]
pub struct DirectionalLight {
    /// Unit direction the light travels in.
    pub direction: Vec3,
    /// Irradiance on a surface facing the light.
    pub irradiance: Rgb,
}

/// A point light shining into a cone (Mitsuba `spot`): full intensity within `beam_width` of
/// its axis, falling linearly in angle to zero at `cutoff_angle`, times an optional texture
/// projected through the cone (Mitsuba 3's `spot.cpp`: a local direction `d` reads
/// `uv = ½ + ½ (d.x, d.y) / (d.z tan cutoff)`, so the image spans the cone's square).
#[derive(Clone, Debug)]
pub struct SpotLight {
    /// Position.
    pub position: Vec3,
    /// Unit axis of the cone.
    pub axis: Vec3,
    /// Radiant intensity on the axis.
    pub intensity: Rgb,
    /// Half-angle of the cone's edge, radians.
    pub cutoff: f32,
    /// Half-angle of the full-intensity beam, radians.
    pub beam_width: f32,
    /// The projected texture, if any.
    pub texture: Option<Arc<Texture>>,
    /// World-to-local map of directions (the inverse of `to_world`'s linear part).
    pub to_local: Mat3,
}

impl SpotLight {
    /// The fraction of the intensity sent in unit direction `d`.
    pub fn falloff(&self, d: Vec3) -> f32 {
        let cos = d.dot(self.axis).clamp(-1.0, 1.0);
        if cos <= self.cutoff.cos() {
            0.0
        } else if cos >= self.beam_width.cos() {
            1.0
        } else {
            (self.cutoff - cos.acos()) / (self.cutoff - self.beam_width)
        }
    }

    /// The intensity sent in unit direction `d`: falloff times texture.
    pub fn intensity_towards(&self, d: Vec3) -> Rgb {
        let falloff = self.falloff(d);
        if falloff <= 0.0 {
            return Rgb::ZERO;
        }
        let mut intensity = self.intensity * falloff;
        if let Some(texture) = &self.texture {
            let l = self.to_local * d;
            let uv = Vec2::new(l.x, l.y) / (2.0 * l.z * self.cutoff.tan()) + Vec2::splat(0.5);
            if !uv.is_finite() {
                return Rgb::ZERO;
            }
            intensity *= texture.eval(uv);
        }
        intensity
    }
}

/// A pinhole projecting an image (Mitsuba 3's `projector.cpp`, the perspective camera's
/// reciprocal): a point `p` in the local frame reads the irradiance texture at
/// `uv = ½ − ½ (x / (z tan_x), y / (z tan_y))` (Mitsuba's sample-to-camera map) and receives
/// intensity over distance² `π · scale · E(uv) / (z² cos θ)`, so that a plane at z = 1 facing
/// it gets irradiance `π · scale · E`, as in Mitsuba.
#[derive(Clone, Debug)]
pub struct ProjectorLight {
    /// Position (the pinhole).
    pub position: Vec3,
    /// World-to-local map of points.
    pub to_local: Mat4,
    /// The local +z in world space (Mitsuba's `ds.n`).
    pub axis: Vec3,
    /// Half-width and half-height of the image at z = 1.
    pub tan_half: Vec2,
    /// Constant irradiance factor (the colour, or one under a texture) times `scale`.
    pub irradiance: Rgb,
    /// The projected image, if any.
    pub texture: Option<Arc<Texture>>,
}

impl ProjectorLight {
    /// Radiance times solid angle arriving at world point `p` from the projector (zero
    /// outside its frustum).
    pub fn arriving_at(&self, p: Vec3) -> Rgb {
        let l = self.to_local.transform_point3(p);
        let uv = Vec2::splat(0.5) - 0.5 * Vec2::new(l.x, l.y) / (l.z * self.tan_half);
        let inside = l.z > 0.0 && uv.cmpge(Vec2::ZERO).all() && uv.cmple(Vec2::ONE).all();
        let to_light = self.position - p;
        let cos = self.axis.dot(-to_light.normalize_or_zero());
        if !inside || cos <= 0.0 {
            return Rgb::ZERO;
        }
        let e = self.texture.as_ref().map_or(Rgb::ONE, |t| t.eval(uv));
        self.irradiance * e * (PI / (l.z * l.z * cos))
    }
}

/// A light that no BSDF sample can reach: sampled by next-event estimation only.
#[derive(Clone, Debug)]
pub enum DeltaLight {
    /// Infinitely far away in one direction.
    Directional(DirectionalLight),
    /// A point shining equally in all directions (Mitsuba `point`): radiant intensity at a
    /// position.
    Point {
        /// Position.
        position: Vec3,
        /// Radiant intensity.
        intensity: Rgb,
    },
    /// A point with a cone.
    Spot(SpotLight),
    /// A pinhole projecting an image.
    Projector(ProjectorLight),
}

impl DeltaLight {
    /// The light's weight in the choice among delta lights.
    fn power(&self) -> f32 {
        match self {
            DeltaLight::Directional(l) => luminance(l.irradiance),
            DeltaLight::Point { intensity, .. } => luminance(*intensity),
            DeltaLight::Spot(l) => {
                luminance(l.intensity) * l.texture.as_ref().map_or(1.0, |t| luminance(t.mean()))
            }
            DeltaLight::Projector(l) => {
                PI * luminance(l.irradiance)
                    * l.texture.as_ref().map_or(1.0, |t| luminance(t.mean()))
            }
        }
    }
}

/// All lights of a scene.
#[derive(Clone, Debug, Default)]
pub struct Lights {
    /// Emitting primitives.
    pub area: Vec<AreaLight>,
    /// Constant environment radiance (Mitsuba `constant` emitter).
    pub environment: Option<Rgb>,
    /// An environment map (Mitsuba `envmap`) or the sun and sky (`sunsky`), in place of a
    /// constant environment.
    pub environment_map: Option<Arc<EnvironmentLight>>,
    /// Directional, point, spot and projector lights.
    pub delta: Vec<DeltaLight>,
    selection: Option<Distribution1D>,
    delta_selection: Option<Distribution1D>,
}

impl Lights {
    /// Collect lights and build the selection distribution.
    pub fn new(area: Vec<AreaLight>, environment: Option<Rgb>) -> Self {
        Self::with_directional(area, environment, Vec::new())
    }

    /// [`Lights::new`] with directional lights.
    pub fn with_directional(
        area: Vec<AreaLight>,
        environment: Option<Rgb>,
        delta: Vec<DeltaLight>,
    ) -> Self {
        let weights: Vec<f32> = area
            .iter()
            .map(|l| l.area * luminance(l.radiance))
            .collect();
        let selection = Distribution1D::new(&weights);
        let weights: Vec<f32> = delta.iter().map(DeltaLight::power).collect();
        let delta_selection = Distribution1D::new(&weights);
        Lights {
            area,
            environment,
            environment_map: None,
            delta,
            selection,
            delta_selection,
        }
    }

    /// Replace the delta (directional, point, spot and projector) lights.
    pub fn set_delta(&mut self, delta: Vec<DeltaLight>) {
        let map = self.environment_map.take();
        *self = Self::with_directional(std::mem::take(&mut self.area), self.environment, delta);
        self.environment_map = map;
    }

    /// Light the scene by an environment map instead of a constant environment.
    pub fn set_environment_map(&mut self, map: EnvMap) {
        self.set_environment_light(EnvironmentLight::Map(map));
    }

    /// Light the scene by an environment map or the sun and sky instead of a constant
    /// environment.
    pub fn set_environment_light(&mut self, light: EnvironmentLight) {
        self.environment_map = Some(Arc::new(light));
        self.environment = None;
    }

    /// Whether any environment lights the scene.
    fn has_environment(&self) -> bool {
        self.environment.is_some() || self.environment_map.is_some()
    }

    /// Radiance arriving from the environment along world direction `dir` (away from the
    /// scene), if there is an environment.
    pub fn environment_radiance(&self, dir: Vec3) -> Option<Rgb> {
        match &self.environment_map {
            Some(map) => Some(map.eval(dir)),
            None => self.environment,
        }
    }

    /// Number of kinds of light present (environment, area, directional).
    fn kinds(&self) -> f32 {
        (u8::from(self.has_environment())
            + u8::from(self.selection.is_some())
            + u8::from(self.delta_selection.is_some())) as f32
    }

    /// Probability of choosing the environment.
    fn env_probability(&self) -> f32 {
        match (
            self.has_environment(),
            self.selection.is_some(),
            self.delta_selection.is_some(),
        ) {
            (false, _, _) => 0.0,
            (true, false, false) => 1.0,
            (true, true, false) => 0.5,
            (true, _, true) => 1.0 / self.kinds(),
        }
    }

    /// Probability of choosing one of the area lights.
    fn area_probability(&self) -> f32 {
        if self.delta_selection.is_none() {
            1.0 - self.env_probability()
        } else if self.selection.is_some() {
            1.0 / self.kinds()
        } else {
            0.0
        }
    }

    /// Whether there is anything to sample.
    pub fn is_empty(&self) -> bool {
        self.selection.is_none() && !self.has_environment() && self.delta.is_empty()
    }

    /// Sample a light as seen from `p`; `None` if it is back-facing or has no lights.
    pub fn sample(&self, p: Vec3, u_select: f32, u: Vec2) -> Option<LightSample> {
        let p_env = self.env_probability();
        if u_select < p_env {
            if let Some(map) = &self.environment_map {
                let s = map.sample(u)?;
                return Some(LightSample {
                    wi: s.wi,
                    dist: f32::INFINITY,
                    point: Vec3::ZERO,
                    radiance: s.radiance,
                    pdf: p_env * s.pdf,
                    delta: false,
                });
            }
            let wi = square_to_uniform_sphere(u);
            return Some(LightSample {
                wi,
                dist: f32::INFINITY,
                point: Vec3::ZERO,
                radiance: self.environment?,
                pdf: p_env / (4.0 * PI),
                delta: false,
            });
        }
        let p_area = self.area_probability();
        if u_select >= p_env + p_area {
            let selection = self.delta_selection.as_ref()?;
            let p_dir = 1.0 - p_env - p_area;
            let u = ((u_select - p_env - p_area) / p_dir).min(1.0 - f32::EPSILON);
            let index = selection.sample(u);
            let pdf = p_dir * selection.pmf(index);
            return match &self.delta[index] {
                DeltaLight::Directional(light) => Some(LightSample {
                    wi: -light.direction,
                    dist: f32::INFINITY,
                    point: Vec3::ZERO,
                    radiance: light.irradiance,
                    pdf,
                    delta: true,
                }),
                DeltaLight::Point {
                    position,
                    intensity,
                } => from_position(*position, p, pdf, |_, dist2| *intensity / dist2),
                DeltaLight::Spot(light) => from_position(light.position, p, pdf, |d, dist2| {
                    light.intensity_towards(d) / dist2
                }),
                DeltaLight::Projector(light) => {
                    from_position(light.position, p, pdf, |_, _| light.arriving_at(p))
                }
            };
        }
        let selection = self.selection.as_ref()?;
        let u_select = if self.delta_selection.is_none() {
            (u_select - p_env) / (1.0 - p_env)
        } else {
            (u_select - p_env) / p_area
        }
        .min(1.0 - f32::EPSILON);
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
        let pmf = selection.pmf(index) * p_area;
        Some(LightSample {
            wi,
            dist,
            point: q,
            radiance: light.radiance,
            pdf: pmf / light.area * dist2 / cos_light,
            delta: false,
        })
    }

    /// Solid-angle density with which [`Lights::sample`] picks area light `index` at a point
    /// at distance `dist` whose normal makes cosine `cos_light` with the direction.
    pub fn pdf_area(&self, index: usize, dist: f32, cos_light: f32) -> f32 {
        let Some(selection) = &self.selection else {
            return 0.0;
        };
        let pmf = selection.pmf(index) * self.area_probability();
        pmf / self.area[index].area * dist * dist / cos_light.abs().max(1e-12)
    }

    /// Solid-angle density of sampling the environment in world direction `dir`.
    pub fn pdf_environment(&self, dir: Vec3) -> f32 {
        match &self.environment_map {
            Some(map) => self.env_probability() * map.pdf(dir),
            None => self.env_probability() / (4.0 * PI),
        }
    }
}

/// The sample of a light at `position` seen from `p`, of density `pdf` (its selection), with
/// the radiance `radiance(direction from the light, distance²)` gives; `None` at the light
/// itself or where it sends nothing.
fn from_position(
    position: Vec3,
    p: Vec3,
    pdf: f32,
    radiance: impl FnOnce(Vec3, f32) -> Rgb,
) -> Option<LightSample> {
    let to = position - p;
    let dist2 = to.length_squared();
    if dist2 <= 0.0 {
        return None;
    }
    let dist = dist2.sqrt();
    let radiance = radiance(-to / dist, dist2);
    (radiance != Rgb::ZERO).then(|| LightSample {
        wi: to / dist,
        dist,
        point: position,
        radiance,
        pdf,
        delta: true,
    })
}
