//! The adaptation between the pilot and the estimate: every part adapts on an equal share, which
//! measures its σ and integral; then the a-priori weights move to Kleiss–Pittau's a_k ∝ a_k·√W_k
//! (kept above the floor) and, for NIS, the weight network is fitted (module docs of
//! [`super`]).

use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;

use super::part::{self, weight_ratio, PartIntegrand, Weighting};
use super::weight_net::{fit, PartPoints};
use super::{part_seed, MultiChannel};
use crate::error::Result;
use crate::integrate::{evaluate, Integrand, IntegrationResult, Integrator, Method};

impl MultiChannel {
    /// Adapts every part on `adapt` evaluations, then the weights (Kleiss–Pittau), then fits the
    /// weight network when asked: each part's result (its σ and integral), the evaluations
    /// spent, and each part's σ per evaluation under the weights the estimate will use.
    pub(super) fn adapt_parts(
        &mut self,
        f: &dyn Integrand,
        adapt: u64,
    ) -> Result<(Vec<IntegrationResult>, u64, Vec<f64>)> {
        let mut measured = Vec::with_capacity(self.parts.len());
        let mut spent = 0;
        // The parts adapt to Kleiss–Pittau's α; a network is refitted after them.
        self.net = None;
        let before = self.weights.clone();
        let index = self.parts_index();
        let w = Weighting {
            set: &self.set,
            a: &self.weights,
            net: None,
        };
        if let Some(shared) = &mut self.shared {
            // The flow trains on every part's share at once; then each part gets the flow at
            // its context as an integrator of its own, and is measured with it.
            let train = adapt * 4 / 5;
            let (set, a, dim) = (&self.set, &self.weights, self.set.dim());
            let h =
                |counts: &[usize], u: &[f64]| part::eval_blocks(f, set, a, &index, counts, u, dim);
            spent += shared.train(&h, train * index.len() as u64)?;
            let base = self.settings.seed_of(self.method);
            for (i, p) in self.parts.iter_mut().enumerate() {
                let mut nis = shared.part(i, part_seed(base, i as u64))?;
                let h = PartIntegrand::new(f, w, p.channel, p.sign);
                let r = nis.estimate(&h, adapt - train)?;
                spent += r.n_eval;
                measured.push(r);
                p.integrator = Some(Box::new(nis));
            }
        } else {
            for p in self.parts.iter_mut() {
                let h = PartIntegrand::new(f, w, p.channel, p.sign);
                let r = adapt_part(p.sampler()?, &h, adapt)?;
                spent += r.n_eval;
                measured.push(r);
            }
        }
        if self.config.adapt_weights && self.set.len() > 1 {
            self.weights = self.adapted_weights(&measured);
        }
        let mut sd = sd_per_eval(&measured);
        if self.config.weight_network && self.method == Method::Nis && self.set.len() > 1 {
            let (fitted, sigmas) = self.fit_weight_net(f, adapt)?;
            spent += fitted;
            sd = sigmas;
        }
        self.rescale_memories(&before)?;
        Ok((measured, spent, sd))
    }

    /// The parts trained on h_k under the weights `before` (no network); their estimates use
    /// the adapted weights and network, so each NIS part's training points are rescaled to the
    /// h_k the estimate integrates, for its missing-mass check (`nis/memory.rs`).
    fn rescale_memories(&mut self, before: &[f64]) -> Result<()> {
        if before == self.weights.as_slice() && self.net.is_none() {
            return Ok(());
        }
        let dim = self.set.dim();
        let old = Weighting {
            set: &self.set,
            a: before,
            net: None,
        };
        let new = Weighting {
            set: &self.set,
            a: &self.weights,
            net: self.net.as_ref(),
        };
        for p in self.parts.iter_mut() {
            let k = p.channel;
            if let Some(nis) = p.integrator.as_mut().and_then(|i| i.as_nis()) {
                let memory = nis.training_memory_mut();
                let factors = weight_ratio(old, new, k, memory.points(), dim)?;
                memory.rescale(&factors);
            }
        }
        Ok(())
    }

    /// a_k ∝ a_k·√W_k, W_k = Σ over channel k's parts of their weights' second moment
    /// (σ² per evaluation + F²) over a_k², normalised, each at least `weight_floor`/K.
    fn adapted_weights(&self, measured: &[IntegrationResult]) -> Vec<f64> {
        let k = self.set.len();
        let mut w = vec![0.0; k];
        for (p, r) in self.parts.iter().zip(measured) {
            let n: u64 = r.iterations.iter().map(|i| i.evals).sum();
            let second = r.std_err * r.std_err * n as f64 + r.value * r.value;
            w[p.channel] += second;
        }
        let mut a: Vec<f64> = self
            .weights
            .iter()
            .zip(&w)
            .map(|(a, w)| a * (w / (a * a)).sqrt())
            .collect();
        normalise_with_floor(&mut a, self.config.weight_floor / k as f64);
        if a.iter().all(|v| v.is_finite()) {
            a
        } else {
            self.weights.clone()
        }
    }

