//! Training the neural guide (Müller et al. 2019, "Neural Importance Sampling", §5): after
//! every training pass, Adam steps of both networks on batches drawn from the replay buffer of
//! records, with the paper's off-policy gradients of the KL or χ² divergence (see the module
//! docs of [`super`]), and what each training phase did ([`TrainingStats`]).

use glam::Vec2;
use nis::flow::{Bijection, Coupling, Density, Layer};
use nis::nn::ParamAverage;
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;
use rayon::prelude::*;

use super::record_draw::{self, RecordPicker};
use super::records::{PassSamples, Sample};
use super::{GuideLoss, NisGuide};
use crate::guiding::cylindrical_to_dir;
use crate::guiding::directions::GuideFrame;

/// Bit position of the training phase's index in the seed of its batch stream: each phase
/// draws its batches from a stream of its own, disjoint from the weights' streams (whose
/// salts use only the low bits).
const PHASE_SEED_SHIFT: u32 = 32;

/// The gradients of a training step's loss: the flow's, and the selection network's when it
/// learns.
pub(super) struct StepGradients {
    pub(super) flow: Vec<f32>,
    pub(super) selection: Option<Vec<f32>>,
}

/// What one part of a training step adds up ([`NisGuide::part_gradients`]), before the
/// division by the batch's mean weight.
#[derive(Default)]
struct PartGradients {
    /// Sum of the records' weights.
    weight: f64,
    /// Sum of the records' χ² weights, when part of the selection network's loss is the χ²
    /// divergence ([`NisGuideConfig::selection_chi2_share`](super::NisGuideConfig)).
    weight_chi: f64,
    /// Sum of the records' weighted losses.
    loss: f64,
    /// Sum of the selection probabilities.
    selection_sum: f64,
    flow: Vec<f32>,
    selection: Option<Vec<f32>>,
    /// The selection network's gradient of the χ² divergence (weights `weight_chi`).
    selection_chi: Option<Vec<f32>>,
}

/// What one training phase did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TrainingStats {
    /// Records with non-zero `F` that arrived in the pass.
    pub new_records: usize,
    /// Adam steps taken.
    pub steps: usize,
    /// Mean selection probability of the guide over the last batch.
    pub mean_selection: f64,
    /// Mean over the last batch of the normalised loss, `−(w/w̄)·ln q` for KL and `(w/w̄)` for
    /// χ² (`w` the sample weight of the chosen loss), before the step.
    pub loss: f64,
    /// Wall-clock seconds the training phase took.
    pub seconds: f64,
    /// Share of the flow's probability mass below the surface (directions on the other side
    /// of the shading normal than `ω_o`) at the last batch's vertices, from one flow sample per
    /// record drawn after the phase's steps (0 by construction in the local frame, whose
    /// hemisphere map has no point below the surface).
    pub below_surface: f64,
    /// The one selection probability that would minimise the KL divergence of the mixture on
    /// the last batch, with the flow as it is after the phase (the best constant the selection
    /// network could have learned; compare [`TrainingStats::mean_selection`]).
    pub best_constant_selection: f64,
}

impl NisGuide {
    /// One Adam step on `batch`, whose records were favoured by the factors `scales`
    /// ([`RecordPicker::scale`]): of the flow, and of the selection network when `selection`.
    pub(super) fn step(
        &mut self,
        batch: &[Sample],
        scales: &[f64],
        selection: bool,
    ) -> nis::Result<TrainingStats> {
        // The batch in parts of `chunk_rows(n)` records (a function of `n` alone), each through
        // both networks and back on one thread: a step is one parallel loop over the parts,
        // not dozens of loops over a few hundred records each, which the cores handed over one
        // by one.
        let part = Coupling::chunk_rows(batch.len());
        let (stats, gradients) = self.gradients(batch, scales, selection, part)?;
        if let Some(g) = gradients {
            self.flow_adam.step(self.flow.params_mut(), &g.flow)?;
            if let Some(g_sel) = g.selection {
                let s = &mut self.selection;
                s.adam.step(&mut s.params, &g_sel)?;
            }
        }
        Ok(stats)
    }

