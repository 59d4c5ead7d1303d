//! Mitsuba 3's `principled` BSDF against ours: values and densities pinned from Mitsuba 3.9.1 at
//! fixed directions, and a smooth white metal's albedo. (The χ² and reciprocity tests of every
//! BSDF, in `tests.rs`, take these BSDFs too.)

use glam::{Vec2, Vec3};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg32;

use super::*;

/// The principled BSDFs of `scripts/scenes/principled-eval.py`'s cases.
pub(super) fn principled(case: usize) -> Material {
    let base = Principled {
        base_color: Vec3::splat(0.5),
        roughness: 0.5,
        anisotropic: 0.0,
        metallic: 0.0,
        spec_tint: 0.0,
        spec_trans: 0.0,
        sheen: 0.0,
        sheen_tint: 0.0,
        clearcoat: 0.0,
        clearcoat_gloss: 0.0,
        flatness: 0.0,
        eta: 1.5,
        rates: [1.0; 3],
    };
    let b = match case {
        0 => Principled {
            base_color: Vec3::new(0.8, 0.3, 0.2),
            roughness: 0.4,
            sheen: 0.5,
            sheen_tint: 0.5,
            clearcoat: 0.7,
            clearcoat_gloss: 0.3,
            spec_tint: 0.3,
            flatness: 0.3,
            ..base
        },
        1 => Principled {
            base_color: Vec3::new(0.9, 0.6, 0.3),
            roughness: 0.25,
            metallic: 0.8,
            // specular 0.6.
            eta: 2.0 / (1.0 - 0.048f32.sqrt()) - 1.0,
            ..base
        },
        2 => Principled {
            base_color: Vec3::new(0.7, 0.9, 0.8),
            roughness: 0.3,
            spec_trans: 0.7,
            metallic: 0.1,
            clearcoat: 0.3,
            eta: 1.45,
            ..base
        },
        _ => Principled {
            base_color: Vec3::new(0.6, 0.8, 0.4),
            roughness: 0.45,
            anisotropic: 0.8,
            spec_trans: 0.5,
            metallic: 0.3,
            clearcoat: 0.4,
            ..base
        },
    };
    Material::new(Bsdf::Principled(Box::new(b)))
}

