//! The defensive mixture q_mix = λ·uniform + (1 − λ)·q of a density with the uniform one
//! (Hesterberg 1995, "Weighted average importance sampling and defensive mixture
//! distributions"): weights f/q_mix are bounded by f/λ wherever q has not (yet) put mass, which
//! keeps error bars honest when a flow misses a sliver of the integrand.
//!
//! A batch of n points holds a fixed count of each component, n_u = round(λn) uniform points and
//! n − n_u points of q (stratified sampling of the mixture; with the mixture density for every
//! point this is the balance heuristic of multiple importance sampling, Veach & Guibas 1995), so
//! the estimate stays unbiased with fewer random quantities than drawing the component per
//! point.

use rand::{Rng, RngCore};

use super::{Density, Evaluated, Samples, Tape};
use crate::error::{Error, Result};

/// A density mixed with the uniform density in fixed proportion.
///
/// ```
/// use nis::flow::{mixture::DefensiveMixture, Density, Flow, FlowConfig};
/// use rand::SeedableRng;
/// let mix = DefensiveMixture::new(Flow::new(FlowConfig::new(2)).unwrap(), 0.1).unwrap();
/// let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(0);
/// let s = mix.sample(100, None, &mut rng).unwrap();
/// // The untrained flow is uniform, so the mixture is too: ln q_mix = 0.
/// assert!(s.log_q.iter().all(|l| l.abs() < 1e-6));
/// ```
#[derive(Clone, Debug)]
pub struct DefensiveMixture<D> {
    /// The learned component.
    pub density: D,
    /// Share λ of uniform points, in [0, 1).
    lambda: f64,
}

/// A batch of the mixture: all points (q's first, then the uniform ones), their mixture
/// log-density, and q's share as q drew it (with its tape when drawn for training).
#[derive(Clone, Debug)]
pub struct MixtureBatch {
    /// Row-major points, `n × D`.
    pub x: Vec<f32>,
    /// ln q_mix of each point.
    pub log_q_mix: Vec<f64>,
    /// The first `density_part.len()` points, with ln q (not q_mix) and q's tape.
    pub density_part: Samples,
    /// ln q of the uniform points (the rest of `x`).
    pub uniform_log_q: Vec<f64>,
    /// q's tape of the uniform points, when asked for ([`Record::Both`]).
    pub uniform_tape: Option<Tape>,
}

/// Which of q's passes a [`draw`] keeps tapes of.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Record {
    /// None: sampling only.
    Nothing,
    /// q's own share (the on-policy step of a trainer of q, which sees only q's points).
    DensityShare,
    /// Both shares (the mixture's own gradient).
    Both,
}

/// What the mixture's training pass recorded: q's tapes of consecutive row ranges and each
/// point's ∂ln q_mix/∂ln q = (1 − λ)·q/q_mix.
struct MixtureTape {
    parts: Vec<Tape>,
    dlog: Vec<f32>,
}

/// ∂ln q_mix/∂ln q = (1 − λ)·q/q_mix for each pair (ln q, ln q_mix).
fn dlog<'a>(lambda: f64, log_q: impl Iterator<Item = &'a f64>, log_q_mix: &[f64]) -> Vec<f32> {
    log_q
        .zip(log_q_mix)
        .map(|(lq, lm)| ((1.0 - lambda) * (lq - lm).exp()) as f32)
        .collect()
}

/// The mixture's own tapes carry no version: the inner density's tapes inside them do, and its
/// backward pass rejects them once its parameters changed.
const MIXTURE_TAPE: u64 = 0;

/// How many of `n` points the uniform component gets: round(λn), leaving q at least one.
pub fn uniform_count(lambda: f64, n: usize) -> usize {
    ((lambda * n as f64).round() as usize).min(n.saturating_sub(1))
}

/// ln(λ + (1 − λ)·e^{ln q}).
pub fn mix_log_density(lambda: f64, log_q: f64) -> f64 {
    (lambda + (1.0 - lambda) * log_q.exp()).ln()
}

