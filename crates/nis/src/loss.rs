//! Sample weights of the training gradients (Müller et al. 2019, Sec. 3; DESIGN.md).
//!
//! Every loss here has a gradient of the form −Σ_i w_i ∇θ ln q(X_i; θ) with X_i drawn from a
//! proposal of density q_s (the flow itself on-policy, an older flow, or uniform):
//! - KL divergence D_KL(p‖q): w_i ∝ |f_i| / q_s(X_i)                      (Eq. 7)
//! - χ² divergence / estimator variance: w_i ∝ f_i² / (q(X_i;θ)·q_s(X_i)) (Eq. 8; on-policy
//!   (f_i/q_i)²)
//! - negative log-likelihood of data (density estimation): w_i = 1/N.
//!
//! The unknown integral F only scales the gradient, which Adam absorbs. Weights are formed from
//! logarithms in f64 and normalised to sum to one before they enter the f32 backward pass: far
//! from its peaks a 16-dimensional integrand is ~1e-77, which underflows f32 but still points
//! toward the peaks.

use serde::{Deserialize, Serialize};

use crate::comm::Comm;
use crate::error::{Error, Result};

/// The divergence a flow is trained to minimise.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Loss {
    /// Kullback–Leibler divergence D_KL(p‖q): mode-covering in p, the paper's default.
    Kl,
    /// Pearson χ² divergence, proportional to the variance of the estimator f/q.
    ChiSquare,
    /// Negative log-likelihood of the points (no integrand: density estimation).
    Nll,
    /// The integrator's choice ([`Loss::resolve`]): KL for a whole integrand, χ² for the parts
    /// of a multi-channel integral.
    Auto,
}

impl Loss {
    /// The loss `Auto` stands for: KL for a whole integrand (mode-covering: it finds every peak
    /// more often), χ² for a part of a multi-channel integral (`part`), which the channel's map
    /// has already made nearly flat over its cube, where minimising the variance itself gave
    /// lower variance per evaluation on every multi-channel and signed example
    /// (docs/results/integration.md, "One flow shared by the channels"). Other losses unchanged.
    pub fn resolve(self, part: bool) -> Loss {
        match self {
            Loss::Auto if part => Loss::ChiSquare,
            Loss::Auto => Loss::Kl,
            other => other,
        }
    }
}

impl std::str::FromStr for Loss {
    type Err = Error;
    fn from_str(s: &str) -> Result<Loss> {
        match s {
            "kl" => Ok(Loss::Kl),
            "chi2" | "chi_square" | "variance" => Ok(Loss::ChiSquare),
            "nll" => Ok(Loss::Nll),
            "auto" => Ok(Loss::Auto),
            _ => Err(Error::Config(format!(
                "unknown loss {s:?} (kl, chi2, nll, auto)"
            ))),
        }
    }
}

/// Normalised weights for one batch, with estimates computed on the way.
#[derive(Clone, Debug)]
pub struct Weights {
    /// w_i, summing to one (all zero when every f_i is zero).
    pub w: Vec<f32>,
    /// Estimate of ∫ |f| from this batch: mean of |f_i|/q_s,i (0 for NLL).
    pub integral: f64,
    /// Relative variance Var(|f|/q_s)/F² of the batch's weights (0 for NLL).
    pub rel_var: f64,
}

/// Computes the weights of `loss` for integrand values `f` at points with current log-density
/// `log_q` and proposal log-density `log_q_sample`. Non-finite inputs are errors.
pub fn weights(loss: Loss, f: &[f64], log_q: &[f64], log_q_sample: &[f64]) -> Result<Weights> {
    weights_annealed(loss, f, log_q, log_q_sample, 1.0)
}

/// [`weights`] for the tempered target |f|^β (β ≤ 1 flattens it): early in training, a flow that
/// has not yet found every mode sees them all through the flattened target (annealing).
pub fn weights_annealed(
    loss: Loss,
    f: &[f64],
    log_q: &[f64],
    log_q_sample: &[f64],
    beta: f64,
) -> Result<Weights> {
    weights_across(&Comm::default(), loss, f, log_q, log_q_sample, beta)
}

