//! Unweighted events through the channels: points x distributed as |f|(x)/∫|f|, each carrying
//! the channel (and sign part) that produced it. |f| = Σ_p |h_p| pushed forward through the
//! parts' maps, so an event comes from part p with probability A_p/Σ A_q, A_p = ∫|h_p| (measured
//! on a calibration batch of the part's frozen sampler), and is then an unweighted point of that
//! part's sampler (NIS's [`crate::integrate::unweight`]) mapped by its channel, x = φ_k(u).

use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

use super::part::{PartIntegrand, Weighting};
use super::MultiChannel;
use crate::error::{Error, Result};
use crate::integrate::unweight::Unweighted;

/// Points of a calibration batch per part, for A_p.
const CALIBRATION: usize = 1 << 14;
/// Salt of the events' stream ("evnt").
const EVENTS_SALT: u64 = 0x6576_6e74;

/// Unweighted events and the channel of each.
#[derive(Clone, Debug)]
pub struct ChannelEvents {
    /// The events in the integration domain, with their signs (±1, or beyond for the rare
    /// overweight events, as in [`Unweighted`]); `w_max` and `overweight` are the largest over
    /// the parts, `efficiency` the events over all points proposed.
    pub events: Unweighted,
    /// The channel of every event.
    pub channels: Vec<usize>,
    /// The share of events with a negative weight.
    pub negative_fraction: f64,
}

impl MultiChannel {
    /// `n` unweighted events of f through the channels of a multi-channel NIS integrator that
    /// has integrated (its flows are frozen; module docs), in random order. `overweight` is the
    /// tolerated share of weight mass above each part's robust maximum (e.g. 10⁻³). Each call
    /// draws from a stream of its own (of the seed and the calls before it), so successive calls
    /// give independent events.
    pub fn unweighted(
        &mut self,
        f: &dyn crate::integrate::Integrand,
        n: usize,
        overweight: f64,
    ) -> Result<ChannelEvents> {
        if self.parts.is_empty() {
            return Err(Error::Config(
                "unweighted events need an integrator that has integrated (its samplers are \
                 trained by the first call)"
                    .into(),
            ));
        }
        if self.method != crate::integrate::Method::Nis {
            return Err(Error::Config(
                "unweighted events through channels need method nis (a flow per channel)".into(),
            ));
        }
        let dim = self.set.dim();
        let seed = self.settings.seed_of(self.method) ^ EVENTS_SALT;
        let stream = seed ^ self.event_draws.wrapping_mul(0x9e37_79b9_7f4a_7c15);
        self.event_draws += 1;
        let mut rng = Pcg64Mcg::seed_from_u64(self.comm.stream_seed(stream));
        // A_p = mean |w| of a calibration batch of each part's frozen sampler.
        let mut mass = Vec::with_capacity(self.parts.len());
        let w = Weighting {
            set: &self.set,
            a: &self.weights,
            net: self.net.as_ref(),
        };
        for p in self.parts.iter_mut() {
            let h = PartIntegrand::new(f, w, p.channel, p.sign);
            let nis = p.nis()?;
            let (_, w) = nis.weighted(&h, CALIBRATION)?;
            mass.push(w.iter().map(|v| v.abs()).sum::<f64>() / w.len() as f64);
        }
        let total: f64 = mass.iter().sum();
        if !(total > 0.0 && total.is_finite()) {
            return Err(Error::Config(
                "the integrand was zero at every calibration point of every channel: nothing \
                 to sample"
                    .into(),
            ));
        }
        // The events per part: multinomial with probabilities A_p/ΣA.
        let mut counts = vec![0usize; self.parts.len()];
        for _ in 0..n {
            let mut r = rng.random::<f64>() * total;
            let mut i = 0;
            while i + 1 < mass.len() && r >= mass[i] {
                r -= mass[i];
                i += 1;
            }
            counts[i] += 1;
        }
        let mut points = Vec::with_capacity(n * dim);
        let mut weights = Vec::with_capacity(n);
        let mut channels = Vec::with_capacity(n);
        let (mut proposed, mut w_max, mut over) = (0.0, 0.0f64, 0.0f64);
        let w = Weighting {
            set: &self.set,
            a: &self.weights,
            net: self.net.as_ref(),
        };
        for (p, &m) in self.parts.iter_mut().zip(&counts) {
            if m == 0 {
                continue;
            }
            let h = PartIntegrand::new(f, w, p.channel, p.sign);
            let nis = p.nis()?;
            let u = nis.unweighted(&h, m, overweight)?;
            let mut x = vec![0.0; u.points.len()];
            self.set.sample(p.channel, &u.points, &mut x)?;
            points.extend_from_slice(&x);
            weights.extend(u.weights.iter().map(|w| p.sign.factor() * w));
            channels.extend(std::iter::repeat_n(p.channel, m));
            proposed += m as f64 / u.efficiency;
            w_max = w_max.max(u.w_max);
            over = over.max(u.overweight);
        }
        // Random order, so that any prefix is a sample too.
        let mut order: Vec<usize> = (0..n).collect();
        order.shuffle(&mut rng);
        let negative = weights.iter().filter(|w| **w < 0.0).count();
        Ok(ChannelEvents {
            events: Unweighted {
                dim,
                points: order
                    .iter()
                    .flat_map(|&i| points[i * dim..(i + 1) * dim].iter().copied())
                    .collect(),
                weights: order.iter().map(|&i| weights[i]).collect(),
                w_max,
                efficiency: n as f64 / proposed,
                overweight: over,
            },
            channels: order.iter().map(|&i| channels[i]).collect(),
            negative_fraction: negative as f64 / n.max(1) as f64,
        })
    }
}