/// Draws `n` points of λ·uniform + (1 − λ)·`density`: q's share first (from `rng`), then the
/// uniform points; `record` says which of q's passes keep their tapes.
pub fn draw(
    density: &(impl Density + ?Sized),
    lambda: f64,
    n: usize,
    rng: &mut dyn RngCore,
    record: Record,
) -> Result<MixtureBatch> {
    let dim = density.dim();
    let n_u = uniform_count(lambda, n);
    let n_q = n - n_u;
    let density_part = if record == Record::Nothing {
        density.sample(n_q, None, rng)?
    } else {
        density.sample_for_training(n_q, None, rng)?
    };
    let mut x = density_part.x.clone();
    x.extend((0..n_u * dim).map(|_| rng.random::<f32>()));
    let (uniform_log_q, uniform_tape) = if record == Record::Both {
        let e = density.log_density_for_training(&x[n_q * dim..], None)?;
        (e.log_q, Some(e.tape))
    } else {
        (density.log_density(&x[n_q * dim..], None)?, None)
    };
    let log_q_mix = density_part
        .log_q
        .iter()
        .chain(&uniform_log_q)
        .map(|&l| mix_log_density(lambda, l))
        .collect();
    Ok(MixtureBatch {
        x,
        log_q_mix,
        density_part,
        uniform_log_q,
        uniform_tape,
    })
}

impl<D: Density> DefensiveMixture<D> {
    /// `density` mixed with the uniform density at share `lambda` ∈ [0, 1).
    pub fn new(density: D, lambda: f64) -> Result<DefensiveMixture<D>> {
        if !(0.0..1.0).contains(&lambda) {
            return Err(Error::Config(format!(
                "the uniform share of a defensive mixture must be in [0, 1), got {lambda}"
            )));
        }
        if density.context_dim() > 0 {
            return Err(Error::Config(
                "a defensive mixture needs an unconditional density".into(),
            ));
        }
        Ok(DefensiveMixture { density, lambda })
    }

    /// The uniform share λ.
    pub fn lambda(&self) -> f64 {
        self.lambda
    }

    /// Draws `n` points of the mixture: q's share first, then the uniform points (see [`draw`]).
    pub fn draw(&self, n: usize, rng: &mut dyn RngCore, record: Record) -> Result<MixtureBatch> {
        draw(&self.density, self.lambda, n, rng, record)
    }

    /// ln q_mix at a point where q has log-density `log_q`.
    pub fn mix_log_density(&self, log_q: f64) -> f64 {
        mix_log_density(self.lambda, log_q)
    }

    fn samples(&self, n: usize, rng: &mut dyn RngCore, record: bool) -> Result<Samples> {
        let how = if record {
            Record::Both
        } else {
            Record::Nothing
        };
        let b = self.draw(n, rng, how)?;
        let tape = match (b.density_part.tape, b.uniform_tape) {
            (Some(q_share), Some(uniform_share)) => {
                let log_q = b.density_part.log_q.iter().chain(&b.uniform_log_q);
                let records = MixtureTape {
                    parts: vec![q_share, uniform_share],
                    dlog: dlog(self.lambda, log_q, &b.log_q_mix),
                };
                Some(Tape::new(MIXTURE_TAPE, b.log_q_mix.len(), records))
            }
            _ => None,
        };
        Ok(Samples {
            x: b.x,
            log_q: b.log_q_mix,
            tape,
        })
    }
}

impl<D: Density> Density for DefensiveMixture<D> {
    fn dim(&self) -> usize {
        self.density.dim()
    }

    fn sample(&self, n: usize, ctx: Option<&[f32]>, rng: &mut dyn RngCore) -> Result<Samples> {
        super::check_context(n, 0, ctx)?;
        self.samples(n, rng, false)
    }

