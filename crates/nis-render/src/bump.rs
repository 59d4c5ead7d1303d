//! Bump mapping (Blinn, "Simulation of Wrinkled Surfaces", 1978; Mitsuba 3's `bumpmap`): a
//! scalar height texture `h(u, v)` displaces the surface along its shading normal `n`, and the
//! shading normal becomes that of the displaced surface,
//!
//! `n' ∝ (∂p/∂u + (s ∂h/∂u − n·∂p/∂u) n) × (∂p/∂v + (s ∂h/∂v − n·∂p/∂v) n)`,
//!
//! turned to the side of the geometric normal; or a normal map (Mitsuba 3's `normalmap`) gives
//! the new normal itself in the shading frame. Either is mirrored about `n` where it would face away
//! from the viewer (Mitsuba's `flip_invalid_normals`, on by default). As in Mitsuba, a direction
//! on different sides of the two normals scatters nothing, and the BSDF's value is multiplied by
//! the shadowing of Estevez et al., "A Microfacet-Based Shadowing Function to Solve the Bump
//! Terminator Problem" (*Ray Tracing Gems*, ch. 12, 2019), [`BumpShading::factor`], which
//! darkens directions far from the original normal (Mitsuba's `use_shadowing_function`).

use std::sync::Arc;

use glam::{Vec2, Vec3};

use crate::texture::Texture;

/// What a [`Bump`]'s texture holds.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum BumpMap {
    /// A height (the texture's luminance) times `scale` (Mitsuba `bumpmap`).
    Height {
        /// Factor on the height.
        scale: f32,
    },
    /// The shading normal in the shading frame (s, t, n) as 2·rgb − 1, s along ∂p/∂u (Mitsuba
    /// `normalmap`; its texture is read raw).
    Normal,
}

/// A bump or normal map: the texture and what it holds.
#[derive(Clone, Debug, PartialEq)]
pub struct Bump {
    /// The height or the normals.
    pub texture: Arc<Texture>,
    /// Which of the two.
    pub map: BumpMap,
}

impl Bump {
    /// The bumped shading normal at texture coordinates `uv` of a surface with shading normal
    /// `ns`, geometric normal `ng` and derivatives `dpdu`, `dpdv`, seen from direction `wo`.
    pub fn normal(
        &self,
        uv: Vec2,
        ns: Vec3,
        ng: Vec3,
        (dpdu, dpdv): (Vec3, Vec3),
        wo: Vec3,
    ) -> Vec3 {
        let mut n = match self.map {
            BumpMap::Height { scale } => {
                let g = self.texture.eval_scalar_grad(uv) * scale;
                let du = dpdu + (g.x - ns.dot(dpdu)) * ns;
                let dv = dpdv + (g.y - ns.dot(dpdv)) * ns;
                let Some(n) = du.cross(dv).try_normalize() else {
                    return ns;
                };
                if n.dot(ng) < 0.0 {
                    -n
                } else {
                    n
                }
            }
            BumpMap::Normal => {
                let c = self.texture.eval(uv) * 2.0 - Vec3::ONE;
                let s = (dpdu - ns * ns.dot(dpdu))
                    .try_normalize()
                    .unwrap_or_else(|| ns.any_orthonormal_vector());
                let t = ns.cross(s);
                let Some(n) = (s * c.x + t * c.y + ns * c.z).try_normalize() else {
                    return ns;
                };
                n
            }
        };
        if wo.dot(ns) * wo.dot(n) <= 0.0 {
            // Mirror the tilt about the original normal.
            n = (2.0 * n.dot(ns) * ns - n).normalize_or(ns);
        }
        n
    }
}

/// A bump-mapped vertex: the original and the bumped shading normals.
#[derive(Clone, Copy, Debug)]
pub struct BumpShading {
    /// The shading normal before bumping.
    pub original: Vec3,
    /// The bumped shading normal.
    pub bumped: Vec3,
    /// `α² = min(tan²θ/8, 1)` of the bumped normal's angle θ to the original.
    alpha2: f32,
}

impl BumpShading {
    /// The shading of a vertex whose normal `original` was bumped to `bumped`.
    pub fn new(original: Vec3, bumped: Vec3) -> Self {
        let c = bumped.dot(original).clamp(-1.0, 1.0);
        let tan2 = (1.0 - c * c).max(0.0) / (c * c).max(1e-12);
        BumpShading {
            original,
            bumped,
            alpha2: (0.125 * tan2).min(1.0),
        }
    }

