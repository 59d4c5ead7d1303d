//! What is integrated: the [`Integrand`] batch interface (scalar or vector-valued, fallible), the
//! choice of the component a sampler adapts to ([`TrainOn`]), and the checked evaluation every
//! integrator goes through.
//!
//! Vector-valued integrands follow the `vegas` package: f returns k values per point (say a total
//! and the bins of a histogram of an observable), every component is estimated from the same
//! points, and the sampler adapts to one of them (or to the sum of their magnitudes).

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
pub use crate::kernels::points_per_task;

/// A function to integrate over [0, 1]^d, evaluated in batches; it may return several values per
/// point ([`Integrand::components`]) and may fail ([`Error::IntegrandFailed`]).
///
/// Closures `Fn(&[f64]) -> f64 + Sync` are scalar integrands (evaluated in parallel):
/// ```
/// use nis::integrate::Integrand;
/// let f = |x: &[f64]| x[0] * x[1];
/// let mut out = [0.0; 2];
/// f.eval_batch(&[0.5, 0.5, 1.0, 0.25], 2, &mut out).unwrap();
/// assert_eq!(out, [0.25, 0.25]);
/// ```
/// A fallible batch integrand implements the trait itself:
/// ```
/// use nis::integrate::Integrand;
/// use nis::Error;
/// struct Positive;
/// impl Integrand for Positive {
///     fn eval_batch(&self, x: &[f64], _dim: usize, out: &mut [f64]) -> nis::Result<()> {
///         if x.iter().any(|v| *v > 0.99) {
///             return Err(Error::IntegrandFailed { message: "too close to the edge".into() });
///         }
///         out.fill(1.0);
///         Ok(())
///     }
/// }
/// let mut out = [0.0; 1];
/// assert!(Positive.eval_batch(&[0.995, 0.5], 2, &mut out).is_err());
/// ```
pub trait Integrand: Sync {
    /// Writes f at each point of `x` (row-major, `dim` coordinates each) into `out`, which holds
    /// `components()` values per point (row-major: point i's values at `i·k..(i + 1)·k`). An
    /// error stops the integration and is handed to its caller unchanged.
    fn eval_batch(&self, x: &[f64], dim: usize, out: &mut [f64]) -> Result<()>;
    /// The dimension this integrand is defined in, if it has a fixed one.
    fn dim(&self) -> Option<usize> {
        None
    }
    /// Values per point, k ≥ 1 (1: a scalar integrand).
    fn components(&self) -> usize {
        1
    }
}

impl<F: Fn(&[f64]) -> f64 + Sync> Integrand for F {
    fn eval_batch(&self, x: &[f64], dim: usize, out: &mut [f64]) -> Result<()> {
        let chunk = points_per_task(out.len());
        out.par_chunks_mut(chunk)
            .zip(x.par_chunks(chunk * dim))
            .for_each(|(out, x)| {
                for (o, p) in out.iter_mut().zip(x.chunks_exact(dim)) {
                    *o = self(p);
                }
            });
        Ok(())
    }
}

/// A vector-valued integrand from a closure that writes its `components` values for one point,
/// evaluated in parallel like scalar closures.
///
/// ```
/// use nis::integrate::{Integrand, VectorFn};
/// // f and x₀·f of one point, estimated together.
/// let f = VectorFn::new(2, |x: &[f64], out: &mut [f64]| {
///     out[0] = 1.0 + x[1];
///     out[1] = x[0] * (1.0 + x[1]);
/// });
/// let mut out = [0.0; 4];
/// f.eval_batch(&[0.5, 0.0, 1.0, 1.0], 2, &mut out).unwrap();
/// assert_eq!(out, [1.0, 0.5, 2.0, 2.0]);
/// ```
pub struct VectorFn<F> {
    components: usize,
    f: F,
}

impl<F: Fn(&[f64], &mut [f64]) + Sync> VectorFn<F> {
    /// An integrand with `components` values per point, computed by `f(point, values)`.
    pub fn new(components: usize, f: F) -> VectorFn<F> {
        VectorFn { components, f }
    }
}

impl<F: Fn(&[f64], &mut [f64]) + Sync> Integrand for VectorFn<F> {
    fn eval_batch(&self, x: &[f64], dim: usize, out: &mut [f64]) -> Result<()> {
        let k = self.components;
        let chunk = points_per_task(out.len() / k.max(1));
        out.par_chunks_mut(chunk * k)
            .zip(x.par_chunks(chunk * dim))
            .for_each(|(out, x)| {
                for (o, p) in out.chunks_exact_mut(k).zip(x.chunks_exact(dim)) {
                    (self.f)(p, o);
                }
            });
        Ok(())
    }
    fn components(&self) -> usize {
        self.components
    }
}

/// What an adaptive sampler (the flow, the VEGAS+ map and strata) adapts to when the integrand
/// has several components. Every component is estimated either way.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TrainOn {
    /// One component (index from 0); the default is the first.
    Component(usize),
    /// The sum of the components' magnitudes Σ_j |f_j|: a density that covers all of them.
    SumAbs,
}

