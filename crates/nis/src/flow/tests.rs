//! Whole-flow checks: Jacobians, normalisation, gradients, the on-policy fast path, determinism
//! and input validation.

use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

use super::*;
use crate::error::Error;
use crate::transform::TransformKind;
use composed::Rows;

const TRANSFORMS: [TransformKind; 4] = [
    TransformKind::Affine,
    TransformKind::Linear { bins: 8 },
    TransformKind::Quadratic { bins: 8 },
    TransformKind::RationalQuadratic { bins: 8 },
];

/// A flow whose every parameter got uniform noise of half-width `scale`: not the identity.
fn random_flow(dim: usize, transform: TransformKind, context_dim: usize, scale: f32) -> Flow {
    let config = FlowConfig {
        dim,
        transform,
        hidden_layers: 2,
        hidden_width: 16,
        blob_bins: 8,
        context_dim,
        ..FlowConfig::new(dim)
    };
    noisy_flow(config, scale)
}

/// The flow of `config` with uniform noise of half-width `scale` on every parameter.
fn noisy_flow(config: FlowConfig, scale: f32) -> Flow {
    let dim = config.dim;
    let mut flow = Flow::new(config).unwrap();
    let mut rng = Pcg64Mcg::seed_from_u64(dim as u64 * 31 + 7);
    for p in flow.params_mut() {
        *p += scale * (2.0 * rng.random::<f32>() - 1.0);
    }
    flow
}

fn uniform_points(n: usize, dim: usize, seed: u64) -> Vec<f32> {
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    (0..n * dim).map(|_| rng.random::<f32>()).collect()
}

/// log|det J| of the map `forward` (one point in, one point out) at `x`, by central
/// differences in f64 arithmetic on the f32 map.
pub(crate) fn fd_log_det(forward: impl Fn(&[f32]) -> Vec<f32>, x: &[f32], h: f32) -> f64 {
    let d = x.len();
    let mut jac = vec![0.0f64; d * d];
    for j in 0..d {
        let (mut xp, mut xm) = (x.to_vec(), x.to_vec());
        xp[j] += h;
        xm[j] -= h;
        let step = (xp[j] - xm[j]) as f64;
        let (zp, zm) = (forward(&xp), forward(&xm));
        for i in 0..d {
            jac[i * d + j] = (zp[i] as f64 - zm[i] as f64) / step;
        }
    }
    // Determinant by Gaussian elimination with partial pivoting.
    let mut logdet = 0.0;
    for c in 0..d {
        let p = (c..d)
            .max_by(|&a, &b| jac[a * d + c].abs().total_cmp(&jac[b * d + c].abs()))
            .unwrap();
        for k in 0..d {
            jac.swap(c * d + k, p * d + k);
        }
        let piv = jac[c * d + c];
        logdet += piv.abs().ln();
        for r in c + 1..d {
            let f = jac[r * d + c] / piv;
            for k in c..d {
                jac[r * d + k] -= f * jac[c * d + k];
            }
        }
    }
    logdet
}

