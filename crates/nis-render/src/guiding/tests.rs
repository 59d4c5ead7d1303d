//! Statistical checks of the classical guides ([`ppg`](super::ppg), [`gmm`](super::gmm)) after
//! training on synthetic records whose radiance is concentrated around two directions: the
//! density integrates to one, sampled directions follow it (χ²), `sample` reports `pdf`, the
//! learned density peaks where the light is, and learning ignores the order of the records.

use std::f64::consts::PI;

use glam::{Vec2, Vec3};
use rand::RngCore;
use rand_pcg::Pcg32;

use super::gmm::{Gmm, GmmConfig};
use super::ppg::{Ppg, PpgConfig};
use super::{
    cylindrical_to_dir, dir_to_cylindrical, Guide, GuideRecord, GuideSample, GuideStatistics,
    GuideVertex,
};
use crate::bvh::Aabb;
use crate::geometry::Frame;

/// Grid over `(cos θ, φ)` for quadrature; cells of `1/512 × 1/1024` of the cylindrical square,
/// so PPG quadtree cells down to depth 9 are integrated exactly.
const GRID: (usize, usize) = (512, 1024);
/// χ² bins over `(cos θ, φ)`.
const BINS: (usize, usize) = (16, 32);
/// Smallest expected count of a χ² bin; smaller ones are pooled.
const MIN_EXPECTED: f64 = 5.0;

fn uniform(rng: &mut Pcg32) -> f32 {
    (rng.next_u32() >> 8) as f32 / 16_777_216.0
}

fn unit_box() -> Aabb {
    Aabb {
        min: Vec3::ZERO,
        max: Vec3::ONE,
    }
}

fn vertex(p: Vec3) -> GuideVertex {
    GuideVertex {
        p,
        n: Vec3::Z,
        wo: Vec3::Z,
        transmissive: false,
    }
}

/// The two light directions of the synthetic radiance.
fn lights() -> [Vec3; 2] {
    [
        Vec3::new(0.3, 0.2, 0.9).normalize(),
        Vec3::new(-0.6, 0.1, 0.5).normalize(),
    ]
}

/// Radiance arriving from `w`: two von Mises–Fisher-shaped lobes.
fn radiance(w: Vec3) -> f32 {
    let [a, b] = lights();
    10.0 * (KAPPA[0] * (w.dot(a) - 1.0)).exp() + 3.0 * (KAPPA[1] * (w.dot(b) - 1.0)).exp()
}

/// Concentrations of the light lobes, which the synthetic records are also drawn from.
const KAPPA: [f32; 2] = [40.0, 15.0];

/// `n` records at each of `positions`, as a path tracer would produce that samples a third of
/// its directions uniformly over the sphere (or the upper hemisphere) and a third from a von
/// Mises–Fisher lobe around each light; `pdf` is that mixture's density.
fn records(positions: &[Vec3], n: usize, hemisphere: bool, seed: u64) -> Vec<GuideRecord> {
    let mut rng = Pcg32::new(seed, 0xda3e_39cb_94b9_5bdb);
    let vmf_pdf = |w: Vec3, l: usize| {
        let k = KAPPA[l];
        k / (2.0 * std::f32::consts::PI * (1.0 - (-2.0 * k).exp()))
            * (k * (w.dot(lights()[l]) - 1.0)).exp()
    };
    let mut out = Vec::new();
    for &p in positions {
        for _ in 0..n {
            let u = Vec2::new(uniform(&mut rng), uniform(&mut rng));
            let technique = (3.0 * uniform(&mut rng)) as usize;
            let wi = if technique == 0 {
                let x = if hemisphere { 0.5 + 0.5 * u.x } else { u.x };
                cylindrical_to_dir(Vec2::new(x, u.y))
            } else {
                let k = KAPPA[technique - 1];
                let cos = 1.0 + (u.x + (1.0 - u.x) * (-2.0 * k).exp()).ln() / k;
                let c = Vec2::new(0.5 * (cos.clamp(-1.0, 1.0) + 1.0), u.y);
                let frame = Frame::from_normal(lights()[technique - 1]);
                frame.to_world(cylindrical_to_dir(c)).normalize()
            };
            let uniform_pdf = match (hemisphere, wi.z > 0.0) {
                (true, true) => 0.5 / std::f32::consts::PI,
                (true, false) => 0.0,
                (false, _) => 0.25 / std::f32::consts::PI,
            };
            out.push(GuideRecord {
                vertex: vertex(p),
                wi,
                pdf: (uniform_pdf + vmf_pdf(wi, 0) + vmf_pdf(wi, 1)) / 3.0,
                bsdf_pdf: 0.0,
                bsdf_cos: Vec3::ONE,
                radiance: Vec3::splat(radiance(wi)),
                throughput: 1.0,
            });
        }
    }
    out
}