    fn sample_for_training(
        &self,
        n: usize,
        ctx: Option<&[f32]>,
        rng: &mut dyn RngCore,
    ) -> Result<Samples> {
        super::check_context(n, 0, ctx)?;
        self.samples(n, rng, true)
    }

    fn log_density(&self, x: &[f32], ctx: Option<&[f32]>) -> Result<Vec<f64>> {
        let log_q = self.density.log_density(x, ctx)?;
        Ok(log_q
            .into_iter()
            .map(|l| mix_log_density(self.lambda, l))
            .collect())
    }

    fn log_density_for_training(&self, x: &[f32], ctx: Option<&[f32]>) -> Result<Evaluated> {
        let e = self.density.log_density_for_training(x, ctx)?;
        let log_q: Vec<f64> = e
            .log_q
            .iter()
            .map(|&l| mix_log_density(self.lambda, l))
            .collect();
        let records = MixtureTape {
            dlog: dlog(self.lambda, e.log_q.iter(), &log_q),
            parts: vec![e.tape],
        };
        Ok(Evaluated {
            tape: Tape::new(MIXTURE_TAPE, log_q.len(), records),
            log_q,
        })
    }

    fn params(&self) -> &[f32] {
        self.density.params()
    }

    fn params_mut(&mut self) -> &mut [f32] {
        self.density.params_mut()
    }

