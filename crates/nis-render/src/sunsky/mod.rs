//! Mitsuba 3's `sunsky` emitter: the sky of Hosek & Wilkie's analytic model ("An Analytic Model
//! for Full Spectral Sky-Dome Radiance", SIGGRAPH 2012) and the sun's disk of their solar
//! radiance function (2013), with Mitsuba 3.9's tables, parameters and RGB reduction
//! (`src/emitters/sunsky.cpp`, `include/mitsuba/render/sunsky.h`): radiance infinitely far
//! away, in a frame where z is up and the ground (z < 0) sends nothing, turned into the scene
//! by `to_world`; the sun stands at `sun_direction` or where the date, time and place put it
//! ([`position`]).
//!
//! Light sampling mixes two strategies in proportion to their estimated power: a direction
//! uniformly in the sun's cone, and one from a table over the hemisphere proportional to the
//! sky's radiance ([`table`]); a direction's density is the mixture's, so that multiple
//! importance sampling with the BSDF sees one light. As in Mitsuba, a direction drawn from the
//! sun's cone counts as inside the disk even when rounding puts it a hair outside.
//!
//! The tables come from Mitsuba's data files ([`dataset`]), which are not part of nis.

pub mod dataset;
pub mod model;
pub mod position;
pub mod table;

#[cfg(test)]
mod tests;

use glam::{Mat3, Vec2, Vec3};

use crate::envmap::EnvSample;
use crate::geometry::{Frame, Rgb};
pub use dataset::Dataset;
pub use model::SUN_APERTURE_DEG;
use model::{one_minus_cos_radius, SkyModel, SunModel};
pub use position::{DateTime, Location};
use table::HemisphereTable;

/// Where the sun stands.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SunPosition {
    /// A world direction towards the sun (Mitsuba's `sun_direction`).
    Direction(Vec3),
    /// The place and the local time of an observer (in the emitter's frame: z up, x north).
    Time {
        /// Date and local time.
        time: DateTime,
        /// Latitude, longitude and timezone.
        location: Location,
    },
}

/// The `sunsky` emitter's parameters, with Mitsuba 3's names and defaults.
#[derive(Clone, Debug, PartialEq)]
pub struct SunSkyParams {
    /// Atmospheric turbidity, 1 to 10 (default 3).
    pub turbidity: f32,
    /// Ground albedo per channel, 0 to 1 (default 0.3).
    pub albedo: Rgb,
    /// The sun's position (default: Tokyo, 10 July 2010, 15:00).
    pub sun: SunPosition,
    /// Scale of the sun's radiance (default 1).
    pub sun_scale: f32,
    /// Scale of the sky's radiance (default 1).
    pub sky_scale: f32,
    /// The sun's full apparent diameter in degrees, in (0, 180) (default 0.5358); its
    /// irradiance does not change with it.
    pub sun_aperture: f32,
    /// The limb-darkened sun (default false: uniform).
    pub complex_sun: bool,
    /// Emitter to world: a rotation or reflection, possibly uniformly scaled.
    pub to_world: Mat3,
}

impl Default for SunSkyParams {
    fn default() -> Self {
        SunSkyParams {
            turbidity: 3.0,
            albedo: Rgb::splat(0.3),
            sun: SunPosition::Time {
                time: DateTime::default(),
                location: Location::default(),
            },
            sun_scale: 1.0,
            sky_scale: 1.0,
            sun_aperture: SUN_APERTURE_DEG,
            complex_sun: false,
            to_world: Mat3::IDENTITY,
        }
    }
}

/// Why [`SunSky::new`] refuses parameters.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ParamError {
    /// A parameter out of its range.
    #[error("{name} = {value} is out of range ({range})")]
    OutOfRange {
        /// The parameter.
        name: &'static str,
        /// Its value.
        value: String,
        /// What it must be.
        range: &'static str,
    },
    /// `to_world` is not a rotation or reflection times a scale.
    #[error("to_world must be a rotation (or reflection), possibly uniformly scaled")]
    NotARotation,
}

