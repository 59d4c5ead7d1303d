//! One part of a multi-channel integral as an integrand of its own over the channel's cube:
//! h_k(u) = a_k·f(x)/g(x) at x = φ_k(u), g = Σ_j a_j g_j the mixture of the channels' densities
//! (Kleiss & Pittau 1994: ∫ α_k f dx with α_k = a_k g_k/g, written over u), or its positive or
//! negative part, max(±h_k, 0), when the integrand changes sign. When the channels have
//! enhancements w ([`crate::channels::Channel::enhancement`]), α_k = a_k w̃_k/Σ_j a_j w̃_j and
//! h_k = α_k f/g_k. With a weight network N (`weight_net.rs`) every a_j is a_j e^{N_j(x)}.

use std::sync::atomic::{AtomicBool, Ordering};

use rand::Rng;
use rand_pcg::Pcg64Mcg;

use super::config::Sign;
use super::weight_net::{exp_shifted, WeightNet};
use crate::channels::ChannelSet;
use crate::comm::Comm;
use crate::error::{Error, Result};
use crate::integrate::{evaluate, Integrand};

/// What splits f into the parts: the channels, the a-priori weights a and the weight network.
#[derive(Clone, Copy)]
pub(super) struct Weighting<'a> {
    pub(super) set: &'a ChannelSet,
    pub(super) a: &'a [f64],
    pub(super) net: Option<&'a WeightNet>,
}

/// The integrand h_k of channel `k` (and `sign`) for the integrand `f` under the weighting `w`;
/// it records whether it saw values of either sign.
pub(super) struct PartIntegrand<'a> {
    pub(super) f: &'a dyn Integrand,
    pub(super) w: Weighting<'a>,
    pub(super) k: usize,
    pub(super) sign: Sign,
    pub(super) saw_positive: AtomicBool,
    pub(super) saw_negative: AtomicBool,
}

impl<'a> PartIntegrand<'a> {
    pub(super) fn new(
        f: &'a dyn Integrand,
        w: Weighting<'a>,
        k: usize,
        sign: Sign,
    ) -> PartIntegrand<'a> {
        PartIntegrand {
            f,
            w,
            k,
            sign,
            saw_positive: AtomicBool::new(false),
            saw_negative: AtomicBool::new(false),
        }
    }
}

impl Integrand for PartIntegrand<'_> {
    fn eval_batch(&self, u: &[f64], dim: usize, out: &mut [f64]) -> Result<()> {
        let mut x = vec![0.0; u.len()];
        // Maps and checks: x in the cube, g_k(x) finite and > 0 where channel k put a point.
        self.w.set.sample(self.k, u, &mut x)?;
        let fx = evaluate(self.f, &x, dim)?;
        for v in &fx {
            if *v > 0.0 {
                self.saw_positive.store(true, Ordering::Relaxed);
            } else if *v < 0.0 {
                self.saw_negative.store(true, Ordering::Relaxed);
            }
        }
        let parts = [(self.k, self.sign)];
        let counts = [out.len()];
        values(self.w, &parts, &counts, &x, &fx, dim, out)
    }

    fn dim(&self) -> Option<usize> {
        Some(self.w.set.dim())
    }
}

/// Evaluates `h` (of dimension `dim`) at this rank's share of `n` uniform points from `rng`:
/// the sign pilot, and the cost probe of a run to a target.
pub(super) fn at_uniform_points(
    h: &PartIntegrand,
    comm: &Comm,
    n: u64,
    dim: usize,
    rng: &mut Pcg64Mcg,
) -> Result<()> {
    let mine = comm.share(n) as usize;
    let u: Vec<f64> = (0..mine * dim).map(|_| rng.random::<f64>()).collect();
    comm.check(evaluate(h, &u, dim)).map(|_| ())
}

