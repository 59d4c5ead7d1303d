//! Rays, orthonormal frames and the small vector helpers every other module shares.
//!
//! Directions in a BSDF's local frame follow pbrt's convention: the shading normal is +z, `wo`
//! points back towards the camera (where the path came from) and `wi` towards the next vertex.
//! The orthonormal basis is built with the branchless construction of Duff et al. 2017,
//! "Building an Orthonormal Basis, Revisited" (JCGT 6(1)).

use glam::Vec3;

/// RGB radiance or reflectance, linear (no gamma), as in Mitsuba 3's `rgb` variants.
pub type Rgb = Vec3;

/// A ray `origin + t * dir` with `dir` of unit length.
#[derive(Clone, Copy, Debug)]
pub struct Ray {
    /// Where the ray starts.
    pub origin: Vec3,
    /// Unit direction.
    pub dir: Vec3,
}

impl Ray {
    /// A ray from `origin` along the unit vector `dir`.
    pub fn new(origin: Vec3, dir: Vec3) -> Self {
        Self { origin, dir }
    }

    /// The point at distance `t` along the ray.
    pub fn at(&self, t: f32) -> Vec3 {
        self.origin + t * self.dir
    }
}

/// Relative size of the offset that moves a spawned ray's origin off its surface, so that it
/// does not hit the surface it leaves again (floating-point self-intersection).
pub const RAY_EPSILON: f32 = 1e-4;

/// The origin for a ray leaving surface point `p` (geometric normal `ng`) in direction `dir`:
/// `p` pushed along `ng` to the side `dir` goes to, by an offset that grows with `|p|`.
pub fn offset_origin(p: Vec3, ng: Vec3, dir: Vec3) -> Vec3 {
    let scale = RAY_EPSILON * (1.0 + p.abs().max_element());
    if ng.dot(dir) >= 0.0 {
        p + scale * ng
    } else {
        p - scale * ng
    }
}

/// An orthonormal frame `(s, t, n)`; `to_local` maps world vectors to coordinates in it.
#[derive(Clone, Copy, Debug)]
pub struct Frame {
    /// First tangent.
    pub s: Vec3,
    /// Second tangent.
    pub t: Vec3,
    /// Normal (local +z).
    pub n: Vec3,
}

impl Frame {
    /// A frame around the unit normal `n` (Duff et al. 2017, listing 3).
    pub fn from_normal(n: Vec3) -> Self {
        let sign = 1.0f32.copysign(n.z);
        let a = -1.0 / (sign + n.z);
        let b = n.x * n.y * a;
        let s = Vec3::new(1.0 + sign * n.x * n.x * a, sign * b, -sign * n.x);
        let t = Vec3::new(b, sign + n.y * n.y * a, -n.y);
        Self { s, t, n }
    }

    /// Mitsuba 3's shading frame: `s` is `dpdu` made orthogonal to the unit normal `n`,
    /// `t = n × s`; [`Frame::from_normal`] where `dpdu` is degenerate.
    pub fn from_normal_tangent(n: Vec3, dpdu: Vec3) -> Self {
        match (dpdu - n * n.dot(dpdu)).try_normalize() {
            Some(s) => Self {
                s,
                t: n.cross(s),
                n,
            },
            None => Self::from_normal(n),
        }
    }

    /// World vector to local coordinates.
    pub fn to_local(&self, v: Vec3) -> Vec3 {
        Vec3::new(v.dot(self.s), v.dot(self.t), v.dot(self.n))
    }

    /// Local coordinates to world vector.
    pub fn to_world(&self, v: Vec3) -> Vec3 {
        v.x * self.s + v.y * self.t + v.z * self.n
    }
}

/// Mirror `w` about the local +z axis (perfect specular reflection in a local frame).
pub fn reflect_z(w: Vec3) -> Vec3 {
    Vec3::new(-w.x, -w.y, w.z)
}

/// Mirror `w` about the unit vector `m`.
pub fn reflect(w: Vec3, m: Vec3) -> Vec3 {
    2.0 * w.dot(m) * m - w
}

/// Rec. 709 luminance of a linear RGB value.
pub fn luminance(c: Rgb) -> f32 {
    0.212_671 * c.x + 0.715_160 * c.y + 0.072_169 * c.z
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn frame_is_orthonormal_for_all_normal_signs() {
        for n in [
            Vec3::Z,
            -Vec3::Z,
            Vec3::new(0.3, -0.5, 0.8).normalize(),
            Vec3::new(0.3, 0.5, -0.8).normalize(),
            Vec3::X,
        ] {
            let f = Frame::from_normal(n);
            assert!((f.s.length() - 1.0).abs() < 1e-5);
            assert!((f.t.length() - 1.0).abs() < 1e-5);
            assert!(f.s.dot(f.t).abs() < 1e-5 && f.s.dot(n).abs() < 1e-5);
            let v = Vec3::new(0.2, -0.7, 0.4);
            assert!((f.to_world(f.to_local(v)) - v).length() < 1e-5);
        }
    }

    #[test]
    fn a_tangent_frame_follows_dpdu_projected_onto_the_normal() {
        let n = Vec3::new(0.0, 0.6, 0.8);
        let f = Frame::from_normal_tangent(n, Vec3::new(2.0, 1.0, 0.0));
        let s = Vec3::new(2.0, 0.64, -0.48).normalize();
        assert!((f.s - s).length() < 1e-5 && (f.t - n.cross(s)).length() < 1e-5);
        assert!(f.s.cross(f.t).dot(n) > 0.999);
        // Degenerate: along the normal, or zero.
        for d in [n * 3.0, Vec3::ZERO] {
            let f = Frame::from_normal_tangent(n, d);
            assert_eq!(f.s, Frame::from_normal(n).s);
        }
    }
}
