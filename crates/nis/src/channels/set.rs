//! A validated set of channels with their a-priori weights, and the quantities a multi-channel
//! estimator needs from it: every channel's density at a batch of points, the mixture density
//! g = Σ_k a_k g_k and the channel weights α_k = a_k g_k/g (Kleiss & Pittau 1994, Eq. 2–5).

use std::borrow::Cow;

use super::check::{check_sampled, points, same_len};
use super::Channel;
use crate::error::{Error, Result};

/// Channels of one dimension with their priors a_k (finite, > 0; normalised to Σ a_k = 1 in
/// [`ChannelSet::weights`]).
///
/// ```
/// use nis::channels::{ChannelFn, ChannelSet};
/// let flat = ChannelFn::new(1, |u: &[f64], x: &mut [f64]| x[0] = u[0], |_: &[f64]| 1.0);
/// let ramp = ChannelFn::new(1, |u: &[f64], x: &mut [f64]| x[0] = u[0].sqrt(), |x: &[f64]| 2.0 * x[0]);
/// let set = ChannelSet::with_priors(vec![Box::new(flat), Box::new(ramp)], vec![1.0, 3.0]).unwrap();
/// assert_eq!(set.weights(), vec![0.25, 0.75]);
/// let mut g = [0.0];
/// set.mixture_density(&[0.5], &mut g).unwrap();
/// assert_eq!(g, [0.25 * 1.0 + 0.75 * 1.0]);
/// ```
pub struct ChannelSet {
    channels: Vec<Box<dyn Channel>>,
    priors: Vec<f64>,
    dim: usize,
    /// Whether the channel weights use the channels' enhancements when they have them.
    enhance: bool,
}

impl std::fmt::Debug for ChannelSet {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "ChannelSet({} channels, d = {}, priors {:?})",
            self.channels.len(),
            self.dim,
            self.priors
        )
    }
}

impl ChannelSet {
    /// The channels with equal priors.
    pub fn new(channels: Vec<Box<dyn Channel>>) -> Result<ChannelSet> {
        let k = channels.len();
        ChannelSet::with_priors(channels, vec![1.0; k])
    }

    /// The channels with the priors `priors` (one per channel, finite and > 0). Errors: no
    /// channel, a channel of dimension 0 or of another dimension than the first, a prior count
    /// that is not the channel count, a prior that is not finite and positive.
    pub fn with_priors(channels: Vec<Box<dyn Channel>>, priors: Vec<f64>) -> Result<ChannelSet> {
        let Some(first) = channels.first() else {
            return Err(Error::Config(
                "a channel set needs at least one channel".into(),
            ));
        };
        let dim = first.dim();
        if dim == 0 {
            return Err(Error::Config("channel 0 has dimension 0".into()));
        }
        for c in &channels {
            same_len("channel dimension", dim, c.dim())?;
        }
        same_len("channel priors", channels.len(), priors.len())?;
        if let Some(k) = priors.iter().position(|a| !(a.is_finite() && *a > 0.0)) {
            return Err(Error::Config(format!(
                "prior of channel {k} is {}; priors must be finite and > 0",
                priors[k]
            )));
        }
        Ok(ChannelSet {
            channels,
            priors,
            dim,
            enhance: true,
        })
    }

    /// The number of channels.
    pub fn len(&self) -> usize {
        self.channels.len()
    }

    /// Always false: a set holds at least one channel.
    pub fn is_empty(&self) -> bool {
        self.channels.is_empty()
    }

    /// The dimension of every channel.
    pub fn dim(&self) -> usize {
        self.dim
    }

    /// The channels, in order.
    pub fn channels(&self) -> &[Box<dyn Channel>] {
        &self.channels
    }

    /// The priors as given.
    pub fn priors(&self) -> &[f64] {
        &self.priors
    }

    /// The priors normalised to sum 1: the a_k of g = Σ_k a_k g_k.
    pub fn weights(&self) -> Vec<f64> {
        let total: f64 = self.priors.iter().sum();
        self.priors.iter().map(|a| a / total).collect()
    }

    /// Channel `k` maps the uniform points `u` (n × d) to `x`, and the batch is checked
    /// ([`check_sampled`] with the channel's own density, which is returned). The channel sees
    /// u moved 2⁻⁵³ inside the cube where it reaches a face (`inside`).
    pub fn sample(&self, k: usize, u: &[f64], x: &mut [f64]) -> Result<Vec<f64>> {
        let c = self.channel(k)?;
        let n = points("channel sample u", self.dim, u.len())?;
        same_len("channel sample x", u.len(), x.len())?;
        let u = inside(u);
        c.sample(&u, x)?;
        let mut g = vec![0.0; n];
        c.density(x, &mut g)?;
        check_sampled(k, self.dim, &u, x, &g)?;
        Ok(g)
    }

    /// Every channel's density at the points `x` (n × d): `g` is n × K, row-major (point i's
    /// densities at `i·K..(i + 1)·K`). A density that is negative or not finite is an error.
    pub fn densities(&self, x: &[f64], g: &mut [f64]) -> Result<()> {
        let n = points("channel density x", self.dim, x.len())?;
        let k = self.len();
        same_len("channel densities", n * k, g.len())?;
        let mut one = vec![0.0; n];
        for (j, c) in self.channels.iter().enumerate() {
            c.density(x, &mut one)?;
            for (i, &v) in one.iter().enumerate() {
                g[i * k + j] = self.non_negative(j, "density", x, i, v)?;
            }
        }
        Ok(())
    }