    /// The loss of a step on `batch` and its gradients (none when no record of the batch
    /// carries weight), computed `part` records at a time and summed in the parts' order.
    ///
    /// Each part runs both networks forward and back with its records' weights as they are;
    /// the loss and the gradients are linear in the weights, so their sums are divided by the
    /// batch's mean weight once every part is done. The parts are then one parallel loop, not
    /// two with the mean between them: the other core sleeps at the end of every loop, and
    /// waking it again cost more than its share of the work (docs/results/guiding.md).
    pub(super) fn gradients(
        &self,
        batch: &[Sample],
        scales: &[f64],
        selection: bool,
        part: usize,
    ) -> nis::Result<(TrainingStats, Option<StepGradients>)> {
        let n = batch.len();
        let parts = batch
            .par_chunks(part)
            .zip(scales.par_chunks(part))
            .map(|(b, scales)| self.part_gradients(b, scales, selection, n))
            .collect::<nis::Result<Vec<_>>>()?;
        let mean = parts.iter().map(|p| p.weight).sum::<f64>() / n as f64;
        let mut stats = TrainingStats {
            mean_selection: parts.iter().map(|p| p.selection_sum).sum::<f64>() / n as f64,
            ..TrainingStats::default()
        };
        if mean <= 0.0 || !mean.is_finite() {
            return Ok((stats, None));
        }
        stats.loss = parts.iter().map(|p| p.loss).sum::<f64>() / mean / n as f64;
        let mean_chi = parts.iter().map(|p| p.weight_chi).sum::<f64>() / n as f64;
        let mut g_flow = vec![0.0f32; self.flow.params().len()];
        let mut g_sel = selection.then(|| vec![0.0f32; self.selection.params.len()]);
        let mut g_chi = g_sel
            .clone()
            .filter(|_| mean_chi > 0.0 && mean_chi.is_finite());
        for p in parts {
            g_flow.iter_mut().zip(&p.flow).for_each(|(a, b)| *a += b);
            if let (Some(sum), Some(s)) = (&mut g_sel, p.selection) {
                sum.iter_mut().zip(&s).for_each(|(a, b)| *a += b);
            }
            if let (Some(sum), Some(s)) = (&mut g_chi, p.selection_chi) {
                sum.iter_mut().zip(&s).for_each(|(a, b)| *a += b);
            }
        }
        let inv_mean = (1.0 / mean) as f32;
        for g in g_flow.iter_mut().chain(g_sel.iter_mut().flatten()) {
            *g *= inv_mean;
        }
        // The selection's loss: (1 − λ) of the guide's own, λ of the χ² divergence, each
        // normalised by its batch's mean weight.
        if let (Some(sel), Some(chi)) = (&mut g_sel, &g_chi) {
            let share = self.config.selection_chi2_share;
            let inv_chi = (1.0 / mean_chi) as f32;
            for (a, b) in sel.iter_mut().zip(chi) {
                *a = (1.0 - share) * *a + share * inv_chi * b;
            }
        }
        Ok((
            stats,
            Some(StepGradients {
                flow: g_flow,
                selection: g_sel,
            }),
        ))
    }