#[test]
fn log_det_matches_finite_difference_jacobian() {
    for dim in [2, 3, 5] {
        for t in TRANSFORMS {
            let flow = random_flow(dim, t, 0, 0.3);
            let mut rng = Pcg64Mcg::seed_from_u64(3);
            let mut checked = 0;
            while checked < 10 {
                let x: Vec<f32> = (0..dim).map(|_| 0.05 + 0.9 * rng.random::<f32>()).collect();
                let lq = flow.log_density(&x, None).unwrap()[0];
                // Two step sizes: where they disagree the stencil straddles a bin edge (a kink
                // of C') or the map curves too fast for it; such points are skipped.
                let (fd, fd_half) = (
                    fd_log_det(|x| flow.forward(x, None).unwrap().0, &x, 2e-3),
                    fd_log_det(|x| flow.forward(x, None).unwrap().0, &x, 1e-3),
                );
                if (fd - fd_half).abs() > 5e-4 {
                    continue;
                }
                // The determinant of a finite-difference Jacobian of the composite map is only as
                // good as its conditioning allows: later layers depend steeply on earlier outputs
                // through their conditioners, so the entries are large and cancel. Seen here:
                // ~3e-3 off where each layer's own finite difference (below) agrees to 3e-4.
                assert!(
                    (fd_half - lq).abs() < 1e-2,
                    "dim {dim} {t:?}: log q {lq} vs finite-difference {fd_half}"
                );
                // Layer by layer, the Jacobian is triangular with C' on the B diagonal.
                let mut u = x.clone();
                for c in flow.layers() {
                    let mut ld = [0.0f64];
                    let u0 = u.clone();
                    let apply = |u: &mut Vec<f32>, ld: &mut [f64; 1]| {
                        let rows = Rows {
                            u,
                            dim,
                            ctx: None,
                            log_det: ld,
                        };
                        c.apply(&flow.params, rows, Direction::Forward);
                    };
                    apply(&mut u, &mut ld);
                    // Per B dimension, differences at steps h and h/2; where they disagree the
                    // stencil straddles a knot or the density curves too fast, and the layer is
                    // not checked at this point.
                    let mut fd = 0.0;
                    let mut smooth = true;
                    for &d in c.b() {
                        // A step relative to the distance from the ends: the affine density
                        // varies like x^(e^s − 1) there.
                        let h0 = (1e-2 * u0[d].min(1.0 - u0[d])).clamp(1e-5, 1e-3);
                        let at = |h: f32| {
                            let (mut up, mut um) = (u0.clone(), u0.clone());
                            up[d] += h;
                            um[d] -= h;
                            let step = (up[d] - um[d]) as f64;
                            apply(&mut up, &mut [0.0]);
                            apply(&mut um, &mut [0.0]);
                            // y_B depends on u_B only through its own coordinate.
                            for &e in c.b() {
                                if e != d {
                                    assert!((up[e] - um[e]).abs() < 1e-6);
                                }
                            }
                            ((up[d] - um[d]) as f64 / step).ln()
                        };
                        let (a, b) = (at(h0), at(h0 / 2.0));
                        smooth &= (a - b).abs() < 5e-4;
                        fd += b;
                    }
                    if !smooth {
                        continue;
                    }
                    assert!(
                        (fd - ld[0]).abs() < 2e-3,
                        "{t:?} layer {:?}: {fd} vs {}",
                        c.b(),
                        ld[0]
                    );
                }
                checked += 1;
            }
        }
    }
}

#[test]
fn density_integrates_to_one_on_a_grid() {
    // Midpoint rule on a 1000² grid. The affine transform's density behaves like x^(e^s − 1) at
    // the ends, an integrable singularity a plain grid misses, so there the grid is graded:
    // x = g(t) = t³(10 − 15t + 6t²), whose g' = 30t²(1 − t)² vanishes at the ends and makes the
    // integrand smooth. (The piecewise-linear density is discontinuous, which a graded grid with
    // its coarser middle would resolve worse; the splines are bounded, so they use a plain grid.)
    let n = 1000;
    let ts: Vec<f64> = (0..n).map(|i| (i as f64 + 0.5) / n as f64).collect();
    for t in TRANSFORMS {
        let graded = t == TransformKind::Affine;
        let g = |t: f64| {
            if graded {
                t * t * t * (10.0 - 15.0 * t + 6.0 * t * t)
            } else {
                t
            }
        };
        let dg = |t: f64| {
            if graded {
                30.0 * t * t * (1.0 - t) * (1.0 - t)
            } else {
                1.0
            }
        };
        let flow = random_flow(2, t, 0, 0.3);
        let x: Vec<f32> = (0..n * n)
            .flat_map(|i| [g(ts[i / n]) as f32, g(ts[i % n]) as f32])
            .collect();
        let lq = flow.log_density(&x, None).unwrap();
        let integral = (0..n * n)
            .map(|i| lq[i].exp() * dg(ts[i / n]) * dg(ts[i % n]))
            .sum::<f64>()
            / (n * n) as f64;
        assert!((integral - 1.0).abs() < 1e-3, "{t:?}: ∫q = {integral}");
        // And the flow is not the identity.
        assert!(lq.iter().map(|l| l.abs()).fold(0.0, f64::max) > 0.3);
    }
}

#[test]
fn density_integrates_to_one_by_monte_carlo_in_four_dimensions() {
    for t in TRANSFORMS {
        let flow = random_flow(4, t, 0, 0.3);
        let n = 200_000;
        let lq = flow.log_density(&uniform_points(n, 4, 5), None).unwrap();
        let q: Vec<f64> = lq.iter().map(|l| l.exp()).collect();
        let mean = q.iter().sum::<f64>() / n as f64;
        let var = q.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
        let sigma = (var / n as f64).sqrt();
        assert!((mean - 1.0).abs() < 5.0 * sigma, "{t:?}: {mean} ± {sigma}");
    }
}