    /// The set whose channel weights are made of the densities alone, whatever enhancements
    /// its channels have (the classic a_k g_k/Σ_j a_j g_j).
    pub fn without_enhancements(mut self) -> ChannelSet {
        self.enhance = false;
        self
    }

    /// Whether the channel weights are made of enhancements ([`Channel::enhancement`]): some
    /// channel has one, and [`ChannelSet::without_enhancements`] was not asked for.
    pub fn enhanced(&self) -> bool {
        self.enhance && self.channels.iter().any(|c| c.has_enhancement())
    }

    /// What the channel weights are made of at the points `x` (n × d), given every channel's
    /// density there (`g`, n × K, from [`ChannelSet::densities`]): `None` when they are the
    /// densities themselves (no enhancements, [`ChannelSet::enhanced`]), else the enhancements
    /// w̃_j = w_j where g_j > 0 and 0 elsewhere, n × K (a channel without one: its density). An
    /// enhancement that is negative or not finite is an error.
    pub fn weight_basis(&self, x: &[f64], g: &[f64]) -> Result<Option<Vec<f64>>> {
        if !self.enhanced() {
            return Ok(None);
        }
        let n = points("channel weight basis x", self.dim, x.len())?;
        let k = self.len();
        same_len("channel weight basis g", n * k, g.len())?;
        let mut b = g.to_vec();
        let mut one = vec![0.0; n];
        for (j, c) in self.channels.iter().enumerate() {
            if !c.has_enhancement() {
                continue;
            }
            c.enhancement(x, &mut one)?;
            for (i, &v) in one.iter().enumerate() {
                let v = self.non_negative(j, "enhancement", x, i, v)?;
                b[i * k + j] = if g[i * k + j] > 0.0 { v } else { 0.0 };
            }
        }
        Ok(Some(b))
    }

    /// The mixture density g(x) = Σ_k a_k g_k(x) at the points `x` (n × d), into `g` (n values).
    pub fn mixture_density(&self, x: &[f64], g: &mut [f64]) -> Result<()> {
        let n = points("channel density x", self.dim, x.len())?;
        same_len("mixture density", n, g.len())?;
        let k = self.len();
        let mut all = vec![0.0; n * k];
        self.densities(x, &mut all)?;
        let a = self.weights();
        for (gi, row) in g.iter_mut().zip(all.chunks_exact(k)) {
            *gi = row.iter().zip(&a).map(|(g, a)| g * a).sum();
        }
        Ok(())
    }

    /// The channel weights α_k(x) = a_k g_k(x)/Σ_j a_j g_j(x) at the points `x` (n × d), into
    /// `alpha` (n × K, row-major), g the [`ChannelSet::weight_basis`] where the channels have
    /// enhancements; they sum to 1 at every point some channel reaches (and are all 0 where none
    /// does).
    pub fn channel_weights(&self, x: &[f64], alpha: &mut [f64]) -> Result<()> {
        self.densities(x, alpha)?;
        if let Some(b) = self.weight_basis(x, alpha)? {
            alpha.copy_from_slice(&b);
        }
        let a = self.weights();
        for row in alpha.chunks_exact_mut(self.len()) {
            let total: f64 = row.iter().zip(&a).map(|(g, a)| g * a).sum();
            for (v, a) in row.iter_mut().zip(&a) {
                *v = if total > 0.0 { a * *v / total } else { 0.0 };
            }
        }
        Ok(())
    }

    /// `v`, channel `j`'s `what` at point `i` of `x`, if it is finite and ≥ 0; else an error
    /// naming the channel and the point.
    fn non_negative(&self, j: usize, what: &str, x: &[f64], i: usize, v: f64) -> Result<f64> {
        if v.is_finite() && v >= 0.0 {
            return Ok(v);
        }
        Err(Error::Channel {
            channel: j,
            point: x[i * self.dim..(i + 1) * self.dim].to_vec(),
            reason: format!("its {what} is {v}; it must be finite and ≥ 0"),
        })
    }

    fn channel(&self, k: usize) -> Result<&dyn Channel> {
        self.channels.get(k).map(|c| &**c).ok_or_else(|| {
            Error::Config(format!(
                "channel {k} asked for, but the set has {} channels",
                self.len()
            ))
        })
    }
}

/// How far inside the cube a coordinate of 0 or 1 moves before a channel maps it: 2⁻⁵³, the
/// spacing of doubles just below 1.
pub const FACE: f64 = 1.0 / (1u64 << 53) as f64;

/// `u` with every coordinate in [[`FACE`], 1 − [`FACE`]]: a flow's f32 output reaches 0 and 1
/// exactly, where the Jacobian of many maps vanishes (x = u², the edges of phase space) and
/// their density is infinite or undefined; one ulp inside it is finite. The points moved have
/// no measure, so no integral changes. Borrowed when no coordinate moves.
pub fn inside(u: &[f64]) -> Cow<'_, [f64]> {
    if u.iter().all(|v| (FACE..=1.0 - FACE).contains(v)) {
        Cow::Borrowed(u)
    } else {
        Cow::Owned(u.iter().map(|&v| v.clamp(FACE, 1.0 - FACE)).collect())
    }
}
