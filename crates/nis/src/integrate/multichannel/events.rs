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
        let seed = self.settings.seed_of(self.method) ^ EVENTS_SALT;
        let stream = seed ^ self.event_draws.wrapping_mul(0x9e37_79b9_7f4a_7c15);
        self.event_draws += 1;
        let mut rng = Pcg64Mcg::seed_from_u64(self.comm.stream_seed(stream));
        let mass = self.part_masses(f)?;
        let counts = multinomial(&mass, n, &mut rng);
        let drawn = self.draw_events(f, &counts, overweight)?;
        Ok(drawn.shuffled(self.set.dim(), n, &mut rng))
    }

    /// A_p of every part p: the mean |w| of a calibration batch of its frozen sampler. An error
    /// when f was zero at every calibration point.
    fn part_masses(&mut self, f: &dyn crate::integrate::Integrand) -> Result<Vec<f64>> {
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
        Ok(mass)
    }

    /// `counts[p]` unweighted events of every part p, part after part, mapped by its channel.
    fn draw_events(
        &mut self,
        f: &dyn crate::integrate::Integrand,
        counts: &[usize],
        overweight: f64,
    ) -> Result<Drawn> {
        let n: usize = counts.iter().sum();
        let mut drawn = Drawn {
            points: Vec::with_capacity(n * self.set.dim()),
            weights: Vec::with_capacity(n),
            channels: Vec::with_capacity(n),
            proposed: 0.0,
            w_max: 0.0,
            over: 0.0,
        };
        let w = Weighting {
            set: &self.set,
            a: &self.weights,
            net: self.net.as_ref(),
        };
        for (p, &m) in self.parts.iter_mut().zip(counts) {
            if m == 0 {
                continue;
            }
            let h = PartIntegrand::new(f, w, p.channel, p.sign);
            let nis = p.nis()?;
            let u = nis.unweighted(&h, m, overweight)?;
            let mut x = vec![0.0; u.points.len()];
            self.set.sample(p.channel, &u.points, &mut x)?;
            drawn.points.extend_from_slice(&x);
            drawn
                .weights
                .extend(u.weights.iter().map(|w| p.sign.factor() * w));
            drawn.channels.extend(std::iter::repeat_n(p.channel, m));
            drawn.proposed += m as f64 / u.efficiency;
            drawn.w_max = drawn.w_max.max(u.w_max);
            drawn.over = drawn.over.max(u.overweight);
        }
        Ok(drawn)
    }
}

/// The events per part of `n`: multinomial with probabilities A_p/ΣA (`mass` holds the A_p).
fn multinomial(mass: &[f64], n: usize, rng: &mut Pcg64Mcg) -> Vec<usize> {
    let total: f64 = mass.iter().sum();
    let mut counts = vec![0usize; mass.len()];
    for _ in 0..n {
        let mut r = rng.random::<f64>() * total;
        let mut i = 0;
        while i + 1 < mass.len() && r >= mass[i] {
            r -= mass[i];
            i += 1;
        }
        counts[i] += 1;
    }
    counts
}

/// The events of every part, part after part ([`MultiChannel::unweighted`]).
struct Drawn {
    points: Vec<f64>,
    weights: Vec<f64>,
    channels: Vec<usize>,
    /// Points proposed over all parts, Σ m_p / efficiency_p.
    proposed: f64,
    w_max: f64,
    over: f64,
}

impl Drawn {
    /// The `n` events in random order, so that any prefix is a sample too.
    fn shuffled(self, dim: usize, n: usize, rng: &mut Pcg64Mcg) -> ChannelEvents {
        let mut order: Vec<usize> = (0..n).collect();
        order.shuffle(rng);
        let negative = self.weights.iter().filter(|w| **w < 0.0).count();
        ChannelEvents {
            events: Unweighted {
                dim,
                points: order
                    .iter()
                    .flat_map(|&i| self.points[i * dim..(i + 1) * dim].iter().copied())
                    .collect(),
                weights: order.iter().map(|&i| self.weights[i]).collect(),
                w_max: self.w_max,
                efficiency: n as f64 / self.proposed,
                overweight: self.over,
            },
            channels: order.iter().map(|&i| self.channels[i]).collect(),
            negative_fraction: negative as f64 / n.max(1) as f64,
        }
    }
}