/// The layout of fewer layers builds a flow like any other: its density integrates to one and
/// sampling inverts it.
#[test]
fn a_flow_with_code_masks_is_normalised_and_inverts() {
    let dim = 7;
    let flow = noisy_flow(
        FlowConfig {
            dim,
            transform: TransformKind::Quadratic { bins: 8 },
            masks: crate::flow::mask::Masks::Codes,
            hidden_layers: 2,
            hidden_width: 16,
            blob_bins: 8,
            ..FlowConfig::new(dim)
        },
        0.3,
    );
    assert_eq!(flow.layers().len(), 5);
    let n = 200_000;
    let lq = flow.log_density(&uniform_points(n, dim, 5), None).unwrap();
    let q: Vec<f64> = lq.iter().map(|l| l.exp()).collect();
    let mean = q.iter().sum::<f64>() / n as f64;
    let var = q.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
    let sigma = (var / n as f64).sqrt();
    assert!((mean - 1.0).abs() < 5.0 * sigma, "{mean} ± {sigma}");
    assert!(
        lq.iter().map(|l| l.abs()).fold(0.0, f64::max) > 0.3,
        "the identity"
    );
    let mut rng = Pcg64Mcg::seed_from_u64(9);
    let s = flow.sample(600, None, &mut rng).unwrap();
    let lq = flow.log_density(&s.x, None).unwrap();
    for (a, b) in s.log_q.iter().zip(&lq) {
        assert!((a - b).abs() < 1e-3 * a.abs().max(1.0), "{a} vs {b}");
    }
    let (z, _) = flow.forward(&s.x, None).unwrap();
    let (x2, _) = flow.inverse(&z, None).unwrap();
    for (a, b) in s.x.iter().zip(&x2) {
        assert!((a - b).abs() < 1e-4);
    }
}

#[test]
fn sampling_inverts_the_density_pass() {
    for t in TRANSFORMS {
        let flow = random_flow(3, t, 2, 0.3);
        let mut rng = Pcg64Mcg::seed_from_u64(9);
        let ctx: Vec<f32> = (0..600 * 2).map(|_| rng.random::<f32>()).collect();
        let s = flow.sample(600, Some(&ctx), &mut rng).unwrap();
        let lq = flow.log_density(&s.x, Some(&ctx)).unwrap();
        for (a, b) in s.log_q.iter().zip(&lq) {
            // Sampling computes log q at the exact inverse; the density pass starts from x
            // rounded to f32, an error the forward map amplifies where it expands (q ≫ 1).
            assert!((a - b).abs() < 1e-3 * a.abs().max(1.0), "{t:?}: {a} vs {b}");
        }
        let (z, ld) = flow.forward(&s.x, Some(&ctx)).unwrap();
        let (x2, ld_inv) = flow.inverse(&z, Some(&ctx)).unwrap();
        for (a, b) in s.x.iter().zip(&x2) {
            assert!((a - b).abs() < 1e-4);
        }
        assert!((ld[0] + ld_inv[0]).abs() < 1e-3);
    }
}

/// L(θ) = −Σ w_i ln q(x_i; θ) for fixed points and weights.
fn loss_at(flow: &Flow, x: &[f32], ctx: Option<&[f32]>, w: &[f32]) -> f64 {
    let lq = flow.log_density(x, ctx).unwrap();
    -lq.iter().zip(w).map(|(l, &w)| l * w as f64).sum::<f64>()
}

