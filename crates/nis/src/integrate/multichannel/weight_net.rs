//! A network that refines the channel weights, as MadNIS does (Heimel, Winterhalder, Butter,
//! Isaacson, Krause, Maltoni, Mattelaer, Plehn, "MadNIS — Neural multi-channel importance
//! sampling", SciPost Phys. 15, 141 (2023), §2.3): α_k(x) = a_k g_k(x) e^{N_k(x)} / Σ_j a_j g_j(x)
//! e^{N_j(x)} (g the channels' enhancements w̃ when they have them), N = B·tanh(r/B) of a small
//! MLP r of x with one output per channel. Σ_k α_k = 1 at every x whatever N is, so every
//! estimate made with a fixed N is unbiased; N = 0 is Kleiss–Pittau's α.
//!
//! Given the parts' samplers Q_p and the points shared among them by Neyman's allocation, the
//! estimate's σ per evaluation is Σ_p σ_p, σ_p² = Var_{Q_p}(α_k f/Q_p). N is fitted to minimise
//! it after the parts adapt, on fresh points of every part's frozen sampler (half to fit, half
//! held out; each step on a few parts drawn at random, so that a fit's cost does not grow with
//! the channels), and kept only when it lowers (Σσ_p)² on the held-out half by [`MIN_GAIN`].
//! It moves each x's share towards the channels whose trained samplers cover x best (the
//! pointwise optimum at fixed samplers is α_k ∝ n_k Q_k(x), which would need every channel's
//! inverse map).

use rand::seq::index::sample;
use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;
use serde::{Deserialize, Serialize};

use super::config::Sign;
use crate::error::Result;
use crate::nn::mlp::Layout;
use crate::nn::{Adam, AdamConfig, Mlp};

/// Hidden layers' width.
const WIDTH: usize = 32;
/// Adam steps at most, each on a minibatch of [`MINIBATCH`] rows of the fitting half of
/// [`PARTS_PER_STEP`] parts drawn at random (all parts when they are fewer): a step's cost does
/// not grow with the number of channels.
const STEPS: usize = 300;
const MINIBATCH: usize = 1024;
const PARTS_PER_STEP: usize = 8;
/// Steps between the checks on the held-out half; the fit stops after [`PATIENCE`] checks that
/// did not lower the held-out Σσ by [`PROGRESS`] (relative) since the last that did, and keeps
/// the best. Most of the gain comes in the first 25–50 steps.
const CHECK_EVERY: usize = 25;
const PATIENCE: usize = 2;
const PROGRESS: f64 = 0.005;
/// The largest correction |N_k(x)| (see [`squash`]): larger bounds lowered the variance little
/// more, for far heavier tails, and smaller ones lost (docs/results/integration.md, "Learned
/// channel weights").
const BOUND: f32 = 0.5;
/// The held-out (Σσ)² must fall by this factor for the network to be kept.
const MIN_GAIN: f64 = 1.05;

/// The fitted correction N (saved with a multi-channel integrator).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct WeightNet {
    /// Inputs, hidden widths, outputs (the channels).
    dims: Vec<usize>,
    params: Vec<f32>,
}

impl WeightNet {
    fn mlp(&self) -> Mlp {
        mlp(&self.dims)
    }

    /// Whether it takes points of `dim` coordinates, corrects `channels` channels and has the
    /// parameters its shape needs (a loaded one).
    pub(super) fn fits(&self, dim: usize, channels: usize) -> bool {
        self.dims.len() >= 2
            && self.dims[0] == dim
            && self.dims[self.dims.len() - 1] == channels
            && self.dims.iter().all(|d| *d > 0)
            && self.params.len() == self.mlp().param_count()
            && self.params.iter().all(|p| p.is_finite())
    }

    /// N(x) at the points `x` (n × d): n × K, row-major.
    pub(super) fn corrections(&self, x: &[f64]) -> Vec<f32> {
        let input: Vec<f32> = x.iter().map(|v| *v as f32).collect();
        self.mlp()
            .forward_batch(&self.params, &input)
            .outputs()
            .map(|r| squash(*r).0)
            .collect()
    }
}

/// The network's output r becomes N = B·tanh(r/B), B = [`BOUND`], with dN/dr: a correction
/// moves a channel's weight by at most e^{±B}, so it cannot make a part's weights unbounded where
/// its points were too few to show it.
fn squash(r: f32) -> (f32, f32) {
    let t = (r / BOUND).tanh();
    (BOUND * t, 1.0 - t * t)
}

fn mlp(dims: &[usize]) -> Mlp {
    Mlp {
        dims: dims.to_vec(),
        output: Layout::Rows,
    }
}