/// Mitsuba 3.9.1's `principled` at fixed directions (`scripts/scenes/principled-eval.py`):
/// (case of [`principled`], wo, wi, f without the cosine, pdf).
#[allow(
    clippy::type_complexity,
    clippy::excessive_precision,
    clippy::approx_constant
)]
const MITSUBA_PRINCIPLED: [(usize, [f32; 3], [f32; 3], [f32; 3], f32); 24] = [
    (
        0,
        [4.9003329e-01, 9.9334665e-02, 8.6602540e-01],
        [-5.6649408e-01, 4.2318371e-01, 7.0710678e-01],
        [2.5446727e-01, 1.0186538e-01, 7.1345000e-02],
        1.8632412e-01,
    ),
    (
        0,
        [8.6602540e-01, 0.0000000e+00, 5.0000000e-01],
        [-8.6169888e-01, -8.6458275e-02, 5.0000000e-01],
        [1.0323467e+00, 7.4935210e-01, 6.9275314e-01],
        1.9702039e+00,
    ),
    (
        0,
        [9.3822511e-02, 1.4611990e-01, 9.8480775e-01],
        [-6.4371331e-01, -7.4530496e-01, 1.7364818e-01],
        [2.5076317e-01, 9.6849436e-02, 6.6066695e-02],
        3.7458934e-02,
    ),
    (
        0,
        [6.7226724e-01, 3.6726127e-01, 6.4278761e-01],
        [-6.0194276e-01, -2.2547911e-01, -7.6604444e-01],
        [0.0000000e+00, 0.0000000e+00, 0.0000000e+00],
        0.0000000e+00,
    ),
    (
        0,
        [7.3183021e-01, 2.2638161e-01, -6.4278761e-01],
        [-2.0807342e-01, 4.5464871e-01, -8.6602540e-01],
        [0.0000000e+00, 0.0000000e+00, 0.0000000e+00],
        4.5006339e-02,
    ),
    (
        0,
        [4.6791552e-01, 7.2873525e-01, -5.0000000e-01],
        [-2.2355928e-01, -2.5884170e-01, 9.3969262e-01],
        [0.0000000e+00, 0.0000000e+00, 0.0000000e+00],
        0.0000000e+00,
    ),
    (
        1,
        [4.9003329e-01, 9.9334665e-02, 8.6602540e-01],
        [-5.6649408e-01, 4.2318371e-01, 7.0710678e-01],
        [9.0989240e-02, 6.0817771e-02, 3.0646288e-02],
        6.4746194e-02,
    ),
    (
        1,
        [8.6602540e-01, 0.0000000e+00, 5.0000000e-01],
        [-8.6169888e-01, -8.6458275e-02, 5.0000000e-01],
        [7.2214503e+00, 4.9566689e+00, 2.6918879e+00],
        4.0611854e+00,
    ),
    (
        1,
        [9.3822511e-02, 1.4611990e-01, 9.8480775e-01],
        [-6.4371331e-01, -7.4530496e-01, 1.7364818e-01],
        [6.3445980e-02, 4.2368843e-02, 2.1291702e-02],
        1.1587850e-02,
    ),
    (
        1,
        [6.7226724e-01, 3.6726127e-01, 6.4278761e-01],
        [-6.0194276e-01, -2.2547911e-01, -7.6604444e-01],
        [0.0000000e+00, 0.0000000e+00, 0.0000000e+00],
        0.0000000e+00,
    ),
    (
        1,
        [7.3183021e-01, 2.2638161e-01, -6.4278761e-01],
        [-2.0807342e-01, 4.5464871e-01, -8.6602540e-01],
        [0.0000000e+00, 0.0000000e+00, 0.0000000e+00],
        7.8648878e-03,
    ),
    (
        1,
        [4.6791552e-01, 7.2873525e-01, -5.0000000e-01],
        [-2.2355928e-01, -2.5884170e-01, 9.3969262e-01],
        [0.0000000e+00, 0.0000000e+00, 0.0000000e+00],
        0.0000000e+00,
    ),
    (
        2,
        [4.9003329e-01, 9.9334665e-02, 8.6602540e-01],
        [-5.6649408e-01, 4.2318371e-01, 7.0710678e-01],
        [7.1117517e-02, 9.0084368e-02, 8.0600943e-02],
        7.3501870e-02,
    ),
    (
        2,
        [8.6602540e-01, 0.0000000e+00, 5.0000000e-01],
        [-8.6169888e-01, -8.6458275e-02, 5.0000000e-01],
        [1.5989330e+00, 1.8219024e+00, 1.7104176e+00],
        1.8133156e+00,
    ),
    (
        2,
        [9.3822511e-02, 1.4611990e-01, 9.8480775e-01],
        [-6.4371331e-01, -7.4530496e-01, 1.7364818e-01],
        [5.9442205e-02, 7.5939081e-02, 6.7690640e-02],
        1.6087821e-02,
    ),
    (
        2,
        [6.7226724e-01, 3.6726127e-01, 6.4278761e-01],
        [-6.0194276e-01, -2.2547911e-01, -7.6604444e-01],
        [2.7535276e-01, 3.1222066e-01, 2.9436448e-01],
        3.9466268e-01,
    ),
    (
        2,
        [7.3183021e-01, 2.2638161e-01, -6.4278761e-01],
        [-2.0807342e-01, 4.5464871e-01, -8.6602540e-01],
        [5.1358262e-04, 5.1358262e-04, 5.1358262e-04],
        7.0646923e-04,
    ),
    (
        2,
        [4.6791552e-01, 7.2873525e-01, -5.0000000e-01],
        [-2.2355928e-01, -2.5884170e-01, 9.3969262e-01],
        [0.0000000e+00, 0.0000000e+00, 0.0000000e+00],
        0.0000000e+00,
    ),
    (
        3,
        [4.9003329e-01, 9.9334665e-02, 8.6602540e-01],
        [-5.6649408e-01, 4.2318371e-01, 7.0710678e-01],
        [7.6345012e-02, 1.0064542e-01, 5.2044588e-02],
        7.7695578e-02,
    ),
    (
        3,
        [8.6602540e-01, 0.0000000e+00, 5.0000000e-01],
        [-8.6169888e-01, -8.6458275e-02, 5.0000000e-01],
        [6.7819041e-01, 8.3914614e-01, 5.1723450e-01],
        7.9034632e-01,
    ),
    (
        3,
        [9.3822511e-02, 1.4611990e-01, 9.8480775e-01],
        [-6.4371331e-01, -7.4530496e-01, 1.7364818e-01],
        [7.2036098e-02, 9.5517027e-02, 4.8555169e-02],
        2.0419858e-02,
    ),
    (
        3,
        [6.7226724e-01, 3.6726127e-01, 6.4278761e-01],
        [-6.0194276e-01, -2.2547911e-01, -7.6604444e-01],
        [1.9599312e+00, 2.2631335e+00, 1.6002771e+00],
        3.0749321e+00,
    ),
    (
        3,
        [7.3183021e-01, 2.2638161e-01, -6.4278761e-01],
        [-2.0807342e-01, 4.5464871e-01, -8.6602540e-01],
        [2.9004386e-04, 2.9004386e-04, 2.9004386e-04],
        7.1975111e-04,
    ),
    (
        3,
        [4.6791552e-01, 7.2873525e-01, -5.0000000e-01],
        [-2.2355928e-01, -2.5884170e-01, 9.3969262e-01],
        [0.0000000e+00, 0.0000000e+00, 0.0000000e+00],
        0.0000000e+00,
    ),
];