#[test]
fn parameter_gradients_match_finite_differences() {
    for (dim, cdim) in [(2, 0), (3, 2), (1, 0)] {
        for t in TRANSFORMS {
            let flow = random_flow(dim, t, cdim, 0.3);
            let n = 64;
            let x = uniform_points(n, dim, 11);
            let ctx_v = uniform_points(n, cdim, 12);
            let ctx = (cdim > 0).then_some(&ctx_v[..]);
            let mut rng = Pcg64Mcg::seed_from_u64(13);
            let w: Vec<f32> = (0..n).map(|_| rng.random::<f32>() / n as f32).collect();
            let eval = flow.log_density_for_training(&x, ctx).unwrap();
            let grad = flow.backward(&eval.tape, &w).unwrap();
            // One directional derivative per weight and bias block of every conditioner layer
            // (the first layers' blocks reach the loss through later layers' one-blob encodings).
            for c in flow.layers() {
                let mut off = c.param_range().start;
                for j in 0..c.mlp().layers() {
                    let (i, o) = (c.mlp().dims[j], c.mlp().dims[j + 1]);
                    for len in [i * o, o] {
                        let block = off..off + len;
                        off += len;
                        if len == 0 {
                            continue;
                        }
                        // Direction: the gradient plus noise, unit length.
                        let mut v: Vec<f32> = grad[block.clone()]
                            .iter()
                            .map(|g| {
                                g + 0.1
                                    * (rng.random::<f32>() - 0.5)
                                    * grad[block.clone()]
                                        .iter()
                                        .map(|g| g.abs())
                                        .fold(0.0, f32::max)
                            })
                            .collect();
                        let norm = v.iter().map(|a| (a * a) as f64).sum::<f64>().sqrt() as f32;
                        if norm == 0.0 {
                            continue;
                        }
                        v.iter_mut().for_each(|a| *a /= norm);
                        let analytic: f64 = grad[block.clone()]
                            .iter()
                            .zip(&v)
                            .map(|(g, v)| (g * v) as f64)
                            .sum();
                        // A small step: the ReLU network is only piecewise smooth, and a large
                        // step crosses units switching on or off.
                        let fd_at = |h: f32| {
                            let mut fp = flow.clone();
                            let mut fm = flow.clone();
                            for (k, p) in block.clone().enumerate() {
                                fp.params_mut()[p] += h * v[k];
                                fm.params_mut()[p] -= h * v[k];
                            }
                            (loss_at(&fp, &x, ctx, &w) - loss_at(&fm, &x, ctx, &w))
                                / (2.0 * h as f64)
                        };
                        // Where parameters move a bin edge across a point, log q has a kink in
                        // θ; a step that straddles it is off. Two step sizes rarely both do,
                        // while a wrong gradient fails both.
                        let fd = fd_at(1e-3);
                        let close = |fd: f64| {
                            (fd - analytic).abs() <= 1e-2 * fd.abs().max(analytic.abs()) + 1e-5
                        };
                        assert!(
                            close(fd) || close(fd_at(2e-4)),
                            "dim {dim} {t:?} layer offset {}: analytic {analytic} vs finite difference {fd}",
                            block.start
                        );
                    }
                }
            }
        }
    }
}

#[test]
fn on_policy_tape_gives_the_recomputed_gradient() {
    for t in TRANSFORMS {
        let flow = random_flow(3, t, 0, 0.3);
        let mut rng = Pcg64Mcg::seed_from_u64(17);
        let s = flow.sample_for_training(700, None, &mut rng).unwrap();
        let w: Vec<f32> = (0..700).map(|_| rng.random::<f32>() / 700.0).collect();
        let g_fast = flow.backward(s.tape.as_ref().unwrap(), &w).unwrap();
        let eval = flow.log_density_for_training(&s.x, None).unwrap();
        let g_slow = flow.backward(&eval.tape, &w).unwrap();
        let scale = g_slow.iter().map(|g| g.abs()).fold(0.0f32, f32::max);
        let worst = g_fast
            .iter()
            .zip(&g_slow)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        // The two passes differ only by the round trip of intermediate values through f32.
        assert!(
            worst <= 1e-3 * scale,
            "{t:?}: worst difference {worst} of {scale}"
        );
    }
}

#[test]
fn a_batch_cut_into_uneven_chunks_has_the_gradient_of_its_pieces() {
    // 1000 rows run as 7 chunks of 128 and one of 104 (`kernels::chunk_rows`); each 50-row
    // piece on its own is one chunk. The gradient is a sum over rows, so the pieces' gradients
    // add up to the batch's, up to f32 rounding, only if every chunk reads its own rows' weights.
    assert_eq!(crate::kernels::chunk_rows(1000), 128);
    gradient_of_pieces(1000, 50);
}

#[test]
fn a_batch_of_more_chunks_than_gradient_groups_has_the_gradient_of_its_pieces() {
    // 9000 rows: 17 chunks of 512 and one of 296, more than `kernels::GRADIENT_GROUPS`, so the
    // backward pass sums two chunks per group (the last group holds the short chunk).
    let n = 9000;
    assert_eq!(crate::kernels::chunk_rows(n), 512);
    assert!(n.div_ceil(512) > crate::kernels::GRADIENT_GROUPS);
    gradient_of_pieces(n, 1000);
}

