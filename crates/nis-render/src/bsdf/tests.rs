//! Statistical tests of every BSDF: its sampling density matches its `pdf`, integrates to at
//! most one, and the sampled directions pass a χ² goodness-of-fit test against that density
//! (the approach of Mitsuba's and pbrt's BSDF test suites); values are reciprocal.

use std::f32::consts::PI;

use glam::{Vec2, Vec3};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg32;

use super::principled_tests::principled;
use super::*;

fn materials() -> Vec<(&'static str, Material)> {
    let gold_eta = Vec3::new(0.143, 0.374, 1.442);
    let gold_k = Vec3::new(3.983, 2.385, 1.603);
    let mut two_sided = Material::new(Bsdf::Diffuse {
        reflectance: Vec3::splat(0.7),
    });
    two_sided.two_sided = true;
    vec![
        (
            "diffuse",
            Material::new(Bsdf::Diffuse {
                reflectance: Vec3::new(0.8, 0.5, 0.2),
            }),
        ),
        ("twosided diffuse", two_sided),
        (
            "rough conductor 0.3",
            Material::new(Bsdf::RoughConductor {
                dist: Microfacet::ggx(0.3),
                eta: gold_eta,
                k: gold_k,
                specular_reflectance: Vec3::ONE,
            }),
        ),
        (
            "rough conductor 0.7",
            Material::new(Bsdf::RoughConductor {
                dist: Microfacet::ggx(0.7),
                eta: Vec3::ZERO,
                k: Vec3::ONE,
                specular_reflectance: Vec3::ONE,
            }),
        ),
        (
            "rough dielectric 0.4",
            Material::new(Bsdf::RoughDielectric {
                dist: Microfacet::ggx(0.4),
                eta: 1.5,
                specular_reflectance: Vec3::ONE,
                specular_transmittance: Vec3::ONE,
            }),
        ),
        (
            "beckmann conductor 0.3",
            Material::new(Bsdf::RoughConductor {
                dist: beckmann(0.3),
                eta: gold_eta,
                k: gold_k,
                specular_reflectance: Vec3::ONE,
            }),
        ),
        (
            "beckmann dielectric 0.5",
            Material::new(Bsdf::RoughDielectric {
                dist: beckmann(0.5),
                eta: 1.5,
                specular_reflectance: Vec3::ONE,
                specular_transmittance: Vec3::ONE,
            }),
        ),
        (
            "anisotropic ggx conductor 0.05 × 0.4",
            Material::new(Bsdf::RoughConductor {
                dist: anisotropic(MicrofacetKind::Ggx, 0.05, 0.4),
                eta: gold_eta,
                k: gold_k,
                specular_reflectance: Vec3::ONE,
            }),
        ),
        (
            "anisotropic beckmann conductor 0.5 × 0.1",
            Material::new(Bsdf::RoughConductor {
                dist: anisotropic(MicrofacetKind::Beckmann, 0.5, 0.1),
                eta: gold_eta,
                k: gold_k,
                specular_reflectance: Vec3::ONE,
            }),
        ),
        (
            "anisotropic ggx dielectric 0.15 × 0.5",
            Material::new(Bsdf::RoughDielectric {
                dist: anisotropic(MicrofacetKind::Ggx, 0.15, 0.5),
                eta: 1.5,
                specular_reflectance: Vec3::ONE,
                specular_transmittance: Vec3::ONE,
            }),
        ),
        (
            "anisotropic beckmann dielectric 0.4 × 0.1",
            Material::new(Bsdf::RoughDielectric {
                dist: anisotropic(MicrofacetKind::Beckmann, 0.4, 0.1),
                eta: 1.5,
                specular_reflectance: Vec3::ONE,
                specular_transmittance: Vec3::ONE,
            }),
        ),
        (
            "plastic",
            Material::new(Bsdf::Plastic(Box::new(Plastic::new(
                1.49,
                Vec3::new(0.7, 0.3, 0.1),
                Vec3::ONE,
                false,
                None,
            )))),
        ),
        (
            "rough plastic beckmann 0.2",
            Material::new(Bsdf::Plastic(Box::new(Plastic::new(
                1.49,
                Vec3::new(0.2, 0.5, 0.8),
                Vec3::ONE,
                true,
                Some(beckmann(0.2)),
            )))),
        ),
        (
            "blend 0.3 of rough gold over diffuse",
            Material::new(Bsdf::Blend(Box::new(Blend {
                weight: 0.3,
                bsdfs: [
                    Bsdf::Diffuse {
                        reflectance: Vec3::new(0.2, 0.6, 0.3),
                    },
                    Bsdf::RoughConductor {
                        dist: beckmann(0.25),
                        eta: gold_eta,
                        k: gold_k,
                        specular_reflectance: Vec3::ONE,
                    },
                ],
            }))),
        ),
        (
            "blend 0.6 of smooth plastic and rough glass",
            Material::new(Bsdf::Blend(Box::new(Blend {
                weight: 0.6,
                bsdfs: [
                    Bsdf::Plastic(Box::new(Plastic::new(
                        1.49,
                        Vec3::new(0.7, 0.3, 0.1),
                        Vec3::ONE,
                        false,
                        None,
                    ))),
                    Bsdf::RoughDielectric {
                        dist: beckmann(0.4),
                        eta: 1.5,
                        specular_reflectance: Vec3::ONE,
                        specular_transmittance: Vec3::ONE,
                    },
                ],
            }))),
        ),
        (
            "principled: sheen, clearcoat, tint, flatness",
            principled(0),
        ),
        ("principled: metallic", principled(1)),
        ("principled: rough transmission", principled(2)),
        ("principled: anisotropic, transmission", principled(3)),
        ("masked diffuse", {
            let mut m = Material::new(Bsdf::Diffuse {
                reflectance: Vec3::splat(0.6),
            });
            m.opacity = 0.4;
            m
        }),
    ]
}