    /// One part of a step of `n` records ([`NisGuide::gradients`]): both networks forward and
    /// back with the records' weights `F/(p_s·scale)` (KL) or `F²/(p_s·q_mix·scale)` (χ²), not
    /// yet divided by the batch's mean weight.
    fn part_gradients(
        &self,
        batch: &[Sample],
        scales: &[f64],
        selection: bool,
        n: usize,
    ) -> nis::Result<PartGradients> {
        let scalars: Vec<_> = batch.iter().map(|s| s.context).collect();
        let context = self.encode(&scalars);
        let x: Vec<f32> = batch.iter().flat_map(|s| s.x).collect();
        let evaluated = self.flow.log_density_for_training(&x, Some(&context))?;
        let (forward, c) = self.selection.forward(&context);
        let m = self.config.min_selection;
        let mut out = PartGradients {
            selection_sum: c.iter().map(|&c| f64::from(c)).sum(),
            ..PartGradients::default()
        };
        let mixed = selection && self.config.selection_chi2_share > 0.0;
        let mut w_flow = vec![0.0f32; batch.len()];
        let mut g_logit = vec![0.0f32; batch.len()];
        let mut g_logit_chi = vec![0.0f32; if mixed { batch.len() } else { 0 }];
        for (i, (s, &log_q)) in batch.iter().zip(&evaluated.log_q).enumerate() {
            let q = (log_q.exp() as f32) * s.jacobian;
            let q_mix = c[i] * q + (1.0 - c[i]) * s.bsdf_pdf;
            let w = match self.config.loss {
                GuideLoss::Kl => s.kl_weight(),
                GuideLoss::ChiSquare => {
                    f64::from(s.f) * f64::from(s.f) / (f64::from(s.pdf) * f64::from(q_mix))
                }
            } / scales[i];
            let w = if w.is_finite() { w } else { 0.0 };
            out.weight += w;
            out.loss += match self.config.loss {
                GuideLoss::Kl => -w * f64::from(q_mix).ln(),
                GuideLoss::ChiSquare => w,
            };
            if q_mix > 0.0 {
                w_flow[i] = (w * f64::from(c[i] * q / q_mix) / n as f64) as f32;
                // The logit's sigmoid, and the mixture's derivative in c.
                let sig = (c[i] - m) / (1.0 - 2.0 * m);
                let d_c = (f64::from(q - s.bsdf_pdf) / f64::from(q_mix)) as f32;
                let d_z = f64::from(d_c * (1.0 - 2.0 * m) * sig * (1.0 - sig)) / n as f64;
                g_logit[i] = (-w * d_z) as f32;
                if mixed {
                    let w_chi = f64::from(s.f) * f64::from(s.f)
                        / (f64::from(s.pdf) * f64::from(q_mix) * scales[i]);
                    let w_chi = if w_chi.is_finite() { w_chi } else { 0.0 };
                    out.weight_chi += w_chi;
                    g_logit_chi[i] = (-w_chi * d_z) as f32;
                }
            }
        }
        out.flow = self.flow.backward(&evaluated.tape, &w_flow)?;
        out.selection = selection.then(|| self.selection.backward(&forward, &g_logit));
        out.selection_chi = mixed.then(|| self.selection.backward(&forward, &g_logit_chi));
        Ok(out)
    }