/// The gradient of `n` rows in one batch against the sum of its `piece`-row pieces' gradients.
fn gradient_of_pieces(n: usize, piece: usize) {
    for t in TRANSFORMS {
        let flow = random_flow(3, t, 2, 0.3);
        let x = uniform_points(n, 3, 21);
        let ctx = uniform_points(n, 2, 22);
        let mut rng = Pcg64Mcg::seed_from_u64(23);
        let w: Vec<f32> = (0..n).map(|_| rng.random::<f32>() / n as f32).collect();
        let eval = flow.log_density_for_training(&x, Some(&ctx)).unwrap();
        let whole = flow.backward(&eval.tape, &w).unwrap();
        let mut pieces = vec![0.0f64; whole.len()];
        for p in 0..n / piece {
            let rows = p * piece..(p + 1) * piece;
            let eval = flow
                .log_density_for_training(
                    &x[rows.start * 3..rows.end * 3],
                    Some(&ctx[rows.start * 2..rows.end * 2]),
                )
                .unwrap();
            let g = flow.backward(&eval.tape, &w[rows]).unwrap();
            pieces.iter_mut().zip(&g).for_each(|(a, g)| *a += *g as f64);
        }
        let scale = pieces.iter().map(|g| g.abs()).fold(0.0f64, f64::max);
        let worst = whole
            .iter()
            .zip(&pieces)
            .map(|(a, b)| (*a as f64 - b).abs())
            .fold(0.0f64, f64::max);
        assert!(
            worst <= 1e-4 * scale,
            "{t:?}: worst difference {worst} of {scale}"
        );
        // Shifting the weights by one row (what a chunk reading another chunk's weights sees)
        // is far outside that tolerance.
        let shifted: Vec<f32> = w.iter().cycle().skip(1).take(n).copied().collect();
        let other = flow.backward(&eval.tape, &shifted).unwrap();
        let moved = whole
            .iter()
            .zip(&other)
            .map(|(a, b)| (a - b).abs() as f64)
            .fold(0.0f64, f64::max);
        assert!(
            moved > 1e-2 * scale,
            "{t:?}: the test cannot see misread weights"
        );
    }
}

#[test]
fn chunks_depend_on_the_batch_alone_and_spread_small_batches() {
    use crate::kernels::{chunk_rows, CHUNK_ROWS, MIN_CHUNK_ROWS};
    assert_eq!(chunk_rows(1), MIN_CHUNK_ROWS);
    assert_eq!(chunk_rows(1024), 128);
    assert_eq!(chunk_rows(1022), 128);
    assert_eq!(chunk_rows(256), MIN_CHUNK_ROWS);
    assert_eq!(chunk_rows(65_536), CHUNK_ROWS);
    for rows in [64usize, 100, 512, 1000, 1024, 3000, 4096, 5000] {
        let c = chunk_rows(rows);
        assert!(c.is_power_of_two() && (MIN_CHUNK_ROWS..=CHUNK_ROWS).contains(&c));
        // Between MIN_CHUNKS/2 and MIN_CHUNKS items (the item a power of two) unless an item
        // would fall below MIN_CHUNK_ROWS rows or rise above CHUNK_ROWS.
        let (items, most) = (rows.div_ceil(c), crate::kernels::MIN_CHUNKS);
        assert!(
            (c == MIN_CHUNK_ROWS && items <= most)
                || (c == CHUNK_ROWS && items > most / 2)
                || (most / 2 < items && items <= most),
            "{rows} rows in {items} chunks of {c}"
        );
    }
}