fn beckmann(alpha: f32) -> Microfacet {
    Microfacet::new(MicrofacetKind::Beckmann, alpha)
}

fn anisotropic(kind: MicrofacetKind, alpha_u: f32, alpha_v: f32) -> Microfacet {
    Microfacet {
        kind,
        alpha_u,
        alpha_v,
    }
}

fn directions() -> Vec<Vec3> {
    let d = |theta_deg: f32, phi: f32, below: bool| {
        let t = theta_deg.to_radians();
        let z = if below { -t.cos() } else { t.cos() };
        Vec3::new(t.sin() * phi.cos(), t.sin() * phi.sin(), z)
    };
    vec![
        d(10.0, 0.3, false),
        d(55.0, 1.0, false),
        d(80.0, 2.0, false),
        d(40.0, 0.7, true),
    ]
}

const COS_BINS: usize = 20;
const PHI_BINS: usize = 40;
const SUB: usize = 16;

fn bin_of(w: Vec3) -> usize {
    let c = ((w.z.clamp(-1.0, 1.0) + 1.0) * 0.5 * COS_BINS as f32) as usize;
    let phi = w.y.atan2(w.x).rem_euclid(2.0 * PI);
    let p = (phi / (2.0 * PI) * PHI_BINS as f32) as usize;
    c.min(COS_BINS - 1) * PHI_BINS + p.min(PHI_BINS - 1)
}

/// Integral of `pdf` over each (cos θ, φ) bin by the midpoint rule on a `SUB × SUB` grid that is
/// uniform in θ (weight `sin θ dθ dφ`), which resolves lobes near the poles.
fn expected_mass(m: &Material, wo: Vec3) -> Vec<f64> {
    let dc = 2.0 / COS_BINS as f32;
    let dp = 2.0 * PI / PHI_BINS as f32;
    let mut mass = vec![0.0f64; COS_BINS * PHI_BINS];
    for ci in 0..COS_BINS {
        // θ range of the bin: cos θ from c0 up to c0 + dc.
        let c0 = -1.0 + dc * ci as f32;
        let (theta_lo, theta_hi) = (
            c0.clamp(-1.0, 1.0).acos(),
            (c0 + dc).clamp(-1.0, 1.0).acos(),
        );
        for pi in 0..PHI_BINS {
            let mut acc = 0.0f64;
            for a in 0..SUB {
                let theta = theta_hi + (theta_lo - theta_hi) * (a as f32 + 0.5) / SUB as f32;
                let (s, c) = theta.sin_cos();
                for b in 0..SUB {
                    let phi = dp * (pi as f32 + (b as f32 + 0.5) / SUB as f32);
                    let wi = Vec3::new(s * phi.cos(), s * phi.sin(), c);
                    acc += f64::from(m.pdf(wo, wi) * s);
                }
            }
            let d_theta = f64::from(theta_lo - theta_hi) / SUB as f64;
            mass[ci * PHI_BINS + pi] = acc * d_theta * f64::from(dp) / SUB as f64;
        }
    }
    mass
}

