//! Every example's channels are the true densities of their maps, and every exact value agrees
//! with the classic multi-channel estimate and with an independent quadrature.

use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

use super::quadrature::integrate;
use super::*;
use crate::channels::{check_sampled, ChannelSet};
use crate::integrate::Integrand;

const NAMES: [&str; 5] = [
    "gauss-pm",
    "dalitz",
    "resonances-4d",
    "phase-space-8d",
    "resonances-100",
];

fn uniform(rng: &mut Pcg64Mcg, n: usize, d: usize, margin: f64) -> Vec<f64> {
    (0..n * d)
        .map(|_| margin + (1.0 - 2.0 * margin) * rng.random::<f64>())
        .collect()
}

/// The determinant of a d × d row-major matrix (LU with partial pivoting).
fn det(mut a: Vec<f64>, d: usize) -> f64 {
    let mut det = 1.0;
    for c in 0..d {
        let p = (c..d)
            .max_by(|&i, &j| a[i * d + c].abs().total_cmp(&a[j * d + c].abs()))
            .unwrap();
        if p != c {
            for k in 0..d {
                a.swap(p * d + k, c * d + k);
            }
            det = -det;
        }
        let piv = a[c * d + c];
        det *= piv;
        for r in c + 1..d {
            let f = a[r * d + c] / piv;
            for k in c..d {
                a[r * d + k] -= f * a[c * d + k];
            }
        }
    }
    det
}

/// The coordinates of an example that are angles/2π, periodic in [0, 1).
fn periodic(name: &str) -> &'static [usize] {
    if name == "phase-space-8d" {
        &four_body::AZIMUTHS
    } else {
        &[]
    }
}

/// |det ∂φ/∂u| at u by central differences at h and h/2, Richardson-extrapolated (O(h⁴)); the
/// differences of `periodic` coordinates are taken modulo 1.
fn jacobian_det(ch: &dyn Channel, u: &[f64], h: f64, periodic: &[usize]) -> f64 {
    let d = u.len();
    let mut shifted = Vec::with_capacity(4 * d * d);
    for j in 0..d {
        for s in [h, -h, h / 2.0, -h / 2.0] {
            let mut v = u.to_vec();
            v[j] += s;
            shifted.extend(v);
        }
    }
    let mut x = vec![0.0; shifted.len()];
    ch.sample(&shifted, &mut x).unwrap();
    let mut m = vec![0.0; d * d];
    for j in 0..d {
        let at = |k: usize, i: usize| x[(4 * j + k) * d + i];
        let diff = |a: f64, b: f64, i: usize| {
            if periodic.contains(&i) {
                (a - b + 0.5).rem_euclid(1.0) - 0.5
            } else {
                a - b
            }
        };
        for i in 0..d {
            let wide = diff(at(0, i), at(1, i), i) / (2.0 * h);
            let narrow = diff(at(2, i), at(3, i), i) / h;
            m[i * d + j] = (4.0 * narrow - wide) / 3.0;
        }
    }
    det(m, d).abs()
}

#[test]
fn every_channel_density_is_the_inverse_jacobian_determinant_of_its_map() {
    for name in NAMES {
        let ex = by_name(name).unwrap();
        let d = ex.integrand.dim;
        for (k, ch) in ex.channels.iter().enumerate() {
            let mut rng = Pcg64Mcg::seed_from_u64(17 + k as u64);
            // Away from the faces by 10⁻³, so that every difference stays inside the cube.
            let n = 300;
            let u = uniform(&mut rng, n, d, 1e-3);
            let mut x = vec![0.0; n * d];
            ch.sample(&u, &mut x).unwrap();
            let mut g = vec![0.0; n];
            ch.density(&x, &mut g).unwrap();
            let mut worst = 0.0f64;
            for i in 0..n {
                let jac = jacobian_det(&**ch, &u[i * d..(i + 1) * d], 1e-5, periodic(name));
                let rel = (jac * g[i] - 1.0).abs();
                worst = worst.max(rel);
                assert!(
                    rel < 1e-6,
                    "{name} channel {k} at u = {:?}: |det| = {jac}, 1/g = {}",
                    &u[i * d..(i + 1) * d],
                    1.0 / g[i]
                );
            }
            println!("{name} channel {k}: worst |det·g − 1| = {worst:.1e}");
        }
    }
}