    /// Whether direction `w` is on the same side of both normals (else nothing scatters).
    pub fn same_side(&self, w: Vec3) -> bool {
        w.dot(self.original) * w.dot(self.bumped) > 0.0
    }

    /// The factor on the BSDF's value for direction `wi`: zero across the two normals, else
    /// the shadowing `2 / (1 + √(1 + α² tan²θ))`, θ the angle of `wi` to the original normal.
    pub fn factor(&self, wi: Vec3) -> f32 {
        if !self.same_side(wi) {
            return 0.0;
        }
        let c = wi.dot(self.original);
        let tan2 = (1.0 - c * c).max(0.0) / (c * c).max(1e-12);
        2.0 / (1.0 + (1.0 + self.alpha2 * tan2).sqrt())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::texture::{Bitmap, FilterMode, WrapMode};
    use glam::Mat3;

    /// A height ramp h = a·u on the xy-plane tilts the normal to (−a, 0, 1)/|·|.
    #[test]
    fn a_height_ramp_tilts_the_normal_by_its_slope() {
        let texels = (0..64).map(|i| [(i % 8) as f32 / 8.0; 3]).collect();
        let image = Arc::new(
            Bitmap::from_linear(8, 8, texels, FilterMode::Bilinear, WrapMode::Clamp).unwrap(),
        );
        let bump = Bump {
            texture: Arc::new(Texture::Bitmap {
                image,
                to_uv: Mat3::IDENTITY,
            }),
            map: BumpMap::Height { scale: 0.5 },
        };
        let n = bump.normal(
            Vec2::new(0.5, 0.5),
            Vec3::Z,
            Vec3::Z,
            (Vec3::X, Vec3::Y),
            Vec3::Z,
        );
        // ∂h/∂u = 1 per unit u (a step of 1/8 per texel of width 1/8), times the scale.
        let want = Vec3::new(-0.5, 0.0, 1.0).normalize();
        assert!((n - want).length() < 1e-4, "{n} vs {want}");
    }

    #[test]
    fn shadowing_is_one_along_the_normal_and_zero_across_the_normals() {
        let s = BumpShading::new(Vec3::Z, Vec3::new(0.3, 0.0, 1.0).normalize());
        assert!((s.factor(Vec3::Z) - 1.0).abs() < 1e-6);
        let grazing = s.factor(Vec3::new(0.0, 0.99, 0.14).normalize());
        assert!(grazing > 0.0 && grazing < 0.99, "{grazing}");
        // Above the original normal's horizon but below the bumped one's: nothing.
        assert_eq!(s.factor(Vec3::new(-1.0, 0.0, 0.1).normalize()), 0.0);
        let flat = BumpShading::new(Vec3::Z, Vec3::Z);
        assert_eq!(flat.factor(Vec3::new(0.0, 0.9, 0.1).normalize()), 1.0);
    }

    #[test]
    fn a_normal_map_sets_the_normal_in_the_frame_of_dpdu_and_mirrors_it_away_from_the_back() {
        // Every texel (0.75, 0.5, 0.933): the normal (0.5, 0, 0.866), 30° towards ∂p/∂u.
        let texels = vec![[0.75, 0.5, 0.933]; 4];
        let image = Arc::new(
            Bitmap::from_linear(2, 2, texels, FilterMode::Bilinear, WrapMode::Clamp).unwrap(),
        );
        let map = Bump {
            texture: Arc::new(Texture::Bitmap {
                image,
                to_uv: Mat3::IDENTITY,
            }),
            map: BumpMap::Normal,
        };
        // ∂p/∂u along +y (tilted out of the tangent plane, which the frame projects away).
        let d = (Vec3::new(0.0, 2.0, 0.3), Vec3::new(-1.0, 0.0, 0.0));
        let uv = Vec2::splat(0.5);
        let n = map.normal(uv, Vec3::Z, Vec3::Z, d, Vec3::Z);
        assert!(
            (n - Vec3::new(0.0, 0.5, 0.866).normalize()).length() < 1e-3,
            "{n}"
        );
        // Seen from where the tilted normal faces away: mirrored about the shading normal.
        let wo = Vec3::new(0.0, -0.9, 0.2).normalize();
        let m = map.normal(uv, Vec3::Z, Vec3::Z, d, wo);
        assert!(
            (m - Vec3::new(0.0, -0.5, 0.866).normalize()).length() < 1e-3,
            "{m}"
        );
    }
}