#[test]
fn stale_tapes_and_bad_weights_are_errors() {
    let mut flow = random_flow(2, TransformKind::Quadratic { bins: 4 }, 0, 0.1);
    let mut rng = Pcg64Mcg::seed_from_u64(1);
    let s = flow.sample_for_training(10, None, &mut rng).unwrap();
    assert!(flow.backward(s.tape.as_ref().unwrap(), &[0.1; 9]).is_err());
    flow.params_mut()[0] += 1.0;
    assert!(flow.backward(s.tape.as_ref().unwrap(), &[0.1; 10]).is_err());
    // A tape belongs to the density that recorded it: not to a clone changed since, nor to
    // another flow of the same shape, nor to another kind of density.
    let mut rng = Pcg64Mcg::seed_from_u64(2);
    let s = flow.sample_for_training(10, None, &mut rng).unwrap();
    let tape = s.tape.as_ref().unwrap();
    assert!(flow.backward(tape, &[0.1; 10]).is_ok());
    let twin = random_flow(2, TransformKind::Quadratic { bins: 4 }, 0, 0.1);
    assert!(matches!(
        twin.backward(tape, &[0.1; 10]),
        Err(Error::Config(_))
    ));
    let ms = crate::flow::multiscale::MultiScale::new(crate::flow::multiscale::MultiScaleConfig {
        width: 2,
        height: 2,
        transform: TransformKind::Affine,
        scales: 0,
        features: 2,
        blocks: 0,
        seed: 0,
    })
    .unwrap();
    let x = [0.5f32; 4 * 10];
    let other = ms.log_density_for_training(&x, None).unwrap().tape;
    assert!(matches!(
        flow.backward(&other, &[0.1; 10]),
        Err(Error::Config(_))
    ));
}

#[test]
fn a_trainer_trains_any_density_the_defensive_mixture_included() {
    // The mixture's gradient is that of its own log-likelihood, so maximum likelihood on points
    // bunched near (0.2, 0.2) raises its density there.
    let flow = random_flow(2, TransformKind::Quadratic { bins: 8 }, 0, 0.0);
    let mix = crate::flow::mixture::DefensiveMixture::new(flow, 0.1).unwrap();
    let mut trainer =
        crate::train::Trainer::new(mix, crate::loss::Loss::Nll, Default::default()).unwrap();
    let mut rng = Pcg64Mcg::seed_from_u64(4);
    let data: Vec<f32> = (0..2 * 512)
        .map(|_| (0.2 + 0.05 * (rng.random::<f32>() - 0.5)).clamp(0.0, 1.0))
        .collect();
    let before = trainer.flow().log_density(&data, None).unwrap()[0];
    for _ in 0..40 {
        trainer.step(&data, None, &[], &[0.0; 512]).unwrap();
    }
    let after = trainer.flow().log_density(&data, None).unwrap()[0];
    assert!(before.abs() < 1e-6, "the untrained mixture is uniform");
    // The mixture's density is at most λ + (1 − λ)·q; a rise of ln 2 needs q ≥ 2.1 there.
    assert!(
        after > std::f64::consts::LN_2,
        "ln q_mix went from {before} to {after}"
    );
}

/// Runs `f` in a pool of `threads` threads (for the tests that compare thread counts).
pub(crate) fn run_threads<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> T {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap()
        .install(f)
}

#[test]
fn same_seed_gives_identical_results_on_one_and_two_threads() {
    let job = || {
        let flow = random_flow(4, TransformKind::Quadratic { bins: 8 }, 0, 0.3);
        let mut trainer =
            crate::train::Trainer::new(flow, crate::loss::Loss::Kl, Default::default()).unwrap();
        let mut rng = Pcg64Mcg::seed_from_u64(5);
        for _ in 0..3 {
            let s = trainer
                .flow()
                .sample_for_training(1500, None, &mut rng)
                .unwrap();
            let f: Vec<f64> =
                s.x.chunks(4)
                    .map(|p| p.iter().map(|&v| v as f64).product())
                    .collect();
            trainer.step_on_policy(&s, &f).unwrap();
        }
        let s = trainer.flow().sample(1500, None, &mut rng).unwrap();
        let lq = trainer.flow().log_density(&s.x, None).unwrap();
        (s.x, s.log_q, lq, trainer.flow().params().to_vec())
    };
    let one = run_threads(1, job);
    let two = run_threads(2, job);
    assert!(one
        .0
        .iter()
        .zip(&two.0)
        .all(|(a, b)| a.to_bits() == b.to_bits()));
    assert!(one
        .1
        .iter()
        .zip(&two.1)
        .all(|(a, b)| a.to_bits() == b.to_bits()));
    assert!(one
        .2
        .iter()
        .zip(&two.2)
        .all(|(a, b)| a.to_bits() == b.to_bits()));
    assert!(one
        .3
        .iter()
        .zip(&two.3)
        .all(|(a, b)| a.to_bits() == b.to_bits()));
}