/// e^{N_j − max N} of one point's corrections `n`, into `e`: the common factor e^{max N}
/// cancels in α_k, and none of these overflows.
pub(super) fn exp_shifted(n: &[f32], e: &mut [f64]) {
    let top = n.iter().fold(f32::MIN, |m, v| m.max(*v)) as f64;
    e.iter_mut()
        .zip(n)
        .for_each(|(e, n)| *e = (*n as f64 - top).exp());
}

/// The weights α_j(x) of one point (into `alpha`) from its a_j g_j(x) (`ag`) and corrections N_j
/// (`n`; `None`: 0).
fn alphas(ag: &[f64], n: Option<&[f32]>, alpha: &mut [f64]) {
    match n {
        Some(n) => exp_shifted(n, alpha),
        None => alpha.fill(1.0),
    }
    alpha.iter_mut().zip(ag).for_each(|(a, ag)| *a *= ag);
    let total: f64 = alpha.iter().sum();
    alpha.iter_mut().for_each(|a| *a /= total);
}

/// A part's points for the fit: its channel, and per point x, a_j g_j(x) (all j) and f_s/Q_p,
/// f_s the part's sign of f and Q_p its sampler's density at x.
pub(super) struct PartPoints {
    pub(super) channel: usize,
    pub(super) x: Vec<f64>,
    pub(super) ag: Vec<f64>,
    pub(super) f_over_q: Vec<f64>,
}

impl PartPoints {
    /// From the part's points `x`, their values `fx`, 1/Q_p, the channels' densities `g`
    /// (n × K) and the weights `a`.
    pub(super) fn new(
        channel: usize,
        sign: Sign,
        x: Vec<f64>,
        fx: &[f64],
        inv_q: &[f64],
        g: &[f64],
        a: &[f64],
    ) -> PartPoints {
        let k = a.len();
        let ag = g
            .chunks_exact(k)
            .flat_map(|row| row.iter().zip(a).map(|(g, a)| g * a))
            .collect();
        let f_over_q = fx
            .iter()
            .zip(inv_q)
            .map(|(f, iq)| {
                let f = match sign {
                    Sign::Both => *f,
                    Sign::Plus => f.max(0.0),
                    Sign::Minus => (-f).max(0.0),
                };
                f * iq
            })
            .collect();
        PartPoints {
            channel,
            x,
            ag,
            f_over_q,
        }
    }

    fn len(&self) -> usize {
        self.f_over_q.len()
    }

    /// The rows `rows` of these points.
    fn rows(&self, rows: &[usize], dim: usize, k: usize) -> PartPoints {
        let pick = |v: &[f64], w: usize| {
            rows.iter()
                .flat_map(|&i| v[i * w..(i + 1) * w].to_vec())
                .collect()
        };
        PartPoints {
            channel: self.channel,
            x: pick(&self.x, dim),
            ag: pick(&self.ag, k),
            f_over_q: rows.iter().map(|&i| self.f_over_q[i]).collect(),
        }
    }
}

/// σ_p of every part's weights w = α_k f_s/Q_p under the corrections `n` (per part, n × K; `None`:
/// N = 0) and, when `grads` is given, ∂(Σ_p σ_p)/∂N into it (per part, n × K).
fn sigmas(
    parts: &[PartPoints],
    n: Option<&[Vec<f32>]>,
    k: usize,
    mut grads: Option<&mut Vec<Vec<f32>>>,
) -> Vec<f64> {
    let mut out = Vec::with_capacity(parts.len());
    let mut alpha = vec![0.0; k];
    for (p, part) in parts.iter().enumerate() {
        let m = part.len();
        let mut w = vec![0.0; m];
        let mut all_alpha = vec![0.0; if grads.is_some() { m * k } else { 0 }];
        for i in 0..m {
            let ni = n.map(|n| &n[p][i * k..(i + 1) * k]);
            alphas(&part.ag[i * k..(i + 1) * k], ni, &mut alpha);
            w[i] = alpha[part.channel] * part.f_over_q[i];
            if grads.is_some() {
                all_alpha[i * k..(i + 1) * k].copy_from_slice(&alpha);
            }
        }
        let mean = w.iter().sum::<f64>() / m as f64;
        let var = w.iter().map(|v| (v - mean) * (v - mean)).sum::<f64>() / m as f64;
        let sd = var.sqrt();
        out.push(sd);
        if let Some(g) = grads.as_deref_mut() {
            // ∂σ/∂w_i = (w_i − mean)/(m σ); ∂w_i/∂N_j = w_i (δ_jk − α_j).
            let mut gp = vec![0.0f32; m * k];
            if sd > 0.0 {
                for i in 0..m {
                    let d = (w[i] - mean) / (m as f64 * sd) * w[i];
                    for j in 0..k {
                        let delta = if j == part.channel { 1.0 } else { 0.0 };
                        gp[i * k + j] = (d * (delta - all_alpha[i * k + j])) as f32;
                    }
                }
            }
            g.push(gp);
        }
    }
    out
}