    /// The constant `c ∈ [c_min, 1 − c_min]` that maximises `Σ (F/p_s)·ln(c·p_flow + (1 − c)·p_bsdf)`
    /// over the records `batch` stands for (favoured by `scales`), a concave function of `c`:
    /// bisection on its derivative.
    fn best_constant_selection(&self, batch: &[Sample], scales: &[f64]) -> f64 {
        let scalars: Vec<_> = batch.iter().map(|s| s.context).collect();
        let context = self.encode(&scalars);
        let x: Vec<f32> = batch.iter().flat_map(|s| s.x).collect();
        let Ok(log_q) = self.flow.log_density(&x, Some(&context)) else {
            return f64::NAN;
        };
        let terms: Vec<(f64, f64, f64)> = batch
            .iter()
            .zip(&log_q)
            .zip(scales)
            .map(|((s, l), scale)| {
                let q = l.exp() * f64::from(s.jacobian);
                (s.kl_weight() / scale, q, f64::from(s.bsdf_pdf))
            })
            .filter(|(w, q, _)| w.is_finite() && q.is_finite())
            .collect();
        let slope = |c: f64| -> f64 {
            terms
                .iter()
                .map(|&(w, q, b)| w * (q - b) / (c * q + (1.0 - c) * b).max(f64::MIN_POSITIVE))
                .sum()
        };
        let m = f64::from(self.config.min_selection);
        let (mut lo, mut hi) = (m, 1.0 - m);
        if slope(lo) <= 0.0 {
            return lo;
        }
        if slope(hi) >= 0.0 {
            return hi;
        }
        for _ in 0..40 {
            let mid = 0.5 * (lo + hi);
            if slope(mid) > 0.0 {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        0.5 * (lo + hi)
    }

    /// Share of the flow's samples at the vertices of the records `batch` stands for (favoured
    /// by `scales`, so each counts 1/s) that fall on the other side of the surface from ω_o
    /// (below it at opaque vertices).
    fn below_surface(&self, batch: &[Sample], scales: &[f64], rng: &mut Pcg64Mcg) -> f64 {
        if self.config.frame == GuideFrame::Local {
            // Nothing of the hemisphere map lies below the surface (and the sphere map is for
            // the transmissive vertices, where the other side is not below the surface).
            return 0.0;
        }
        let scalars: Vec<_> = batch.iter().map(|s| s.context).collect();
        let context = self.encode(&scalars);
        let z: Vec<f32> = (0..2 * batch.len()).map(|_| rng.random()).collect();
        let Ok((x, _)) = self.flow.inverse(&z, Some(&context)) else {
            return f64::NAN;
        };
        // World frame: the context holds ω_o and the normal in world coordinates (this counts
        // transmission at transmissive vertices too; the built-in scenes have none).
        let (below, all) = batch.iter().zip(x.chunks_exact(2)).zip(scales).fold(
            (0.0, 0.0),
            |(below, all), ((s, x), scale)| {
                let c = &s.context;
                let n = cylindrical_to_dir(Vec2::new(c[5], c[6]));
                let wo = cylindrical_to_dir(Vec2::new(c[3], c[4]));
                let wi = cylindrical_to_dir(Vec2::new(x[0], x[1]));
                let count = 1.0 / scale;
                let under = n.dot(wi) * n.dot(wo) < 0.0;
                (below + if under { count } else { 0.0 }, all + count)
            },
        );
        if all > 0.0 {
            below / all
        } else {
            0.0
        }
    }

    /// Train on the records of the pass that just ended (the `iteration`-th training phase).
    pub(super) fn train(&mut self, new: PassSamples, iteration: usize) {
        let start = std::time::Instant::now();
        let new_records = new.seen;
        // A pass brings up to millions of records: the copy and the first touch of the new
        // pages run on every core, in the same order (docs/results/guiding.md, "Training").
        self.buffer.par_extend(new.samples.par_iter().copied());
        if self.buffer.len() > self.config.buffer {
            let excess = self.buffer.len() - self.config.buffer;
            self.buffer.drain(..excess);
        }
        let mut stats = TrainingStats {
            new_records,
            ..TrainingStats::default()
        };
        if !self.buffer.is_empty() {
            let steps = (new_records / self.config.batch)
                .clamp(self.config.min_steps, self.config.max_steps);
            if let Some(a) = &mut self.average {
                a.resume(&mut [self.flow.params_mut(), &mut self.selection.params]);
                a.set_decay(ParamAverage::span_decay(
                    f64::from(self.config.average_span),
                    steps,
                ));
            }
            let phase = iteration as u64 + 1;
            let mut rng = Pcg64Mcg::seed_from_u64(self.config.seed ^ phase << PHASE_SEED_SHIFT);
            let size = self.config.batch.min(self.buffer.len());
            let alpha = record_draw::phase_alpha(
                f64::from(self.config.pick_by_weight),
                steps * size,
                self.buffer.len(),
            );
            let picker = RecordPicker::new(self.buffer.par_iter().map(Sample::kl_weight), alpha);
            let mut scales: Vec<f64> = Vec::with_capacity(size);
            let mut batch = Vec::with_capacity(size);
            let mut picks = Vec::with_capacity(size);
            for _ in 0..steps {
                // The indices from the phase's stream in order, and their records: a serial
                // gather, as two parallel loops over a batch cost more than they shared.
                picker.pick(size, &mut rng, &mut picks);
                batch.clear();
                batch.extend(picks.iter().map(|&i| self.buffer[i]));
                scales.clear();
                scales.extend(batch.iter().map(|s| picker.scale(s.kl_weight())));
                let selection = self.history.len() >= self.config.selection_warmup;
                match self.step(&batch, &scales, selection) {
                    Ok(s) => {
                        stats.mean_selection = s.mean_selection;
                        stats.loss = s.loss;
                        stats.steps += 1;
                        if let Some(a) = &mut self.average {
                            a.add(&[self.flow.params(), &self.selection.params]);
                        }
                    }
                    // A non-finite gradient (a rare huge weight) skips the step.
                    Err(_) => continue,
                }
            }
            self.trained = true;
            if let Some(a) = &mut self.average {
                a.use_average(&mut [self.flow.params_mut(), &mut self.selection.params]);
            }
            self.refresh_context();
            stats.below_surface = self.below_surface(&batch, &scales, &mut rng);
            stats.best_constant_selection = self.best_constant_selection(&batch, &scales);
        }
        stats.seconds = start.elapsed().as_secs_f64();
        self.history.push(stats);
    }
}