    /// −Σ w_i ∇ln q_mix(x_i) = −Σ w_i (1 − λ)(q/q_mix)(x_i) ∇ln q(x_i): q's backward with the
    /// weights scaled by ∂ln q_mix/∂ln q.
    fn backward(&self, tape: &Tape, weights: &[f32]) -> Result<Vec<f32>> {
        let t: &MixtureTape = tape.records(MIXTURE_TAPE, weights.len())?;
        let w: Vec<f32> = weights.iter().zip(&t.dlog).map(|(w, d)| w * d).collect();
        let mut grads = vec![0.0f32; self.density.param_count()];
        let mut start = 0;
        for part in &t.parts {
            let rows = start..start + part.rows();
            if !rows.is_empty() {
                for (g, p) in grads
                    .iter_mut()
                    .zip(self.density.backward(part, &w[rows.clone()])?)
                {
                    *g += p;
                }
            }
            start = rows.end;
        }
        Ok(grads)
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use rand::{Rng, SeedableRng};
    use rand_pcg::Pcg64Mcg;

    use super::*;
    use crate::flow::{Flow, FlowConfig};
    use crate::transform::TransformKind;

    /// A 2-d flow whose parameters got uniform noise: q is far from uniform (for this module's
    /// tests and the stratified final phase's).
    pub(crate) fn noisy_flow() -> Flow {
        let mut flow = Flow::new(FlowConfig {
            transform: TransformKind::Quadratic { bins: 6 },
            hidden_layers: 1,
            hidden_width: 8,
            blob_bins: 4,
            ..FlowConfig::new(2)
        })
        .unwrap();
        let mut rng = Pcg64Mcg::seed_from_u64(9);
        for p in flow.params_mut() {
            *p += 0.8 * (2.0 * rng.random::<f32>() - 1.0);
        }
        flow
    }

    /// A 2-d mixture of [`noisy_flow`] and the uniform density.
    fn mixture(lambda: f64) -> DefensiveMixture<Flow> {
        DefensiveMixture::new(noisy_flow(), lambda).unwrap()
    }

    #[test]
    fn mixture_density_is_the_convex_combination_and_integrates_to_one() {
        let mix = mixture(0.25);
        // Midpoint rule on a 400² grid: both components integrate to one, so the mixture does.
        let m = 400;
        let x: Vec<f32> = (0..m * m)
            .flat_map(|i| {
                [
                    ((i / m) as f32 + 0.5) / m as f32,
                    ((i % m) as f32 + 0.5) / m as f32,
                ]
            })
            .collect();
        let lq = mix.density.log_density(&x, None).unwrap();
        let lm = mix.log_density(&x, None).unwrap();
        for (q, l) in lq.iter().zip(&lm) {
            assert!((l.exp() - (0.25 + 0.75 * q.exp())).abs() < 1e-12 * l.exp().max(1.0));
        }
        let integral = lm.iter().map(|l| l.exp()).sum::<f64>() / (m * m) as f64;
        assert!((integral - 1.0).abs() < 2e-3, "∫ q_mix = {integral}");
        assert!(lq.iter().any(|l| l.abs() > 0.3), "the flow is not uniform");
    }

    #[test]
    fn batches_hold_fixed_counts_and_the_mixture_density_of_every_point() {
        let mix = mixture(0.1);
        let mut rng = Pcg64Mcg::seed_from_u64(1);
        let s = mix.sample(1000, None, &mut rng).unwrap();
        assert_eq!(uniform_count(0.1, 1000), 100);
        assert_eq!(uniform_count(0.5, 1), 0, "q keeps at least one point");
        // Evaluated again at the stored points, which are the sampled ones rounded to f32: the
        // log-density moves by |∂ln q/∂x|·ulp(x) ~ 1e-5 where q is steep.
        let again = mix.log_density(&s.x, None).unwrap();
        for (a, b) in s.log_q.iter().zip(&again) {
            assert!((a - b).abs() < 1e-4, "{a} vs {b}");
        }
        assert!(DefensiveMixture::new(mix.density.clone(), 1.0).is_err());
        assert!(DefensiveMixture::new(mix.density.clone(), -0.1).is_err());
    }

    fn loss(mix: &DefensiveMixture<Flow>, x: &[f32], w: &[f32]) -> f64 {
        let lq = mix.log_density(x, None).unwrap();
        -lq.iter().zip(w).map(|(l, &w)| l * w as f64).sum::<f64>()
    }

    #[test]
    fn backward_is_the_gradient_of_the_mixture_log_likelihood() {
        let mix = mixture(0.3);
        let mut rng = Pcg64Mcg::seed_from_u64(2);
        let s = mix.sample_for_training(600, None, &mut rng).unwrap();
        let w: Vec<f32> = (0..600).map(|_| rng.random::<f32>() / 600.0).collect();
        let g = mix.backward(s.tape.as_ref().unwrap(), &w).unwrap();
        // The same gradient from a fresh training pass over the same points.
        let e = mix.log_density_for_training(&s.x, None).unwrap();
        let g2 = mix.backward(&e.tape, &w).unwrap();
        for (a, b) in g.iter().zip(&g2) {
            assert!((a - b).abs() <= 1e-4 * a.abs().max(1e-3), "{a} vs {b}");
        }
        // Along the gradient (plus noise), against central differences of the loss in f64.
        let gmax = g.iter().map(|g| g.abs()).fold(0.0, f32::max);
        let mut v: Vec<f32> = g
            .iter()
            .map(|g| g + 0.1 * (rng.random::<f32>() - 0.5) * gmax)
            .collect();
        let norm = v.iter().map(|a| (a * a) as f64).sum::<f64>().sqrt() as f32;
        v.iter_mut().for_each(|a| *a /= norm);
        let analytic: f64 = g.iter().zip(&v).map(|(g, v)| (g * v) as f64).sum();
        let h = 1e-3;
        let (mut plus, mut minus) = (mix.clone(), mix.clone());
        for ((p, m), v) in plus.params_mut().iter_mut().zip(minus.params_mut()).zip(&v) {
            *p += h * v;
            *m -= h * v;
        }
        let fd = (loss(&plus, &s.x, &w) - loss(&minus, &s.x, &w)) / (2.0 * h as f64);
        assert!(
            (fd - analytic).abs() < 2e-2 * analytic.abs(),
            "analytic {analytic} vs finite difference {fd}"
        );
        // A tape from before a parameter change is refused.
        let mut changed = mix.clone();
        changed.params_mut()[0] += 1.0;
        assert!(changed.backward(&e.tape, &w).is_err());
    }
}