const POSITIONS: [Vec3; 3] = [
    Vec3::new(0.2, 0.3, 0.4),
    Vec3::new(0.8, 0.7, 0.1),
    Vec3::new(0.5, 0.9, 0.9),
];

/// One training pass of `guide` on `batches` of records, accumulated batch by batch (as the
/// render loop does wave by wave) and merged in order.
fn learn<G: Guide>(guide: &mut G, batches: &[&[GuideRecord]]) {
    let mut statistics = G::Statistics::default();
    for batch in batches {
        let mut s = G::Statistics::default();
        guide.accumulate(batch, &mut s);
        statistics.merge(s);
    }
    guide.update(statistics);
}

/// Train `guide` for `iterations` iterations of `n` records per position.
fn train<G: Guide>(guide: &mut G, n: usize, hemisphere: bool, iterations: usize) {
    for it in 0..iterations {
        let rs = records(&POSITIONS, n, hemisphere, 17 + it as u64);
        let chunks: Vec<&[GuideRecord]> = rs.chunks(1000).collect();
        learn(guide, &chunks);
    }
}

fn trained_ppg() -> Ppg {
    let config = PpgConfig {
        spatial_threshold: 4000.0,
        ..PpgConfig::default()
    };
    let mut g = Ppg::new(unit_box(), config);
    train(&mut g, 10_000, false, 3);
    g
}

fn trained_gmm() -> Gmm {
    let config = GmmConfig {
        split_threshold: 2000,
        ..GmmConfig::default()
    };
    let mut g = Gmm::new(unit_box(), config);
    train(&mut g, 5_000, true, 3);
    g
}

/// Probability of each `GRID` cell of `(cos θ, φ)` (midpoint rule).
fn cell_masses<G: Guide>(guide: &G, v: &GuideVertex) -> Vec<f64> {
    let (nt, np) = GRID;
    let cell = (2.0 / nt as f64) * (2.0 * PI / np as f64);
    let mut m = Vec::with_capacity(nt * np);
    for i in 0..nt {
        for j in 0..np {
            let c = Vec2::new((i as f32 + 0.5) / nt as f32, (j as f32 + 0.5) / np as f32);
            m.push(f64::from(guide.pdf(v, cylindrical_to_dir(c))) * cell);
        }
    }
    m
}

/// Integral of the density over the sphere, and the χ² test of `n` samples against it:
/// returns (integral, Wilson–Hilferty z-score of the χ² statistic, samples refused).
fn check_density<G: Guide>(guide: &G, v: &GuideVertex, n: usize, seed: u64) -> (f64, f64, usize) {
    let masses = cell_masses(guide, v);
    let integral: f64 = masses.iter().sum();
    let (nt, np) = GRID;
    let (bt, bp) = BINS;
    let mut expected = vec![0.0f64; bt * bp];
    for i in 0..nt {
        for j in 0..np {
            expected[(i * bt / nt) * bp + j * bp / np] += masses[i * np + j] * n as f64;
        }
    }
    let mut observed = vec![0.0f64; bt * bp];
    let mut rng = Pcg32::new(seed, 0x0a02_bdbf_7bb3_c0a7);
    let mut refused = 0;
    for _ in 0..n {
        let u = Vec2::new(uniform(&mut rng), uniform(&mut rng));
        match guide.sample(v, u) {
            Some(GuideSample { wi, pdf }) => {
                assert_eq!(
                    pdf.to_bits(),
                    guide.pdf(v, wi).to_bits(),
                    "sample vs pdf at {wi}"
                );
                assert!((wi.length() - 1.0).abs() < 1e-5);
                let c = dir_to_cylindrical(wi);
                let b = (c.x * bt as f32) as usize * bp + (c.y * bp as f32) as usize;
                observed[b] += 1.0;
            }
            None => refused += 1,
        }
    }
    // Pool bins with small expected counts.
    let (mut chi2, mut dof) = (0.0, 0usize);
    let (mut pool_e, mut pool_o) = (0.0, 0.0);
    for (e, o) in expected.iter().zip(&observed) {
        if *e < MIN_EXPECTED {
            pool_e += e;
            pool_o += o;
        } else {
            chi2 += (o - e) * (o - e) / e;
            dof += 1;
        }
    }
    if pool_e > 0.0 {
        chi2 += (pool_o - pool_e) * (pool_o - pool_e) / pool_e;
        dof += 1;
    } else {
        assert_eq!(pool_o, 0.0, "samples where the density is zero");
    }
    let k = (dof - 1) as f64;
    let z = ((chi2 / k).cbrt() - (1.0 - 2.0 / (9.0 * k))) / (2.0 / (9.0 * k)).sqrt();
    (integral, z, refused)
}