#[test]
fn sampled_directions_follow_the_pdf_chi_square() {
    const N: usize = 200_000;
    for (name, m) in materials() {
        for (k, wo) in directions().into_iter().enumerate() {
            let mass = expected_mass(&m, wo);
            let total: f64 = mass.iter().sum();
            assert!(total <= 1.0 + 2e-2, "{name}: pdf integrates to {total}");
            let mut counts = vec![0u64; mass.len()];
            let mut rng = Pcg32::seed_from_u64(1000 + k as u64);
            let mut produced = 0usize;
            for _ in 0..N {
                let u = Vec2::new(rng.random(), rng.random());
                if let Some(s) = m.sample(wo, rng.random(), u) {
                    if s.delta {
                        // A mixed BSDF's delta lobe: not part of the density.
                        continue;
                    }
                    let pdf = m.pdf(wo, s.wi);
                    assert!(
                        (s.pdf - pdf).abs() <= 1e-3 * pdf,
                        "{name}: {} vs {pdf}",
                        s.pdf
                    );
                    counts[bin_of(s.wi)] += 1;
                    produced += 1;
                }
            }
            // The fraction of successful samples is the integral of the pdf.
            let frac = produced as f64 / N as f64;
            let sd = (total * (1.0 - total) / N as f64).sqrt().max(1e-4);
            assert!(
                (frac - total).abs() < 4.0 * sd + 5e-3,
                "{name} wo={wo}: sampled mass {frac} vs pdf integral {total}"
            );
            // χ² over bins with expected count ≥ 5; the rest are pooled into one cell.
            let (mut chi2, mut dof) = (0.0f64, 0usize);
            let (mut pool_e, mut pool_o) = (0.0f64, 0.0f64);
            for (e, &o) in mass.iter().zip(&counts) {
                let e = e * N as f64;
                if e >= 5.0 {
                    chi2 += (o as f64 - e).powi(2) / e;
                    dof += 1;
                } else {
                    pool_e += e;
                    pool_o += o as f64;
                }
            }
            if pool_e >= 5.0 {
                chi2 += (pool_o - pool_e).powi(2) / pool_e;
                dof += 1;
            }
            if dof < 2 {
                // One-sided BSDFs seen from below: no mass, nothing sampled, nothing to test.
                assert!(
                    total < 1e-6 && produced == 0,
                    "{name} wo={wo}: mass {total}"
                );
                continue;
            }
            let dof = (dof - 1) as f64;
            // Wilson–Hilferty: (χ²/k)^(1/3) is close to normal.
            let z = ((chi2 / dof).cbrt() - (1.0 - 2.0 / (9.0 * dof))) / (2.0 / (9.0 * dof)).sqrt();
            assert!(
                z < 4.0,
                "{name} wo={wo}: χ² = {chi2:.1} with {dof} dof (z = {z:.2})"
            );
        }
    }
}

/// The index of the rough dielectric a BSDF transmits through (itself, or inside a blend).
fn rough_dielectric_eta(b: &Bsdf) -> Option<f32> {
    match b {
        Bsdf::RoughDielectric { eta, .. } => Some(*eta),
        Bsdf::Blend(blend) => blend.bsdfs.iter().find_map(rough_dielectric_eta),
        Bsdf::Principled(p) if p.spec_trans > 0.0 => Some(p.eta),
        _ => None,
    }
}

#[test]
fn bsdf_values_are_reciprocal() {
    let mut rng = Pcg32::seed_from_u64(3);
    for (name, m) in materials() {
        for _ in 0..2000 {
            let a =
                crate::sampling::square_to_uniform_sphere(Vec2::new(rng.random(), rng.random()));
            let b =
                crate::sampling::square_to_uniform_sphere(Vec2::new(rng.random(), rng.random()));
            let (fab, fba) = (m.f(a, b), m.f(b, a));
            if let Some(eta) = rough_dielectric_eta(&m.bsdf) {
                // Fresnel at a grazing microfacet cosine is ill-conditioned in f32: skip those.
                let etap = if a.z > 0.0 { eta } else { 1.0 / eta };
                let h = if a.z * b.z > 0.0 { a + b } else { a + b * etap }.normalize();
                if a.dot(h).abs() < 0.05 || b.dot(h).abs() < 0.05 {
                    continue;
                }
            }
            // Transmission in radiance mode satisfies f(a,b) η'(a)² = f(b,a) (Veach §5.2).
            let scale = match rough_dielectric_eta(&m.bsdf) {
                Some(eta) if a.z * b.z < 0.0 => {
                    if a.z > 0.0 {
                        eta * eta
                    } else {
                        1.0 / (eta * eta)
                    }
                }
                _ => 1.0,
            };
            let diff = (fab * scale - fba).abs().max_element();
            assert!(
                diff <= 1e-3 * fba.max_element().max(1e-3),
                "{name}: f({a}, {b}) = {fab} vs {fba}"
            );
        }
    }
}