#[test]
fn every_channel_samples_inside_the_cube_and_its_density_integrates_to_one() {
    for name in NAMES {
        let ex = by_name(name).unwrap();
        let d = ex.integrand.dim;
        let n = 200_000;
        for (k, ch) in ex.channels.iter().enumerate() {
            let mut rng = Pcg64Mcg::seed_from_u64(100 + k as u64);
            let u = uniform(&mut rng, n, d, 0.0);
            let mut x = vec![0.0; n * d];
            ch.sample(&u, &mut x).unwrap();
            let mut g = vec![0.0; n];
            ch.density(&x, &mut g).unwrap();
            check_sampled(k, d, &u, &x, &g).unwrap();
            // ∫ g = 1: the mean of g at uniform points, within 4 of its standard errors.
            let xs = uniform(&mut rng, n, d, 0.0);
            ch.density(&xs, &mut g).unwrap();
            let mean = g.iter().sum::<f64>() / n as f64;
            let var = g.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
            let err = (var / n as f64).sqrt();
            println!("{name} channel {k}: ∫g = {mean:.5} ± {err:.5}");
            assert!(
                (mean - 1.0).abs() < 4.0 * err && err < 0.05,
                "{name} channel {k}: ∫g = {mean} ± {err}"
            );
        }
    }
}

#[test]
fn every_channel_takes_the_faces_of_the_closed_cube() {
    // A flow's f32 output reaches 0 and 1 exactly: points with one coordinate on a face of
    // the cube (0 or 1, the others uniform) map, through the set (which moves them 2⁻⁵³
    // inside), inside the cube to a finite density > 0. (Several coordinates on faces at once,
    // a corner, can still reach a degenerate phase-space point of phase-space-8d.)
    for name in NAMES {
        let ex = by_name(name).unwrap();
        let set = ChannelSet::new(by_name(name).unwrap().channels).unwrap();
        let d = ex.integrand.dim;
        let mut rng = Pcg64Mcg::seed_from_u64(7);
        let n = 4000;
        let mut u = uniform(&mut rng, n, d, 0.0);
        for (i, p) in u.chunks_mut(d).enumerate() {
            p[i % d] = (i / d % 2) as f64;
        }
        for k in 0..set.len() {
            let mut x = vec![0.0; n * d];
            if let Err(e) = set.sample(k, &u, &mut x) {
                panic!("{name}: {e}");
            }
        }
    }
}

/// The classic multi-channel estimate (Kleiss & Pittau) with equal priors and `n` points per
/// channel: (estimate, standard error, variance per evaluation).
fn multi_channel(ex: &Example, n: usize, seed: u64) -> (f64, f64, f64) {
    let d = ex.integrand.dim;
    let set = ChannelSet::new(by_name_channels(ex)).unwrap();
    let a = set.weights();
    let (mut value, mut var, mut var_per_eval) = (0.0, 0.0, 0.0);
    for k in 0..set.len() {
        let mut rng = Pcg64Mcg::seed_from_u64(seed + k as u64);
        let u = uniform(&mut rng, n, d, 0.0);
        let mut x = vec![0.0; n * d];
        set.sample(k, &u, &mut x).unwrap();
        let mut g = vec![0.0; n];
        set.mixture_density(&x, &mut g).unwrap();
        let mut f = vec![0.0; n];
        ex.integrand.eval_batch(&x, d, &mut f).unwrap();
        let w: Vec<f64> = f.iter().zip(&g).map(|(f, g)| f / g).collect();
        let m = w.iter().sum::<f64>() / n as f64;
        let v = w.iter().map(|w| (w - m).powi(2)).sum::<f64>() / (n - 1) as f64;
        value += a[k] * m;
        var += a[k] * a[k] * v / n as f64;
        var_per_eval += set.len() as f64 * a[k] * a[k] * v;
    }
    (value, var.sqrt(), var_per_eval)
}

/// The example's channels once more (a set takes them by value).
fn by_name_channels(ex: &Example) -> Vec<Box<dyn Channel>> {
    by_name(ex.integrand.name.as_str()).unwrap().channels
}

/// Plain Monte Carlo: (estimate, standard error, variance per evaluation, mean |f|).
fn plain(ex: &Example, n: usize, seed: u64) -> (f64, f64, f64, f64) {
    let d = ex.integrand.dim;
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    let x = uniform(&mut rng, n, d, 0.0);
    let mut f = vec![0.0; n];
    ex.integrand.eval_batch(&x, d, &mut f).unwrap();
    let m = f.iter().sum::<f64>() / n as f64;
    let v = f.iter().map(|f| (f - m).powi(2)).sum::<f64>() / (n - 1) as f64;
    let abs = f.iter().map(|f| f.abs()).sum::<f64>() / n as f64;
    (m, (v / n as f64).sqrt(), v, abs)
}