/// One-sided z-score with p = 10⁻³.
const Z_CRITICAL: f64 = 3.09;

#[test]
fn untrained_guides_are_uniform_and_not_selected() {
    let v = vertex(Vec3::splat(0.5));
    let ppg = Ppg::new(unit_box(), PpgConfig::default());
    let gmm = Gmm::new(unit_box(), GmmConfig::default());
    assert_eq!(ppg.selection_probability(&v), 0.0);
    assert_eq!(gmm.selection_probability(&v), 0.0);
    for w in [Vec3::Z, -Vec3::Z, Vec3::new(0.6, -0.8, 0.0)] {
        assert!((ppg.pdf(&v, w) - 0.25 / std::f32::consts::PI).abs() < 1e-7);
    }
    assert!((gmm.pdf(&v, Vec3::Z) - 0.5 / std::f32::consts::PI).abs() < 1e-7);
    assert_eq!(gmm.pdf(&v, -Vec3::Z), 0.0);
    for (integral, z, refused) in [
        check_density(&ppg, &v, 50_000, 1),
        check_density(&gmm, &v, 50_000, 2),
    ] {
        assert!((integral - 1.0).abs() < 1e-5, "{integral}");
        assert!(z < Z_CRITICAL, "χ² z = {z}");
        assert!(refused <= 1);
    }
}

/// (a)–(d) for a trained guide at each training position; `uniform` is the density of the
/// uniform guide over its domain.
fn check_trained<G: Guide>(guide: &G, uniform: f64, integral_tol: f64) {
    let [a, b] = lights();
    for (i, &p) in POSITIONS.iter().enumerate() {
        let v = vertex(p);
        assert_eq!(guide.selection_probability(&v), 0.5);
        let (integral, z, refused) = check_density(guide, &v, 200_000, 10 + i as u64);
        assert!((integral - 1.0).abs() < integral_tol, "∫ pdf = {integral}");
        assert!(z < Z_CRITICAL, "χ² z = {z} at {p}");
        assert!(refused <= 2, "{refused} samples refused");
        let (pa, pb) = (f64::from(guide.pdf(&v, a)), f64::from(guide.pdf(&v, b)));
        assert!(
            pa > 10.0 * uniform,
            "pdf at the main light {pa} vs uniform {uniform}"
        );
        assert!(
            pb > 2.0 * uniform,
            "pdf at the second light {pb} vs uniform {uniform}"
        );
        let away = Vec3::new(0.0, -0.9, 0.3).normalize();
        assert!(
            f64::from(guide.pdf(&v, away)) < uniform,
            "pdf away from the lights"
        );
    }
}

#[test]
fn trained_ppg_density_is_normalised_sampled_exactly_and_peaks_at_the_lights() {
    let g = trained_ppg();
    assert!(g.spatial_leaves() > 1, "the spatial tree should have split");
    // Cells up to depth 9 are integrated exactly; what remains is f32 round-off.
    check_trained(&g, 0.25 / PI, 1e-4);
}

#[test]
fn trained_gmm_density_is_normalised_sampled_exactly_and_peaks_at_the_lights() {
    let g = trained_gmm();
    assert!(g.spatial_leaves() > 1, "the spatial tree should have split");
    // Midpoint rule on a smooth density, cells 0.004 × 0.006 rad against lobes ≳ 0.05 wide.
    check_trained(&g, 0.5 / PI, 1e-3);
}