    /// Fits the weight network on fresh points of every part's frozen sampler, drawn alike on
    /// every rank (so every rank fits the same network); returns the points' evaluations and
    /// every part's σ per evaluation on the held-out half under the weights kept.
    pub(super) fn fit_weight_net(
        &mut self,
        f: &dyn Integrand,
        adapt: u64,
    ) -> Result<(u64, Vec<f64>)> {
        let (dim, k) = (self.set.dim(), self.set.len());
        let parts = self.parts.len();
        let n = (adapt as usize / 4)
            .clamp(NET_POINTS.0, NET_POINTS.1)
            .min((NET_POINTS.2 / parts).max(NET_POINTS.0 / 2));
        let base = self.settings.seed_of(self.method) ^ NET_SALT;
        let one = |_: &[f64]| 1.0;
        let mut points = Vec::with_capacity(parts);
        for (i, p) in self.parts.iter_mut().enumerate() {
            let mut rng = Pcg64Mcg::seed_from_u64(part_seed(base, i as u64));
            let (u, inv_q) = p.nis()?.target_weights(&one, n, &mut rng)?;
            let mut x = vec![0.0; u.len()];
            let gk = self.set.sample(p.channel, &u, &mut x)?;
            let fx = self.comm.check(evaluate(f, &x, dim))?;
            let mut g = vec![0.0; n * k];
            self.set.densities(&x, &mut g)?;
            // With enhancements the network refines α_k ∝ a_k w̃_k.
            if let Some(b) = self.set.weight_basis(&x, &g)? {
                g = b;
            }
            let inv_q: Vec<f64> = inv_q.iter().zip(&gk).map(|(q, g)| q / g).collect();
            points.push(PartPoints::new(
                p.channel,
                p.sign,
                x,
                &fx,
                &inv_q,
                &g,
                &self.weights,
            ));
        }
        // The fit's rows (each a forward and backward pass of a network much smaller than the
        // flow) at most FIT_ROWS_PER_EVAL × the parts' adaptation.
        let max_rows = (adapt as usize * parts).saturating_mul(FIT_ROWS_PER_EVAL);
        let fit = fit(points, dim, k, part_seed(base, u64::MAX), max_rows)?;
        self.net = fit.net;
        Ok(((n * parts) as u64, fit.sigmas))
    }
}

/// Each part's standard deviation per evaluation of its estimate, from its adaptation's result.
fn sd_per_eval(measured: &[IntegrationResult]) -> Vec<f64> {
    measured
        .iter()
        .map(|r| r.std_err * (r.iterations.iter().map(|i| i.evals).sum::<u64>() as f64).sqrt())
        .collect()
}

/// Normalises `a` to sum to one with every entry at least `floor` (the entries below it are
/// raised to it, the others share the rest in proportion).
fn normalise_with_floor(a: &mut [f64], floor: f64) {
    let total: f64 = a.iter().sum();
    a.iter_mut().for_each(|v| *v /= total);
    for _ in 0..a.len() {
        let low = a.iter().filter(|v| **v < floor).count();
        if low == 0 {
            break;
        }
        let high: f64 = a.iter().filter(|v| **v >= floor).sum();
        let left = 1.0 - floor * low as f64;
        a.iter_mut().for_each(|v| {
            *v = if *v < floor { floor } else { *v * left / high };
        });
    }
}

/// Adapts a part on `n` evaluations and measures it: NIS trains on most of them and estimates
/// with the rest; the others integrate (VEGAS+ adapts while it does).
fn adapt_part(integ: &mut dyn Integrator, h: &dyn Integrand, n: u64) -> Result<IntegrationResult> {
    if let Some(nis) = integ.as_nis() {
        let train = n * 4 / 5;
        nis.train(h, train)?;
        let mut r = nis.estimate(h, n - train)?;
        r.n_eval += train;
        return Ok(r);
    }
    integ.integrate(h, n)
}

/// Points per part for the weight network: at least, at most, and at most all parts together
/// (a quarter of a part's adaptation within these bounds).
const NET_POINTS: (usize, usize, usize) = (1024, 8192, 1 << 16);
/// Rows of the weight network's fit per evaluation the parts adapted on.
const FIT_ROWS_PER_EVAL: usize = 2;
/// Salt of the weight network's points ("wnet").
const NET_SALT: u64 = 0x776e_6574;