#[test]
fn delta_bsdfs_conserve_energy_and_refract_by_snell() {
    let glass = Material::new(Bsdf::Dielectric {
        eta: 1.5,
        specular_reflectance: Vec3::ONE,
        specular_transmittance: Vec3::ONE,
    });
    let wo = Vec3::new(0.6, 0.0, 0.8);
    let (f, _, _) = fresnel_dielectric(0.8, 1.5);
    let r = glass.sample(wo, 0.0, Vec2::ZERO).unwrap();
    let t = glass.sample(wo, 0.999, Vec2::ZERO).unwrap();
    assert!(r.delta && (r.wi - Vec3::new(-0.6, 0.0, 0.8)).length() < 1e-6);
    // Weights f |cos| / pdf: 1 for reflection, 1/η² for radiance transmission.
    assert!((r.f.x * r.wi.z.abs() / r.pdf - 1.0).abs() < 1e-5 && (r.pdf - f).abs() < 1e-6);
    assert!((t.f.x * t.wi.z.abs() / t.pdf - 1.0 / 2.25).abs() < 1e-5);
    // Snell: sin θt = sin θi / η.
    let sin_t = (t.wi.x * t.wi.x + t.wi.y * t.wi.y).sqrt();
    assert!((sin_t - 0.6 / 1.5).abs() < 1e-5 && t.wi.z < 0.0 && t.wi.x < 0.0);
    let mirror = Material::new(Bsdf::Conductor {
        eta: Vec3::ZERO,
        k: Vec3::ONE,
        specular_reflectance: Vec3::ONE,
    });
    let s = mirror.sample(wo, 0.5, Vec2::ZERO).unwrap();
    assert!((s.f.x * s.wi.z / s.pdf - 1.0).abs() < 1e-5);
    assert!(
        mirror.sample(-wo, 0.5, Vec2::ZERO).is_none(),
        "conductors are one-sided"
    );
}

#[test]
fn diffuse_is_one_sided_unless_two_sided() {
    let m = Material::new(Bsdf::Diffuse {
        reflectance: Vec3::ONE,
    });
    let up = Vec3::new(0.0, 0.6, 0.8);
    assert_eq!(m.f(-up, up), Vec3::ZERO);
    assert_eq!(m.f(up, -up), Vec3::ZERO);
    assert!(m.sample(-up, 0.5, Vec2::splat(0.5)).is_none());
    let mut t = m.clone();
    t.two_sided = true;
    assert!((t.f(-up, -up).x - 1.0 / PI).abs() < 1e-6);
    assert!(t.sample(-up, 0.5, Vec2::splat(0.5)).unwrap().wi.z < 0.0);
}

#[test]
fn a_blend_with_a_delta_lobe_reflects_the_mixture_of_the_albedos() {
    // Diffuse ρ = 0.6 and a perfect mirror, weight 0.3 on the mirror: the sampled albedo
    // E[f·cos/pdf] is 0.7·0.6 + 0.3·1 = 0.72 (the diffuse part's weight is constant, the
    // mirror's exactly 1, so the estimate's only noise is which lobe is picked: σ ≈ 0.18/√n).
    let m = Material::new(Bsdf::Blend(Box::new(Blend {
        weight: 0.3,
        bsdfs: [
            Bsdf::Diffuse {
                reflectance: Vec3::splat(0.6),
            },
            Bsdf::Conductor {
                eta: Vec3::ZERO,
                k: Vec3::ONE,
                specular_reflectance: Vec3::ONE,
            },
        ],
    })));
    assert!(!m.is_delta() && !m.transmits());
    let mut rng = Pcg32::seed_from_u64(9);
    let wo = Vec3::new(0.3, -0.2, 0.9).normalize();
    let n = 40_000;
    let (mut sum, mut deltas) = (0.0f64, 0);
    for _ in 0..n {
        let s = m
            .sample(wo, rng.random(), Vec2::new(rng.random(), rng.random()))
            .unwrap();
        deltas += s.delta as usize;
        sum += f64::from(s.f.x * s.wi.z.abs() / s.pdf);
    }
    let albedo = sum / n as f64;
    assert!(
        (albedo - 0.72).abs() < 5.0 * 0.18 / (n as f64).sqrt(),
        "{albedo}"
    );
    // The mirror is picked with its share, and its weight is the mirror's own.
    let share = deltas as f64 / n as f64;
    assert!(
        (share - 0.3).abs() < 5.0 * (0.21f64 / n as f64).sqrt(),
        "{share}"
    );
}