impl Default for TrainOn {
    fn default() -> Self {
        TrainOn::Component(0)
    }
}

impl TrainOn {
    /// Checks the choice against an integrand with `k` components.
    pub fn check(self, k: usize) -> Result<()> {
        if k == 0 {
            return Err(Error::Config(
                "an integrand needs at least one component".into(),
            ));
        }
        match self {
            TrainOn::Component(i) if i >= k => Err(Error::Config(format!(
                "train_on component {i}, but the integrand has {k} components"
            ))),
            _ => Ok(()),
        }
    }

    /// The values the sampler adapts to, one per point, from `fx` (`n × k`, row-major).
    pub fn target(self, fx: &[f64], k: usize) -> Vec<f64> {
        match self {
            TrainOn::Component(i) => fx.iter().skip(i).step_by(k).copied().collect(),
            TrainOn::SumAbs => fx
                .chunks_exact(k)
                .map(|v| v.iter().map(|c| c.abs()).sum())
                .collect(),
        }
    }
}

/// Evaluates `f` at the points `x` (`dim` coordinates each): `n × k` values, row-major. Integrand
/// errors are passed on; NaN and ±∞ are rejected with an error that names the point.
pub fn evaluate(f: &dyn Integrand, x: &[f64], dim: usize) -> Result<Vec<f64>> {
    let k = f.components();
    let mut out = vec![0.0; x.len() / dim * k];
    // A panicking integrand ends the call with an error, like a failing one: the integrator's
    // state is untouched by a batch it never got back.
    std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        f.eval_batch(x, dim, &mut out)
    }))
    .map_err(|payload| Error::IntegrandFailed {
        message: format!("it panicked: {}", panic_message(payload.as_ref())),
    })??;
    if let Some(i) = out.iter().position(|v| !v.is_finite()) {
        let p = i / k;
        return Err(Error::Integrand {
            point: x[p * dim..(p + 1) * dim].to_vec(),
            value: out[i],
        });
    }
    Ok(out)
}

/// Checks an integrand's declared dimension against the one asked for, and that it has at least
/// one component.
/// The message a panic carried (`&str` or `String` payloads; others have none to show).
fn panic_message(payload: &(dyn std::any::Any + Send)) -> &str {
    payload
        .downcast_ref::<&str>()
        .copied()
        .or_else(|| payload.downcast_ref::<String>().map(String::as_str))
        .unwrap_or("(no message)")
}

pub fn check_dim(f: &dyn Integrand, dim: usize) -> Result<()> {
    if dim == 0 {
        return Err(Error::Config("dimension must be at least 1".into()));
    }
    if f.components() == 0 {
        return Err(Error::Config(
            "an integrand needs at least one component".into(),
        ));
    }
    match f.dim() {
        Some(d) if d != dim => Err(Error::Dimension {
            what: "integrand dimension",
            expected: d,
            got: dim,
        }),
        _ => Ok(()),
    }
}

/// Column `j` of an `n × k` row-major block.
pub(crate) fn column(v: &[f64], k: usize, j: usize) -> Vec<f64> {
    if k == 1 {
        return v.to_vec();
    }
    v.iter().skip(j).step_by(k).copied().collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn small_batches_are_split_for_every_core_and_any_split_gives_the_same_values() {
        // A training batch of 256 points: 16 work items; large batches: 256 points each; an
        // empty batch still gets a valid (non-zero) chunk size.
        assert_eq!(points_per_task(256), 16);
        assert_eq!(256usize.div_ceil(points_per_task(256)), 16);
        assert_eq!(points_per_task(1 << 20), 256);
        assert_eq!(points_per_task(5), 1);
        assert_eq!(points_per_task(0), 1);
        // The values of a batch do not depend on how it is split: a batch of 300 evaluated
        // at once (items of 19) and point by point.
        let f = |x: &[f64]| (x[0] * 3.0).sin() + x[1] * x[1];
        let x: Vec<f64> = (0..600).map(|i| (i as f64 * 0.618_034).fract()).collect();
        let mut whole = vec![0.0; 300];
        f.eval_batch(&x, 2, &mut whole).unwrap();
        for (i, w) in whole.iter().enumerate() {
            let mut one = [0.0];
            f.eval_batch(&x[2 * i..2 * i + 2], 2, &mut one).unwrap();
            assert_eq!(*w, one[0]);
        }
        let g = VectorFn::new(2, |x: &[f64], out: &mut [f64]| {
            out[0] = x[0];
            out[1] = x[0] + x[1];
        });
        let mut both = vec![0.0; 600];
        g.eval_batch(&x, 2, &mut both).unwrap();
        for (i, v) in both.chunks_exact(2).enumerate() {
            assert_eq!(v, [x[2 * i], x[2 * i] + x[2 * i + 1]]);
        }
    }
}