#[test]
fn exact_values_agree_with_the_classic_multi_channel_estimate_and_channels_cut_the_variance() {
    // The least variance reduction each peaked example must show (measured ratios are printed;
    // these bounds leave a margin of more than 3 below them). gauss-pm's mappings are mild: no
    // bound.
    let bounds = [
        ("gauss-pm", 0.0),
        ("dalitz", 3.0),
        ("resonances-4d", 10.0),
        ("phase-space-8d", 5.0),
        ("resonances-100", 2.5),
    ];
    for (name, bound) in bounds {
        let ex = by_name(name).unwrap();
        // Every point evaluates every channel's density: fewer per channel when there are many.
        let n = if ex.channels.len() > 10 {
            10_000
        } else {
            200_000
        };
        let (v, err, mc_var) = multi_channel(&ex, n, 1000);
        let sigma = err.hypot(ex.exact_err);
        let (pv, perr, plain_var, abs) = plain(&ex, n * ex.channels.len(), 2000);
        let scale = if ex.exact != 0.0 { ex.exact } else { abs };
        let ratio = plain_var / mc_var;
        println!(
            "{name}: exact {:.10e}; multi-channel {v:.6e} ± {err:.1e} (pull {:.2}); plain {pv:.6e} ± {perr:.1e}; \
             rel. var/eval plain {:.3e}, multi-channel {:.3e}, ratio {ratio:.1}",
            ex.exact,
            (v - ex.exact) / sigma,
            plain_var / (scale * scale),
            mc_var / (scale * scale),
        );
        assert!(
            (v - ex.exact).abs() < 4.0 * sigma,
            "{name}: {v} ± {sigma} vs {}",
            ex.exact
        );
        assert!(
            (pv - ex.exact).abs() < 4.0 * perr.hypot(ex.exact_err),
            "{name} plain: {pv} ± {perr}"
        );
        assert!(ratio > bound, "{name}: variance ratio {ratio} ≤ {bound}");
    }
}

#[test]
fn exact_values_match_independent_quadratures() {
    let tol = 1e-11;
    // gauss-pm: each Gaussian integrates to the same product of 1-D integrals.
    let ex = by_name("gauss-pm").unwrap();
    let one = |c: f64| integrate(|t| (-(t - c).powi(2) / 0.08).exp(), 0.0, 1.0, 1e-14).0;
    let (pos, neg) = (one(0.2).powi(2), one(0.8).powi(2));
    assert!(
        (pos - neg).abs() < 1e-14 && ex.exact == 0.0 && pos > 0.1,
        "{pos} {neg}"
    );

    // dalitz: nested quadrature of the unit-square integrand itself (x₁ inside, x₀ outside),
    // not of the closed-form s₂₃ integrals.
    let ex = by_name("dalitz").unwrap();
    let f = &ex.integrand;
    let ((lo, hi), _) = dalitz::ranges();
    let peak = (dalitz::KSTAR.0.powi(2) - lo) / (hi - lo);
    let row = |x0: f64| integrate(|x1| f.value(&[x0, x1]), 0.0, 1.0, 1e-13).0;
    let v = integrate(row, 0.0, peak, 1e-12).0 + integrate(row, peak, 1.0, 1e-12).0;
    println!(
        "dalitz: exact {:.15e}, unit-square quadrature {v:.15e}",
        ex.exact
    );
    assert!(
        (v / ex.exact - 1.0).abs() < tol,
        "dalitz {v} vs {}",
        ex.exact
    );

    // resonances-4d: each term as ∫ ρ L by quadrature; the −ln t one after t = e^(−v).
    let ex = by_name("resonances-4d").unwrap();
    let p = resonances::PEAKS;
    let l = resonances::cauchy;
    let split = |f: &dyn Fn(f64) -> f64, a: f64, c: f64, b: f64| {
        integrate(f, a, c, 1e-14).0 + integrate(f, c, b, 1e-14).0
    };
    let sum = split(&|t: f64| t.min(2.0 - t) * l(t, p[0]), 0.0, p[0].0, 2.0);
    let cv = -p[1].0.ln();
    let prod = split(
        &|v: f64| v * (-v).exp() * l((-v).exp(), p[1]),
        0.0,
        cv,
        60.0,
    );
    let diff = split(&|t: f64| (1.0 - t.abs()) * l(t, p[2]), -1.0, p[2].0, 1.0);
    let terms = resonances::exact_terms().0;
    for (a, b) in terms.iter().zip([sum, prod, diff]) {
        assert!((a / b - 1.0).abs() < tol, "resonances-4d term {a} vs {b}");
    }
    assert!((ex.exact / (sum + prod + diff) - 1.0).abs() < tol);

    // phase-space-8d: the same double integral in the masses m = √s (ds = 2m dm), m₁ inside;
    // and the normalisation: 12 ∫∫ λ^½ = 1 (the massless four-body volume).
    let ex = by_name("phase-space-8d").unwrap();
    let mz = four_body::Z.0;
    let masses = |h: &dyn Fn(f64, f64) -> f64| {
        let outer = |m2: f64| {
            let top = 1.0 - m2;
            let g = |m1: f64| 2.0 * m1 * h(m1 * m1, m2 * m2);
            let v = if mz < top {
                integrate(g, 0.0, mz, 1e-13).0 + integrate(g, mz, top, 1e-13).0
            } else {
                integrate(g, 0.0, top, 1e-13).0
            };
            2.0 * m2 * v
        };
        integrate(outer, 0.0, mz, 1e-12).0 + integrate(outer, mz, 1.0, 1e-12).0
    };
    let volume = 12.0 * masses(&|a, b| four_body::sqrt_lambda(a, b));
    assert!((volume - 1.0).abs() < 1e-11, "four-body volume {volume}");
    let v =
        24.0 * masses(&|a, b| four_body::sqrt_lambda(a, b) * four_body::bw2(a) * four_body::bw2(b));
    println!(
        "phase-space-8d: exact {:.15e}, mass quadrature {v:.15e}",
        ex.exact
    );
    assert!(
        (v / ex.exact - 1.0).abs() < 1e-10,
        "phase-space-8d {v} vs {}",
        ex.exact
    );
    // resonances-100: each term as ∫ ρ L by quadrature, split at its peak.
    let ex = by_name("resonances-100").unwrap();
    let quad: f64 = (0..many::PEAKS)
        .map(|k| {
            let p = many::peak(k).1;
            split(&|t: f64| t.min(2.0 - t) * l(t, p), 0.0, p.0, 2.0)
        })
        .sum::<f64>()
        / many::PEAKS as f64;
    assert!(
        (ex.exact / quad - 1.0).abs() < tol,
        "resonances-100 {} vs {quad}",
        ex.exact
    );
    for name in NAMES {
        let ex = by_name(name).unwrap();
        println!("{name}: exact {:.15e} ± {:.1e}", ex.exact, ex.exact_err);
        assert!(ex.exact_err <= 1e-9 * ex.exact.abs().max(1e-300) || ex.exact == 0.0);
    }
}

