//! Where the neural guide's flow lives: a map from a vertex's incident directions to the unit
//! square, in the local frame of the vertex.
//!
//! The frame's normal is the shading normal turned to `ω_o`'s side. Where the material cannot
//! transmit light, everything it scatters leaves on that side (one-sided BSDFs seen from the
//! back scatter nothing), so the square covers only that hemisphere, with the area-preserving
//! map `(u, v) = (cos θ, φ/2π)`: `dω = dcos θ dφ = 2π du dv`, so a density `q` on the square is
//! the solid-angle density `q/2π` and no probability lies below the surface. Where the material
//! transmits, the square covers the whole sphere with the cylindrical map
//! `((cos θ + 1)/2, φ/2π)` of [`super::dir_to_cylindrical`] (density `q/4π`), in the same local
//! frame. The idea of learning in the hemisphere of the normal is the one Müller et al. (2019,
//! §5.1) and later neural guides (e.g. Dong et al. 2023) use for opaque surfaces.
//!
//! The tangents come from a fixed reference direction projected onto the plane of the normal,
//! so they vary continuously with the normal (except where it is parallel to the reference,
//! which no face of the built-in scenes is): a flow conditioned on the normal sees similar
//! local coordinates at similar vertices. A frame that flips its tangents where a coordinate of
//! the normal changes sign (pbrt's and Duff et al.'s branchless frame) would rotate φ by π
//! between vertices whose normals differ by a rounding error.
//!
//! ```
//! use glam::{Vec2, Vec3};
//! use nis_render::guiding::directions::DirectionMap;
//! use nis_render::guiding::GuideVertex;
//!
//! let v = GuideVertex { p: Vec3::ZERO, n: Vec3::Z, wo: Vec3::Z, transmissive: false };
//! let map = DirectionMap::new(&v);
//! assert!(map.to_square(-Vec3::Z).is_none()); // below the surface: not on the square
//! let x = map.to_square(Vec3::new(0.6, 0.0, 0.8)).unwrap();
//! assert!((x.x - 0.8).abs() < 1e-6); // u = cos θ
//! assert!((map.to_direction(x) - Vec3::new(0.6, 0.0, 0.8)).length() < 1e-5);
//! ```

use glam::{Vec2, Vec3};

use serde::{Deserialize, Serialize};

use super::{cylindrical_to_dir, dir_to_cylindrical, GuideVertex, ONE_MINUS_EPSILON};

/// How far below the surface, in cos θ, a direction still counts as on the horizon: a few
/// f32 roundings of a unit vector's components.
const HORIZON: f32 = 1e-6;

/// 1/(2π): solid-angle density per unit density on the square, hemisphere map.
pub const INV_TWO_PI: f32 = 0.5 * std::f32::consts::FRAC_1_PI;
/// 1/(4π): solid-angle density per unit density on the square, sphere map.
pub const INV_FOUR_PI: f32 = 0.25 * std::f32::consts::FRAC_1_PI;

/// The reference direction the tangents are projected from: parallel to no axis, so no face of
/// an axis-aligned scene has it as its normal.
const TANGENT_REFERENCE: Vec3 = Vec3::new(0.267_261_24, 0.534_522_5, 0.801_783_7);

/// Which frame the neural guide's flow works in.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum GuideFrame {
    /// World-space cylindrical coordinates on the whole sphere at every vertex
    /// ([`DirectionMap::WORLD`]): one direction has the same coordinates everywhere.
    #[default]
    World,
    /// The local frame of the vertex, over the hemisphere where the material is opaque
    /// ([`DirectionMap::new`]).
    Local,
}

/// The map of one vertex's incident directions to the unit square (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DirectionMap {
    /// Tangents and normal (turned to `ω_o`'s side) of the local frame.
    s: Vec3,
    t: Vec3,
    n: Vec3,
    /// Upper hemisphere only (the material does not transmit).
    hemisphere: bool,
}

impl DirectionMap {
    /// World-space cylindrical coordinates `((cos θ + 1)/2, φ/2π)`, θ from +z, on the sphere.
    pub const WORLD: DirectionMap = DirectionMap {
        s: Vec3::X,
        t: Vec3::Y,
        n: Vec3::Z,
        hemisphere: false,
    };

    /// The map at vertex `v` in `frame`.
    pub fn in_frame(v: &GuideVertex, frame: GuideFrame) -> Self {
        match frame {
            GuideFrame::World => Self::WORLD,
            GuideFrame::Local => Self::new(v),
        }
    }

    /// The local map at vertex `v`.
    pub fn new(v: &GuideVertex) -> Self {
        let n = if v.n.dot(v.wo) < 0.0 { -v.n } else { v.n };
        let s = (TANGENT_REFERENCE - TANGENT_REFERENCE.dot(n) * n)
            .try_normalize()
            .unwrap_or_else(|| n.any_orthonormal_vector());
        // Once more: near the reference the first projection keeps a rounding error of
        // ε/|sin| along the normal.
        let s = (s - s.dot(n) * n).normalize();
        DirectionMap {
            s,
            t: n.cross(s),
            n,
            hemisphere: !v.transmissive,
        }
    }

    /// Whether the square covers only the hemisphere around the normal.
    pub fn is_hemisphere(&self) -> bool {
        self.hemisphere
    }

    /// The frame's normal: the shading normal on `ω_o`'s side.
    pub fn normal(&self) -> Vec3 {
        self.n
    }