/// The values h of many parts at once, with one call of f and of the channels' densities for
/// all points (a shared flow's training batch): the rows of `u` (`dim` each) come in blocks, the
/// `j`th of `counts[j]` rows for the part `parts[j]` (channel, sign), under the weights `a`
/// (before any weight network: the flow trains before one is fitted).
pub(super) fn eval_blocks(
    f: &dyn Integrand,
    set: &ChannelSet,
    a: &[f64],
    parts: &[(usize, Sign)],
    counts: &[usize],
    u: &[f64],
    dim: usize,
) -> Result<Vec<f64>> {
    let mut x = vec![0.0; u.len()];
    let mut start = 0;
    for (&(k, _), &m) in parts.iter().zip(counts) {
        let rows = start * dim..(start + m) * dim;
        if m > 0 {
            set.sample(k, &u[rows.clone()], &mut x[rows])?;
        }
        start += m;
    }
    let fx = evaluate(f, &x, dim)?;
    let mut out = vec![0.0; fx.len()];
    let w = Weighting { set, a, net: None };
    values(w, parts, counts, &x, &fx, dim, &mut out)?;
    Ok(out)
}

/// h_k under `after` over h_k under `before` (α_k's ratio, f cancels) at the points `u` of
/// channel `k` (`dim` each, in its unit cube); 0 where `before` gives no weight.
pub(super) fn weight_ratio(
    before: Weighting,
    after: Weighting,
    k: usize,
    u: &[f32],
    dim: usize,
) -> Result<Vec<f64>> {
    let u: Vec<f64> = u.iter().map(|&v| v as f64).collect();
    let n = u.len() / dim;
    let mut x = vec![0.0; u.len()];
    before.set.sample(k, &u, &mut x)?;
    let ones = vec![1.0; n];
    let (mut old, mut new) = (vec![0.0; n], vec![0.0; n]);
    values(before, &[(k, Sign::Both)], &[n], &x, &ones, dim, &mut old)?;
    values(after, &[(k, Sign::Both)], &[n], &x, &ones, dim, &mut new)?;
    Ok(old
        .iter()
        .zip(&new)
        .map(|(o, n)| if *o > 0.0 { n / o } else { 0.0 })
        .collect())
}

/// h = a_k·f/Σ_j a_j g_j (or its part of one sign) at the mapped points `x` with values `fx`,
/// in the blocks of [`eval_blocks`], into `out`; with a network N, a_j e^{N_j(x)} for a_j.
#[allow(clippy::too_many_arguments)]
fn values(
    Weighting { set, a, net }: Weighting,
    parts: &[(usize, Sign)],
    counts: &[usize],
    x: &[f64],
    fx: &[f64],
    dim: usize,
    out: &mut [f64],
) -> Result<()> {
    let channels = set.len();
    let mut g = vec![0.0; fx.len() * channels];
    set.densities(x, &mut g)?;
    // With enhancements α_k = a_k w̃_k/Σ a_j w̃_j, so h = α_k f/g_k; without, w̃ = g and g_k
    // cancels.
    let basis = set.weight_basis(x, &g)?;
    let corrections = net.map(|n| n.corrections(x));
    let mut e = vec![1.0; channels];
    let mut i = 0;
    for (&(k, sign), &m) in parts.iter().zip(counts) {
        for _ in 0..m {
            let cols = i * channels..(i + 1) * channels;
            let row = &basis.as_deref().unwrap_or(&g)[cols.clone()];
            if let Some(c) = &corrections {
                exp_shifted(&c[cols.clone()], &mut e);
            }
            let total: f64 = row.iter().zip(a).zip(&e).map(|((b, a), e)| b * a * e).sum();
            let ratio = if basis.is_some() {
                row[k] / g[cols][k]
            } else {
                1.0
            };
            let h = if fx[i] == 0.0 {
                0.0
            } else if total > 0.0 && total.is_finite() {
                a[k] * e[k] * ratio * fx[i] / total
            } else {
                // g_k(x) > 0 was checked, so the mixture is > 0 unless a weight underflowed
                // or every enhancement vanishes at a point where f does not.
                return Err(Error::Channel {
                    channel: k,
                    point: x[i * dim..(i + 1) * dim].to_vec(),
                    reason: format!(
                        "the channel weights' normalisation Σ a_j w_j (w the channels' \
                         densities, or their enhancements) is {total} there, where f = {}",
                        fx[i]
                    ),
                });
            };
            out[i] = match sign {
                Sign::Both => h,
                Sign::Plus => h.max(0.0),
                Sign::Minus => (-h).max(0.0),
            };
            i += 1;
        }
    }
    Ok(())
}