/// The same records delivered in a different order and in different batches.
fn shuffled_batches(rs: &[GuideRecord]) -> Vec<Vec<GuideRecord>> {
    let mut rs = rs.to_vec();
    rs.reverse();
    let third = rs.len() / 3;
    rs.rotate_left(third);
    rs.chunks(777).rev().map(<[GuideRecord]>::to_vec).collect()
}

fn fingerprint<G: Guide>(guide: &G) -> Vec<u32> {
    let mut out = Vec::new();
    for &p in &POSITIONS {
        for i in 0..64 {
            let c = Vec2::new((i as f32 + 0.5) / 64.0, (i * 37 % 64) as f32 / 64.0);
            out.push(guide.pdf(&vertex(p), cylindrical_to_dir(c)).to_bits());
        }
        let GuideSample { wi: w, pdf } = guide.sample(&vertex(p), Vec2::new(0.3, 0.6)).unwrap();
        out.extend([w.x.to_bits(), w.y.to_bits(), w.z.to_bits(), pdf.to_bits()]);
    }
    out
}

fn learn_in_two_orders<G: Guide>(mut make: impl FnMut() -> G, hemisphere: bool) -> [Vec<u32>; 2] {
    let (mut g1, mut g2) = (make(), make());
    for it in 0..2 {
        let rs = records(&POSITIONS, 3000, hemisphere, 5 + it);
        learn(&mut g1, &[&rs]);
        let batches = shuffled_batches(&rs);
        let batches: Vec<&[GuideRecord]> = batches.iter().map(Vec::as_slice).collect();
        learn(&mut g2, &batches);
    }
    [fingerprint(&g1), fingerprint(&g2)]
}

#[test]
fn learning_does_not_depend_on_record_order_or_batching() {
    for spatial_filter in [false, true] {
        let [a, b] = learn_in_two_orders(
            || {
                let config = PpgConfig {
                    spatial_threshold: 2000.0,
                    spatial_filter,
                    ..PpgConfig::default()
                };
                Ppg::new(unit_box(), config)
            },
            false,
        );
        assert_eq!(a, b, "PPG, spatial filter {spatial_filter}");
    }
    let [a, b] = learn_in_two_orders(
        || {
            let config = GmmConfig {
                split_threshold: 1000,
                ..GmmConfig::default()
            };
            Gmm::new(unit_box(), config)
        },
        true,
    );
    assert_eq!(a, b, "GMM");
}

/// The polynomial atan2 against f64's on the circle (every 2⁻¹⁶ of a turn, the axes and the
/// diagonals included), near the axes and at the origin. Error budget: the fit's 8.9·10⁻⁸,
/// the rounding of the ratio and of the Horner steps (about ten half-ulps of π/4, 2.4·10⁻⁷)
/// and of the octant's subtraction from π (half an ulp, 1.2·10⁻⁷).
#[test]
fn polynomial_atan2_is_within_its_error_budget() {
    let budget =
        8.9e-8 + 10.0 * f64::from(f32::EPSILON) / 2.0 * std::f64::consts::FRAC_PI_4 + 1.2e-7;
    let mut worst = 0.0f64;
    let mut check = |y: f32, x: f32| {
        let want = f64::from(y).atan2(f64::from(x));
        let got = f64::from(super::atan2(y, x));
        worst = worst.max((got - want).abs());
        assert!(
            (got - want).abs() <= budget,
            "atan2({y}, {x}) = {got}, want {want}"
        );
    };
    for i in 0..1 << 16 {
        let a = i as f64 / f64::from(1 << 16) * std::f64::consts::TAU;
        check(a.sin() as f32, a.cos() as f32);
    }
    for (y, x) in [
        (1.0, 0.0),
        (-1.0, 0.0),
        (0.0, -1.0),
        (0.0, 1.0),
        (1e-30, 1.0),
        (1.0, -1e-30),
        (-1e-38, -1.0),
        (3.0, 3.0),
    ] {
        check(y, x);
    }
    assert_eq!(super::atan2(0.0, 0.0), 0.0);
    eprintln!("worst atan2 error {worst:e} (budget {budget:e})");
}