/// `∫ f(m) dω_m` over the upper hemisphere, in slope space `m ∝ (−tan a, −tan b, 1)` (where
/// `dω_m = cos³θ_m sec²a sec²b da db`), by the midpoint rule.
fn over_normals(f: impl Fn(Vec3) -> f32) -> f64 {
    const N: usize = 600;
    let h = PI / N as f32;
    let mut sum = 0.0f64;
    for i in 0..N {
        let a = -0.5 * PI + h * (i as f32 + 0.5);
        for j in 0..N {
            let b = -0.5 * PI + h * (j as f32 + 0.5);
            let m = Vec3::new(-a.tan(), -b.tan(), 1.0);
            let cos = 1.0 / m.length();
            let jac = cos.powi(3) / (a.cos() * b.cos()).powi(2);
            sum += f64::from(f(m * cos) * jac * h * h);
        }
    }
    sum
}

#[test]
fn anisotropic_normals_project_to_unit_area_and_their_visible_ones_integrate_to_one() {
    for kind in [MicrofacetKind::Ggx, MicrofacetKind::Beckmann] {
        let dist = anisotropic(kind, 0.1, 0.4);
        let area = over_normals(|m| dist.d(m) * m.z);
        assert!((area - 1.0).abs() < 2e-3, "{kind:?}: ∫ D cos = {area}");
        for v in [Vec3::new(0.5, 0.2, 0.6), Vec3::new(-0.1, 0.9, 0.3)] {
            let v = v.normalize();
            let visible = over_normals(|m| dist.pdf_visible(v, m));
            assert!(
                (visible - 1.0).abs() < 3e-3,
                "{kind:?} {v}: ∫ Dv = {visible}"
            );
        }
        // Rotated 90°, the distribution differs: it is not isotropic.
        let m = Vec3::new(0.3, 0.0, 1.0).normalize();
        let turned = anisotropic(kind, 0.4, 0.1);
        assert!(dist.d(m) < 0.5 * turned.d(m), "{kind:?}");
    }
}

#[test]
fn the_ninety_percent_cone_holds_ninety_percent_of_the_microfacet_normals() {
    // ∫ D(m) cos θ dω over the cone, by the midpoint rule in θ (D is isotropic here), and over
    // the whole hemisphere (1: D is normalised per projected area).
    let mass = |d: &Microfacet, theta_max: f32| -> f64 {
        let steps = 200_000;
        let h = f64::from(theta_max) / f64::from(steps);
        (0..steps)
            .map(|i| {
                let t = (f64::from(i) + 0.5) * h;
                let m = Vec3::new(t.sin() as f32, 0.0, t.cos() as f32);
                f64::from(d.d(m)) * t.cos() * t.sin() * 2.0 * std::f64::consts::PI * h
            })
            .sum()
    };
    for d in [
        Microfacet::ggx(0.02),
        Microfacet::ggx(0.3),
        beckmann(0.05),
        beckmann(0.5),
    ] {
        let total = mass(&d, PI / 2.0);
        assert!((total - 1.0).abs() < 2e-3, "{d:?}: {total}");
        let inside = mass(&d, d.cone_90());
        assert!((inside - 0.9).abs() < 2e-3, "{d:?}: {inside}");
    }
    // The wider axis sets an anisotropic lobe's cone.
    let a = anisotropic(MicrofacetKind::Ggx, 0.05, 0.2);
    assert_eq!(a.cone_90(), Microfacet::ggx(0.2).cone_90());
    let lobe = |dist| Bsdf::RoughConductor {
        dist,
        eta: Vec3::ONE,
        k: Vec3::ONE,
        specular_reflectance: Vec3::ONE,
    };
    let half = lobe(Microfacet::ggx(0.02)).lobe_half_angle().unwrap();
    assert!((half - 2.0 * 0.06f32.atan()).abs() < 1e-6, "{half}");
    assert_eq!(
        Bsdf::Diffuse {
            reflectance: Vec3::ONE
        }
        .lobe_half_angle(),
        None
    );
}
