//! Channels written as two closures, one point at a time: the map and its density.

use rayon::prelude::*;

use super::check::{points, same_len};
use super::Channel;
use crate::error::Result;
use crate::kernels::points_per_task;

/// A channel from closures: `sample(u, x)` writes φ(u) for one point, `density(x)` returns g(x)
/// at one point. Batches are evaluated in parallel, as closure integrands are.
///
/// ```
/// use nis::channels::{Channel, ChannelFn};
/// // A linear ramp in x₀: x₀ = √u₀ has g = 2x₀; x₁ flat.
/// let ramp = ChannelFn::new(
///     2,
///     |u: &[f64], x: &mut [f64]| { x[0] = u[0].sqrt(); x[1] = u[1]; },
///     |x: &[f64]| 2.0 * x[0],
/// );
/// let mut x = [0.0; 2];
/// ramp.sample(&[0.25, 0.5], &mut x).unwrap();
/// assert_eq!(x, [0.5, 0.5]);
/// ```
pub struct ChannelFn<S, D, E = fn(&[f64]) -> f64> {
    dim: usize,
    sample: S,
    density: D,
    enhancement: Option<E>,
}

impl<S, D> ChannelFn<S, D>
where
    S: Fn(&[f64], &mut [f64]) + Send + Sync,
    D: Fn(&[f64]) -> f64 + Send + Sync,
{
    /// A channel of dimension `dim` with the point map `sample(u, x)` and its density
    /// `density(x)`.
    pub fn new(dim: usize, sample: S, density: D) -> ChannelFn<S, D> {
        ChannelFn {
            dim,
            sample,
            density,
            enhancement: None,
        }
    }
}

impl<S, D, E> ChannelFn<S, D, E> {
    /// The channel with the enhancement `w(x)` ([`Channel::enhancement`]).
    pub fn with_enhancement<W>(self, w: W) -> ChannelFn<S, D, W>
    where
        W: Fn(&[f64]) -> f64 + Send + Sync,
    {
        ChannelFn {
            dim: self.dim,
            sample: self.sample,
            density: self.density,
            enhancement: Some(w),
        }
    }
}

/// `out[i] = value(x_i)` for the points of `x` (`d` each), in parallel.
fn per_point(
    d: usize,
    what: &'static str,
    x: &[f64],
    out: &mut [f64],
    value: impl Fn(&[f64]) -> f64 + Send + Sync,
) -> Result<()> {
    let n = points(what, d, x.len())?;
    same_len(what, n, out.len())?;
    let chunk = points_per_task(n);
    out.par_chunks_mut(chunk)
        .zip(x.par_chunks(chunk * d))
        .for_each(|(out, x)| {
            for (o, x) in out.iter_mut().zip(x.chunks_exact(d)) {
                *o = value(x);
            }
        });
    Ok(())
}

impl<S, D, E> Channel for ChannelFn<S, D, E>
where
    S: Fn(&[f64], &mut [f64]) + Send + Sync,
    D: Fn(&[f64]) -> f64 + Send + Sync,
    E: Fn(&[f64]) -> f64 + Send + Sync,
{
    fn dim(&self) -> usize {
        self.dim
    }

    fn sample(&self, u: &[f64], x: &mut [f64]) -> Result<()> {
        let d = self.dim;
        let n = points("channel sample u", d, u.len())?;
        same_len("channel sample x", u.len(), x.len())?;
        let chunk = points_per_task(n) * d;
        x.par_chunks_mut(chunk)
            .zip(u.par_chunks(chunk))
            .for_each(|(x, u)| {
                for (x, u) in x.chunks_exact_mut(d).zip(u.chunks_exact(d)) {
                    (self.sample)(u, x);
                }
            });
        Ok(())
    }

    fn density(&self, x: &[f64], g: &mut [f64]) -> Result<()> {
        per_point(self.dim, "channel density", x, g, &self.density)
    }

    fn has_enhancement(&self) -> bool {
        self.enhancement.is_some()
    }

    fn enhancement(&self, x: &[f64], w: &mut [f64]) -> Result<()> {
        match &self.enhancement {
            Some(e) => per_point(self.dim, "channel enhancement", x, w, e),
            None => self.density(x, w),
        }
    }
}