#[test]
fn the_four_body_map_round_trips_and_conserves_momentum() {
    let mut rng = Pcg64Mcg::seed_from_u64(5);
    for _ in 0..1000 {
        let x = uniform(&mut rng, 1, 8, 1e-3);
        let p = four_body::momenta(four_body::X_TREE, &x);
        for c in 0..4 {
            let total: f64 = p.iter().map(|k| k[c]).sum();
            assert!((total - if c == 0 { 1.0 } else { 0.0 }).abs() < 1e-13);
        }
        for k in &p {
            let m2 = k[0] * k[0] - k[1] * k[1] - k[2] * k[2] - k[3] * k[3];
            assert!(m2.abs() < 1e-13, "massless: {m2}");
        }
        let back = four_body::coordinates(four_body::X_TREE, &p);
        for (a, b) in x.iter().zip(&back) {
            assert!((a - b).abs() < 1e-9, "{x:?} → {back:?}");
        }
    }
    // The flat integrand J integrates to 1 (uniform MC at a stated σ is weak; the quadrature
    // test above checks 12∫∫λ^½ = 1): here J's mean over a fixed sample, within 4σ.
    let n = 200_000;
    let x = uniform(&mut rng, n, 8, 0.0);
    let j: Vec<f64> = x.chunks_exact(8).map(four_body::jacobian).collect();
    let m = j.iter().sum::<f64>() / n as f64;
    let s = (j.iter().map(|v| (v - m).powi(2)).sum::<f64>() / (n * (n - 1)) as f64).sqrt();
    assert!((m - 1.0).abs() < 4.0 * s, "∫J = {m} ± {s}");
}

#[test]
fn examples_are_built_ins_too_and_unknown_names_are_errors() {
    for name in NAMES {
        let b = crate::integrands::by_name(name, None).unwrap();
        let ex = by_name(name).unwrap();
        assert_eq!(b.exact, ex.exact);
        assert!(ex.channels.iter().all(|c| c.dim() == b.dim));
        assert!(crate::integrands::by_name(name, Some(b.dim + 1)).is_err());
    }
    assert_eq!(names(), NAMES);
    assert!(matches!(by_name("camel"), Err(Error::Config(_))));
}