#[test]
fn bad_input_is_an_error() {
    let flow = random_flow(2, TransformKind::Quadratic { bins: 4 }, 0, 0.1);
    assert!(matches!(
        flow.log_density(&[0.5, 1.5], None),
        Err(Error::OutOfDomain { .. })
    ));
    assert!(matches!(
        flow.log_density(&[0.5, -0.0001], None),
        Err(Error::OutOfDomain { .. })
    ));
    assert!(matches!(
        flow.log_density(&[f32::NAN, 0.5], None),
        Err(Error::OutOfDomain { .. })
    ));
    assert!(matches!(
        flow.log_density(&[0.5, 0.5, 0.5], None),
        Err(Error::Dimension { .. })
    ));
    assert!(matches!(
        flow.log_density(&[0.5, 0.5], Some(&[1.0])),
        Err(Error::Dimension { .. })
    ));
    // Ends of the cube are valid.
    assert!(flow.log_density(&[0.0, 1.0], None).unwrap()[0].is_finite());
    let ctx_flow = random_flow(2, TransformKind::Affine, 3, 0.1);
    let mut rng = Pcg64Mcg::seed_from_u64(0);
    assert!(ctx_flow.sample(2, None, &mut rng).is_err());
    assert!(ctx_flow.sample(2, Some(&[0.0; 5]), &mut rng).is_err());
    assert!(ctx_flow
        .sample(1, Some(&[0.0, f32::NAN, 1.0]), &mut rng)
        .is_err());
    for bad in [
        FlowConfig {
            dim: 0,
            ..FlowConfig::new(2)
        },
        FlowConfig {
            transform: TransformKind::Quadratic { bins: 0 },
            ..FlowConfig::new(2)
        },
        FlowConfig {
            transform: TransformKind::Linear { bins: 100_000 },
            ..FlowConfig::new(2)
        },
        FlowConfig {
            hidden_width: 0,
            ..FlowConfig::new(2)
        },
        FlowConfig {
            blob_bins: 0,
            ..FlowConfig::new(2)
        },
    ] {
        assert!(matches!(Flow::new(bad), Err(Error::Config(_))));
    }
}

#[test]
fn densities_stay_finite_at_the_ends_and_for_extreme_weights() {
    for t in TRANSFORMS {
        let flow = random_flow(2, t, 0, 3.0);
        let x = [0.0, 0.0, 1.0, 1.0, 0.0, 1.0, 1.0, 0.0, 0.5, 1.0];
        let lq = flow.log_density(&x, None).unwrap();
        assert!(lq.iter().all(|l| l.is_finite()), "{t:?}: {lq:?}");
        let mut rng = Pcg64Mcg::seed_from_u64(2);
        let s = flow.sample(5000, None, &mut rng).unwrap();
        assert!(s.log_q.iter().all(|l| l.is_finite()));
        assert!(s.x.iter().all(|v| (0.0..=1.0).contains(v)));
    }
}

#[test]
fn a_conditioned_flow_at_a_context_is_the_unconditioned_flow_it_gives() {
    for transform in TRANSFORMS {
        let flow = random_flow(3, transform, 4, 0.3);
        let x = uniform_points(200, 3, 5);
        for ctx in [[0.0f32, 1.0, 0.0, 0.0], [0.3, -0.2, 0.9, 1.5]] {
            let fixed = flow.at_context(&ctx).unwrap();
            assert_eq!(fixed.context_dim(), 0);
            let rows: Vec<f32> = ctx.iter().copied().cycle().take(200 * 4).collect();
            let want = flow.log_density(&x, Some(&rows)).unwrap();
            let got = fixed.log_density(&x, None).unwrap();
            for (a, b) in want.iter().zip(&got) {
                assert!(
                    (a - b).abs() < 1e-4 * (1.0 + a.abs()),
                    "{transform:?}: {a} vs {b}"
                );
            }
            // The same latents map to the same points.
            let s = flow
                .sample(50, Some(&rows[..200]), &mut Pcg64Mcg::seed_from_u64(9))
                .unwrap();
            let t = fixed
                .sample(50, None, &mut Pcg64Mcg::seed_from_u64(9))
                .unwrap();
            assert!(s.x.iter().zip(&t.x).all(|(a, b)| (a - b).abs() < 1e-5));
        }
    }
    let plain = random_flow(2, TransformKind::Affine, 0, 0.3);
    assert!(plain.at_context(&[]).is_err());
    let flow = random_flow(2, TransformKind::Affine, 3, 0.3);
    assert!(flow.at_context(&[1.0]).is_err());
}