/// [`weights_annealed`] for a batch split over the ranks of `comm` (data-parallel training):
/// each rank passes its share and gets its share's weights, normalised so that the weights of
/// the whole batch sum to one (the maximum and the sum of the exponentials are reduced over the
/// ranks). `integral` and `rel_var` describe this rank's share. An invalid input on any rank is
/// an error on every rank ([`Comm::check`]).
pub fn weights_across(
    comm: &Comm,
    loss: Loss,
    f: &[f64],
    log_q: &[f64],
    log_q_sample: &[f64],
    beta: f64,
) -> Result<Weights> {
    let loss = loss.resolve(false);
    comm.check(check_inputs(loss, f, log_q, log_q_sample))?;
    let n = log_q_sample.len();
    if loss == Loss::Nll {
        let total = comm.sum(n as f64) as usize;
        return Ok(Weights {
            w: vec![1.0 / total.max(1) as f32; n],
            integral: 0.0,
            rel_var: 0.0,
        });
    }
    let (mut mean, mut m2) = (0.0f64, 0.0f64);
    for (i, (&fi, &ls)) in f.iter().zip(log_q_sample).enumerate() {
        // Welford's update of the mean and variance of |f|/q_s.
        let r = fi.abs() * (-ls).exp();
        let d = r - mean;
        mean += d / (i + 1) as f64;
        m2 += d * (r - mean);
    }
    let rel_var = if mean > 0.0 && n > 1 {
        m2 / (n - 1) as f64 / (mean * mean)
    } else {
        0.0
    };
    let log_w: Vec<f64> = f
        .iter()
        .zip(log_q.iter().zip(log_q_sample))
        .map(|(&fi, (&lq, &ls))| match loss {
            Loss::Kl => beta * fi.abs().ln() - ls,
            _ => 2.0 * beta * fi.abs().ln() - lq - ls,
        })
        .collect();
    let mut max = [log_w.iter().copied().fold(f64::NEG_INFINITY, f64::max)];
    comm.max_f64(&mut max);
    let max = max[0];
    let w = if max == f64::NEG_INFINITY {
        vec![0.0; n]
    } else {
        let e: Vec<f64> = log_w.iter().map(|l| (l - max).exp()).collect();
        let sum = comm.sum(e.iter().sum());
        e.iter().map(|v| (v / sum) as f32).collect()
    };
    Ok(Weights {
        w,
        integral: mean,
        rel_var,
    })
}

/// The inputs' shapes agree and every value is finite.
fn check_inputs(loss: Loss, f: &[f64], log_q: &[f64], log_q_sample: &[f64]) -> Result<()> {
    let n = log_q_sample.len();
    if log_q.len() != n || (loss != Loss::Nll && f.len() != n) {
        return Err(Error::Dimension {
            what: "loss inputs",
            expected: n,
            got: if log_q.len() != n {
                log_q.len()
            } else {
                f.len()
            },
        });
    }
    if let Some(i) = log_q
        .iter()
        .chain(log_q_sample)
        .position(|v| !v.is_finite())
    {
        return Err(Error::NonFinite {
            what: "log-density",
            index: i % n.max(1),
            value: log_q
                .iter()
                .chain(log_q_sample)
                .nth(i)
                .copied()
                .unwrap_or(f64::NAN),
        });
    }
    if loss == Loss::Nll {
        return Ok(());
    }
    if let Some(i) = f.iter().position(|v| !v.is_finite()) {
        return Err(Error::NonFinite {
            what: "integrand value",
            index: i,
            value: f[i],
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weights_follow_their_formulas() {
        let f = [1.0, -2.0, 0.0, 4.0];
        let lq = [0.0, (2.0f64).ln(), 0.0, (0.5f64).ln()];
        let kl = weights(Loss::Kl, &f, &lq, &lq).unwrap();
        // |f|/q = 1, 1, 0, 8 → normalised by 10.
        let want = [0.1, 0.1, 0.0, 0.8];
        for (w, v) in kl.w.iter().zip(want) {
            assert!((*w as f64 - v).abs() < 1e-7);
        }
        assert!((kl.integral - 2.5).abs() < 1e-12);
        let chi = weights(Loss::ChiSquare, &f, &lq, &lq).unwrap();
        // (f/q)² = 1, 1, 0, 64 → /66.
        assert!((chi.w[3] as f64 - 64.0 / 66.0).abs() < 1e-7);
        let nll = weights(Loss::Nll, &[], &lq, &lq).unwrap();
        assert_eq!(nll.w, vec![0.25; 4]);
        // Auto reaching the weights is KL's.
        assert_eq!(weights(Loss::Auto, &f, &lq, &lq).unwrap().w, kl.w);
    }

    #[test]
    fn auto_is_kl_for_a_whole_integrand_and_chi_square_for_a_part() {
        assert_eq!("auto".parse::<Loss>().unwrap(), Loss::Auto);
        assert_eq!(Loss::Auto.resolve(false), Loss::Kl);
        assert_eq!(Loss::Auto.resolve(true), Loss::ChiSquare);
        for l in [Loss::Kl, Loss::ChiSquare, Loss::Nll] {
            assert_eq!(l.resolve(true), l);
            assert_eq!(l.resolve(false), l);
        }
    }

    #[test]
    fn tiny_integrand_values_keep_their_direction() {
        let f = [1e-300, 3e-300];
        let w = weights(Loss::Kl, &f, &[0.0; 2], &[0.0; 2]).unwrap();
        assert!((w.w[1] - 0.75).abs() < 1e-6);
    }

    #[test]
    fn bad_values_are_errors_and_zero_integrands_give_zero_weights() {
        assert!(weights(Loss::Kl, &[f64::NAN], &[0.0], &[0.0]).is_err());
        assert!(weights(Loss::Kl, &[f64::INFINITY], &[0.0], &[0.0]).is_err());
        assert!(weights(Loss::Kl, &[1.0], &[0.0, 0.0], &[0.0]).is_err());
        let w = weights(Loss::ChiSquare, &[0.0, 0.0], &[0.0; 2], &[0.0; 2]).unwrap();
        assert_eq!(w.w, vec![0.0, 0.0]);
        assert_eq!(w.integral, 0.0);
    }
}