#[test]
fn principled_matches_mitsuba_eval_and_pdf() {
    for (case, wo, wi, f, pdf) in MITSUBA_PRINCIPLED {
        let m = principled(case);
        let (wo, wi, f) = (Vec3::from(wo), Vec3::from(wi), Vec3::from(f));
        let got = m.f(wo, wi);
        assert!(
            (got - f).abs().max_element() <= 2e-4 * f.max_element().max(1.0),
            "case {case} wo={wo} wi={wi}: f = {got}, Mitsuba {f}"
        );
        // Mitsuba gives an opaque BSDF seen from below a density it never samples (its sample
        // returns nothing there); ours is zero, as its sampling.
        let opaque_from_below = wo.z < 0.0 && case < 2;
        let want = if opaque_from_below { 0.0 } else { pdf };
        let got = m.pdf(wo, wi);
        assert!(
            (got - want).abs() <= 2e-4 * want.max(1.0),
            "case {case} wo={wo} wi={wi}: pdf = {got}, Mitsuba {pdf}"
        );
    }
}

#[test]
fn smooth_white_principled_metal_reflects_all_light() {
    // A white metal at roughness 0.03 is a mirror with Schlick F = 1: albedo 1 less a sliver
    // of shadowing, whatever the angle. Estimated by the BSDF's own samples.
    let mut m = principled(1);
    if let Bsdf::Principled(p) = &mut m.bsdf {
        p.base_color = Vec3::ONE;
        p.metallic = 1.0;
        p.roughness = 0.03;
    }
    let mut rng = Pcg32::seed_from_u64(9);
    for theta in [0.2f32, 0.8, 1.2] {
        let wo = Vec3::new(theta.sin(), 0.0, theta.cos());
        let n = 20_000;
        let mut sum = 0.0f64;
        for _ in 0..n {
            let u = Vec2::new(rng.random(), rng.random());
            if let Some(s) = m.sample(wo, rng.random(), u) {
                sum += f64::from(s.f.x * s.wi.z.abs() / s.pdf);
            }
        }
        let albedo = sum / n as f64;
        assert!((albedo - 1.0).abs() < 5e-3, "θ = {theta}: albedo {albedo}");
    }
}