impl SunSkyParams {
    fn check(&self) -> Result<(), ParamError> {
        let out = |name, value: String, range| Err(ParamError::OutOfRange { name, value, range });
        if !(1.0..=10.0).contains(&self.turbidity) {
            return out("turbidity", self.turbidity.to_string(), "1 to 10");
        }
        if !self
            .albedo
            .to_array()
            .iter()
            .all(|a| (0.0..=1.0).contains(a))
        {
            return out("albedo", format!("{}", self.albedo), "0 to 1 per channel");
        }
        for (name, v) in [("sun_scale", self.sun_scale), ("sky_scale", self.sky_scale)] {
            if !(v >= 0.0 && v.is_finite()) {
                return out(name, v.to_string(), "0 or more");
            }
        }
        if !(self.sun_aperture > 0.0 && self.sun_aperture < 180.0) {
            return out(
                "sun_aperture",
                self.sun_aperture.to_string(),
                "0 to 180 degrees, exclusive",
            );
        }
        if let SunPosition::Direction(d) = self.sun {
            if !(d.length_squared() > 0.0 && d.is_finite()) {
                return out("sun_direction", format!("{d}"), "a non-zero vector");
            }
        }
        Ok(())
    }
}

/// `to_world` without its uniform scale, or `None` when it is not a scaled rotation.
fn orthonormal(m: Mat3) -> Option<Mat3> {
    let cols = [m.x_axis, m.y_axis, m.z_axis];
    let len = cols.map(Vec3::length);
    if !(len[0] > 0.0 && len[0].is_finite()) {
        return None;
    }
    let unit = cols.map(|c| c / len[0]);
    let tol = 1e-4;
    let ok = len.iter().all(|l| (l / len[0] - 1.0).abs() < tol)
        && unit[0].dot(unit[1]).abs() < tol
        && unit[0].dot(unit[2]).abs() < tol
        && unit[1].dot(unit[2]).abs() < tol;
    ok.then(|| Mat3::from_cols(unit[0], unit[1], unit[2]))
}

/// The angle between unit vectors `a` and `b`, accurate near 0 and π (Dr.Jit's `unit_angle`).
fn unit_angle(a: Vec3, b: Vec3) -> f32 {
    let d = a.dot(b);
    if d >= 0.0 {
        2.0 * (0.5 * (a - b).length()).min(1.0).asin()
    } else {
        std::f32::consts::PI - 2.0 * (0.5 * (a + b).length()).min(1.0).asin()
    }
}

/// The sun and sky, ready to evaluate and sample.
#[derive(Clone, Debug)]
pub struct SunSky {
    to_world: Mat3,
    to_local: Mat3,
    /// Unit direction towards the sun's centre, local.
    sun_dir: Vec3,
    sun_frame: Frame,
    /// `cos` and `1 − cos` of the disk's angular radius.
    cos_radius: f32,
    one_minus_cos_radius: f32,
    sky: Option<SkyModel>,
    sun: Option<SunModel>,
    table: Option<HemisphereTable>,
    /// Probability of sampling the sun's cone rather than the sky's table.
    p_sun: f32,
}

impl SunSky {
    /// The emitter of `params` with the tables of `data`; `None` when it sends nothing (the
    /// sun below the horizon, which darkens the sky too in Mitsuba 3, or both scales zero).
    pub fn new(params: &SunSkyParams, data: &Dataset) -> Result<Option<SunSky>, ParamError> {
        params.check()?;
        let to_world = orthonormal(params.to_world).ok_or(ParamError::NotARotation)?;
        let to_local = to_world.transpose();
        let sun_dir = match params.sun {
            SunPosition::Direction(d) => (to_local * d).normalize(),
            SunPosition::Time { time, location } => {
                let (theta, phi) = position::sun_coordinates(&time, &location);
                position::spherical_direction(theta, phi)
            }
        };
        if sun_dir.z < 0.0 || (params.sun_scale == 0.0 && params.sky_scale == 0.0) {
            return Ok(None);
        }
        // The sun's elevation above the horizon.
        let eta = std::f32::consts::FRAC_PI_2 - unit_angle(sun_dir, Vec3::Z);
        let sky = (params.sky_scale > 0.0)
            .then(|| SkyModel::new(data, params.turbidity, params.albedo, eta, params.sky_scale));
        let sun = (params.sun_scale > 0.0).then(|| {
            SunModel::new(
                data,
                params.turbidity,
                eta,
                params.sun_scale,
                params.sun_aperture,
                params.complex_sun,
            )
        });
        let one_minus = one_minus_cos_radius(params.sun_aperture);
        let importance = |c: Rgb| c.max(Rgb::ZERO).element_sum() / 3.0;
        let table = sky.as_ref().and_then(|s| {
            HemisphereTable::new(|d| importance(s.eval(d.z, unit_angle(sun_dir, d))))
        });
        // The sun's power: its centre's radiance over the disk's solid angle.
        let sun_power = sun.as_ref().map_or(0.0, |s| {
            f64::from(importance(s.eval(sun_dir.z, 0.0)))
                * 2.0
                * std::f64::consts::PI
                * f64::from(one_minus)
        });
        let sky_power = table.as_ref().map_or(0.0, HemisphereTable::total);
        let total = sun_power + sky_power;
        if total.is_nan() || total <= 0.0 {
            return Ok(None);
        }
        let p_sun = (sun_power / (sun_power + sky_power)) as f32;
        Ok(Some(SunSky {
            to_world,
            to_local,
            sun_dir,
            sun_frame: Frame::from_normal(sun_dir),
            cos_radius: 1.0 - one_minus,
            one_minus_cos_radius: one_minus,
            sky,
            sun: sun.filter(|_| p_sun > 0.0),
            table,
            p_sun,
        }))
    }