/// What a fit found: the network when it is kept, and every part's σ per evaluation on the
/// held-out points under the α the integrator will use (for Neyman's allocation).
pub(super) struct Fit {
    pub(super) net: Option<WeightNet>,
    pub(super) sigmas: Vec<f64>,
}

/// Each part's points split at random into a training half and a held-out half. Each part's
/// points are dropped once split: they are n × K numbers (a_j g_j), the fit's memory with many
/// channels.
fn split_halves(
    points: Vec<PartPoints>,
    rng: &mut Pcg64Mcg,
    dim: usize,
    k: usize,
) -> (Vec<PartPoints>, Vec<PartPoints>) {
    let (mut train, mut held) = (Vec::new(), Vec::new());
    for p in points {
        let m = p.len();
        let order = sample(rng, m, m).into_vec();
        train.push(p.rows(&order[..m / 2], dim, k));
        held.push(p.rows(&order[m / 2..], dim, k));
    }
    (train, held)
}

/// One step's points: at most [`PARTS_PER_STEP`] parts, of each at most [`MINIBATCH`] rows.
fn minibatch(train: &[PartPoints], rng: &mut Pcg64Mcg, dim: usize, k: usize) -> Vec<PartPoints> {
    let chosen = if train.len() > PARTS_PER_STEP {
        sample(rng, train.len(), PARTS_PER_STEP).into_vec()
    } else {
        (0..train.len()).collect()
    };
    chosen
        .iter()
        .map(|&i| &train[i])
        .map(|p| {
            let rows: Vec<usize> = if p.len() <= MINIBATCH {
                (0..p.len()).collect()
            } else {
                sample(rng, p.len(), MINIBATCH).into_vec()
            };
            p.rows(&rows, dim, k)
        })
        .collect()
}

/// The parts' points as the network's f32 inputs.
fn inputs(parts: &[PartPoints]) -> Vec<Vec<f32>> {
    parts
        .iter()
        .map(|p| p.x.iter().map(|v| *v as f32).collect())
        .collect()
}

/// ∂(Σ_p σ_p)/∂θ on `batch` into `grad` (`one`: scratch of the same length).
fn sigma_gradient(
    mlp: &Mlp,
    params: &[f32],
    batch: &[PartPoints],
    k: usize,
    grad: &mut [f32],
    one: &mut [f32],
) {
    let forward: Vec<_> = inputs(batch)
        .iter()
        .map(|x| mlp.forward_batch(params, x))
        .collect();
    let n: Vec<Vec<f32>> = forward
        .iter()
        .map(|f| f.outputs().map(|r| squash(*r).0).collect())
        .collect();
    let mut g = Vec::new();
    sigmas(batch, Some(&n), k, Some(&mut g));
    grad.iter_mut().for_each(|v| *v = 0.0);
    for (f, gp) in forward.iter().zip(g.iter_mut()) {
        gp.iter_mut()
            .zip(f.outputs())
            .for_each(|(g, r)| *g *= squash(*r).1);
        mlp.backward_batch(params, f, gp, one);
        grad.iter_mut().zip(one.iter()).for_each(|(t, o)| *t += o);
    }
}