    /// Solid-angle density per unit density on the square (constant: both maps preserve area).
    pub fn jacobian(&self) -> f32 {
        jacobian(self.hemisphere)
    }

    /// World direction in local coordinates.
    pub fn to_local(&self, w: Vec3) -> Vec3 {
        Vec3::new(w.dot(self.s), w.dot(self.t), w.dot(self.n))
    }

    /// The point of the square of world direction `w`; `None` below the surface of a
    /// hemisphere map (where its density is zero).
    pub fn to_square(&self, w: Vec3) -> Option<Vec2> {
        let l = self.to_local(w);
        if !self.hemisphere {
            return Some(dir_to_cylindrical(l));
        }
        // A direction sampled at the horizon (cos θ = u ≈ 0) comes back from the world frame
        // with a rounding error of the order of 10⁻⁷ in its normal component, of either sign:
        // read as the horizon, so that the density of what was sampled is what was sampled with.
        if l.z < -HORIZON {
            return None;
        }
        Some(Vec2::new(
            l.z.clamp(0.0, ONE_MINUS_EPSILON),
            dir_to_cylindrical(l).y,
        ))
    }

    /// The world direction of point `x` of the square.
    pub fn to_direction(&self, x: Vec2) -> Vec3 {
        let l = if self.hemisphere {
            let cos_theta = x.x.clamp(0.0, 1.0);
            let sin_theta = (1.0 - cos_theta * cos_theta).max(0.0).sqrt();
            let (sin_phi, cos_phi) = (2.0 * std::f32::consts::PI * x.y).sin_cos();
            Vec3::new(sin_theta * cos_phi, sin_theta * sin_phi, cos_theta)
        } else {
            cylindrical_to_dir(x)
        };
        l.x * self.s + l.y * self.t + l.z * self.n
    }
}

/// Solid-angle density per unit density on the square of a hemisphere or a sphere map.
pub fn jacobian(hemisphere: bool) -> f32 {
    if hemisphere {
        INV_TWO_PI
    } else {
        INV_FOUR_PI
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_pcg::Pcg64Mcg;

    fn unit(rng: &mut Pcg64Mcg) -> Vec3 {
        loop {
            let v = Vec3::new(rng.random(), rng.random(), rng.random()) * 2.0 - 1.0;
            if (0.01..=1.0).contains(&v.length_squared()) {
                return v.normalize();
            }
        }
    }

    #[test]
    fn maps_round_trip_and_keep_opaque_directions_above_the_surface() {
        let mut rng = Pcg64Mcg::seed_from_u64(3);
        for i in 0..20_000 {
            let v = GuideVertex {
                p: Vec3::ZERO,
                n: unit(&mut rng),
                wo: unit(&mut rng),
                transmissive: i % 2 == 0,
            };
            let map = DirectionMap::new(&v);
            // An orthonormal frame whose normal faces ω_o.
            assert!(
                (map.s.dot(map.t)).abs() < 1e-5 && (map.s.dot(map.n)).abs() < 1e-5,
                "{map:?} {v:?}"
            );
            assert!((map.t.length() - 1.0).abs() < 1e-5 && map.n.dot(v.wo) >= 0.0);
            let x = Vec2::new(rng.random(), rng.random());
            let w = map.to_direction(x);
            assert!((w.length() - 1.0).abs() < 1e-5);
            if map.is_hemisphere() {
                assert!(w.dot(map.n) >= -1e-6, "{w} below {}", map.n);
            }
            let y = map.to_square(w).unwrap();
            assert!((x.x - y.x).abs() < 2e-4, "{x} -> {y}");
            let dv = (x.y - y.y).abs();
            assert!(dv.min(1.0 - dv) < 2e-4, "{x} -> {y}");
            // Below the surface there is no point of a hemisphere map.
            let below = w - 2.0 * w.dot(map.n) * map.n;
            if map.is_hemisphere() && below.dot(map.n) < -1e-3 {
                assert!(map.to_square(below).is_none());
            }
        }
    }

    #[test]
    fn uniform_square_density_integrates_to_one_over_the_sphere() {
        // The Jacobian is the solid angle each map covers, inverted: the square's uniform
        // density is 1/(2π) on the hemisphere and 0 below it, or 1/(4π) on the sphere. Midpoint
        // rule over a fine grid of the sphere in world coordinates (exact up to the grid's
        // error at the horizon, ≈ 1/(2·512) of the hemisphere's band there).
        for transmissive in [false, true] {
            let v = GuideVertex {
                p: Vec3::ZERO,
                n: Vec3::new(0.3, -0.5, 0.2).normalize(),
                wo: Vec3::new(-0.2, -0.9, 0.1).normalize(),
                transmissive,
            };
            let map = DirectionMap::new(&v);
            let m = 512;
            let mut total = 0.0f64;
            for i in 0..m {
                for j in 0..m {
                    let c = Vec2::new((i as f32 + 0.5) / m as f32, (j as f32 + 0.5) / m as f32);
                    let w = cylindrical_to_dir(c);
                    let pdf = map.to_square(w).map_or(0.0, |_| map.jacobian());
                    total += f64::from(pdf) * 4.0 * std::f64::consts::PI / (m * m) as f64;
                }
            }
            assert!((total - 1.0).abs() < 3e-3, "{transmissive}: {total}");
        }
    }
}