    /// World direction towards the sun's centre.
    pub fn sun_direction(&self) -> Vec3 {
        self.to_world * self.sun_dir
    }

    fn local(&self, dir: Vec3) -> Vec3 {
        (self.to_local * dir).normalize_or_zero()
    }

    fn in_sun(&self, d: Vec3) -> bool {
        self.sun.is_some() && d.dot(self.sun_dir) >= self.cos_radius
    }

    /// Radiance at local unit direction `d`, the sun's disk included when `in_sun`.
    fn radiance(&self, d: Vec3, in_sun: bool) -> Rgb {
        if d.z < 0.0 {
            return Rgb::ZERO;
        }
        let gamma = unit_angle(self.sun_dir, d);
        let mut l = self.sky.as_ref().map_or(Rgb::ZERO, |s| s.eval(d.z, gamma));
        if in_sun {
            if let Some(sun) = &self.sun {
                l += sun.eval(d.z, gamma);
            }
        }
        l
    }

    /// Density of local unit direction `d`, the sun's cone counted when `in_sun`.
    fn density(&self, d: Vec3, in_sun: bool) -> f32 {
        let sky = self.table.as_ref().map_or(0.0, |t| t.pdf(d));
        let sun = if in_sun {
            1.0 / (std::f32::consts::TAU * self.one_minus_cos_radius)
        } else {
            0.0
        };
        (1.0 - self.p_sun) * sky + self.p_sun * sun
    }

    /// Radiance arriving from world direction `dir` (pointing away from the scene).
    pub fn eval(&self, dir: Vec3) -> Rgb {
        let d = self.local(dir);
        self.radiance(d, self.in_sun(d))
    }

    /// Solid-angle density of [`SunSky::sample`] for world direction `dir`.
    pub fn pdf(&self, dir: Vec3) -> f32 {
        let d = self.local(dir);
        self.density(d, self.in_sun(d))
    }

    /// Draw a direction from two uniform numbers; `None` when it falls below the horizon
    /// (from a sun's cone that crosses it).
    pub fn sample(&self, u: Vec2) -> Option<EnvSample> {
        let (d, in_sun) = if u.x < self.p_sun {
            let ux = (u.x / self.p_sun).min(1.0);
            // Uniform in the cone: 1 − cos θ uniform in [0, 1 − cos θ_max].
            let one_minus = ux * self.one_minus_cos_radius;
            let cos = 1.0 - one_minus;
            let sin = (one_minus * (2.0 - one_minus)).max(0.0).sqrt();
            let (s, c) = (std::f32::consts::TAU * u.y).sin_cos();
            let d = self.sun_frame.to_world(Vec3::new(sin * c, sin * s, cos));
            (d.normalize(), true)
        } else {
            let ux = ((u.x - self.p_sun) / (1.0 - self.p_sun)).min(1.0);
            let d = self.table.as_ref()?.sample(Vec2::new(ux, u.y))?;
            (d, self.in_sun(d))
        };
        if d.z < 0.0 {
            return None;
        }
        Some(EnvSample {
            wi: (self.to_world * d).normalize(),
            radiance: self.radiance(d, in_sun),
            pdf: self.density(d, in_sun),
        })
    }
}