/// Fits N to `points` (module docs), seeded by `seed`, in steps whose rows together stay within
/// `max_rows` (beyond the first step).
pub(super) fn fit(
    points: Vec<PartPoints>,
    dim: usize,
    k: usize,
    seed: u64,
    max_rows: usize,
) -> Result<Fit> {
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    let (train, held) = split_halves(points, &mut rng, dim, k);
    let base = sigmas(&held, None, k, None);
    let base_total: f64 = base.iter().sum();
    let dims = vec![dim, WIDTH, WIDTH, k];
    let mlp = mlp(&dims);
    let mut params = vec![0.0f32; mlp.param_count()];
    mlp.init(&mut params, &mut rng);
    let mut adam = Adam::new(
        AdamConfig {
            learning_rate: 3e-3,
            ..AdamConfig::default()
        },
        params.len(),
    )?;
    let held_x = inputs(&held);
    let held_sigmas = |params: &[f32]| {
        let n: Vec<Vec<f32>> = held_x
            .iter()
            .map(|x| {
                let f = mlp.forward_batch(params, x);
                f.outputs().map(|r| squash(*r).0).collect()
            })
            .collect();
        sigmas(&held, Some(&n), k, None)
    };
    // The best held-out Σσ and its parameters and σ_p; the last Σσ that made progress and the
    // checks since it.
    let (mut best, mut best_fit) = (base_total, None);
    let (mut mark, mut since) = (base_total, 0);
    let mut grad = vec![0.0f32; params.len()];
    let mut one = vec![0.0f32; params.len()];
    let mut fitted_rows = 0;
    for step in 1..=STEPS {
        let batch = minibatch(&train, &mut rng, dim, k);
        sigma_gradient(&mlp, &params, &batch, k, &mut grad, &mut one);
        adam.step(&mut params, &grad)?;
        fitted_rows += batch.iter().map(PartPoints::len).sum::<usize>();
        let last = fitted_rows >= max_rows;
        if step % CHECK_EVERY == 0 || last {
            let sigmas = held_sigmas(&params);
            let total: f64 = sigmas.iter().sum();
            if total < best {
                (best, best_fit) = (total, Some((params.clone(), sigmas)));
            }
            if total < mark * (1.0 - PROGRESS) {
                (mark, since) = (total, 0);
            } else {
                since += 1;
            }
            if since >= PATIENCE || last {
                break;
            }
        }
    }
    // Kept when it lowers the held-out variance (Σσ)² by at least the factor MIN_GAIN.
    let kept = best_fit.filter(|_| (base_total / best).powi(2) >= MIN_GAIN);
    Ok(match kept {
        Some((params, sigmas)) => Fit {
            sigmas,
            net: Some(WeightNet { dims, params }),
        },
        None => Fit {
            net: None,
            sigmas: base,
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_weights_sum_to_one_whatever_the_correction() {
        let ag = [0.2, 3.0, 0.0, 1.5];
        let mut alpha = [0.0; 4];
        alphas(&ag, None, &mut alpha);
        assert!((alpha.iter().sum::<f64>() - 1.0).abs() < 1e-15);
        assert!((alpha[1] - 3.0 / 4.7).abs() < 1e-15);
        alphas(&ag, Some(&[5.0, -3.0, 80.0, 0.5]), &mut alpha);
        assert!((alpha.iter().sum::<f64>() - 1.0).abs() < 1e-15);
        // A channel without density at x gets no share, whatever its correction.
        assert_eq!(alpha[2], 0.0);
    }

    #[test]
    fn corrections_are_bounded_and_their_derivative_matches_finite_differences() {
        for r in [-40.0f32, -2.5, -0.3, 0.0, 0.7, 3.0, 1e6] {
            let (n, d) = squash(r);
            assert!(n.abs() <= BOUND);
            let h = 1e-2;
            let fd = (squash(r + h).0 - squash(r - h).0) / (2.0 * h);
            assert!((fd - d).abs() < 1e-3, "at {r}: {fd} vs {d}");
        }
        // Near zero N is r: B·tanh(r/B) = r − r³/(3B²) + …, an alternating series.
        let r = 0.1f32;
        let bound = r.powi(3) / (3.0 * BOUND * BOUND) + 1e-6;
        assert!((squash(r).0 - r).abs() <= bound, "near zero N is r");
    }

    #[test]
    fn the_gradient_of_the_summed_sigmas_matches_finite_differences() {
        let (dim, k) = (2, 3);
        let mut rng = Pcg64Mcg::seed_from_u64(3);
        use rand::Rng;
        let parts: Vec<PartPoints> = (0..k)
            .map(|c| {
                let m = 40;
                PartPoints {
                    channel: c,
                    x: (0..m * dim).map(|_| rng.random()).collect(),
                    ag: (0..m * k).map(|_| rng.random::<f64>() + 0.1).collect(),
                    f_over_q: (0..m).map(|_| rng.random::<f64>() * 3.0).collect(),
                }
            })
            .collect();
        let n: Vec<Vec<f32>> = (0..k)
            .map(|_| (0..40 * k).map(|_| rng.random::<f32>() - 0.5).collect())
            .collect();
        let mut g = Vec::new();
        sigmas(&parts, Some(&n), k, Some(&mut g));
        let total = |n: &[Vec<f32>]| sigmas(&parts, Some(n), k, None).iter().sum::<f64>();
        for (p, i) in [(0, 5), (1, 17), (2, 119)] {
            let h = 1e-2f32;
            let (mut up, mut down) = (n.clone(), n.clone());
            up[p][i] += h;
            down[p][i] -= h;
            let fd = (total(&up) - total(&down)) / (2.0 * h as f64);
            assert!(
                (fd - g[p][i] as f64).abs() < 1e-3 * (1.0 + fd.abs()),
                "{fd} vs {}",
                g[p][i]
            );
        }
    }
}
