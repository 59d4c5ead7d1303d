//! The result of a multi-channel integral: the parts' estimates summed, and what each channel
//! and sign contributed ([`ChannelReport`]).

use std::time::Instant;

use super::config::Sign;
use crate::integrate::convergence::Convergence;
use crate::integrate::diagnostics::{Reliability, WeightTail};
use crate::integrate::estimate::{chi2_warning, CHI2_LIMIT};
use crate::integrate::result::{ChannelReport, IntegrationResult, SignReport};

/// Sums the parts' `results` ((channel, sign) each in `index`) into one result.
pub(super) fn combine(
    index: &[(usize, Sign)],
    results: &[IntegrationResult],
    weights: &[f64],
    channels: usize,
    n_eval: u64,
    started: Instant,
) -> IntegrationResult {
    let mut sums = Sums::new(weights, channels, results.len());
    for (&(k, sign), r) in index.iter().zip(results) {
        sums.add(k, sign, r);
    }
    sums.finish(n_eval, started)
}

/// The parts' estimates summed as [`combine`] adds them, in their order.
struct Sums<'a> {
    report: ChannelReport,
    value: f64,
    var: f64,
    signs: SignReport,
    /// Whether a part is one of a sign split.
    split: bool,
    warnings: Vec<String>,
    /// The parts' χ² summed over their degrees of freedom: the χ² of independent estimates,
    /// one test of the whole result instead of one per part (each at its own false-alarm rate).
    chi2_sum: f64,
    chi2_dof: f64,
    estimate_evals: u64,
    /// Every part's weights scaled by 1/n: each its point's share of the sum F.
    tails: Vec<(&'a WeightTail, f64)>,
    /// Σ |F_p| over the parts, and the unweighting trials Σ |F_p| / efficiency_p.
    abs_total: f64,
    trials: f64,
    missing: Missing,
}

impl<'a> Sums<'a> {
    fn new(weights: &[f64], channels: usize, parts: usize) -> Sums<'a> {
        Sums {
            report: ChannelReport {
                weights: weights.to_vec(),
                means: vec![0.0; channels],
                std_errs: vec![0.0; channels],
                evals: vec![0; channels],
                signs: None,
            },
            value: 0.0,
            var: 0.0,
            signs: SignReport::default(),
            split: false,
            warnings: Vec::new(),
            chi2_sum: 0.0,
            chi2_dof: 0.0,
            estimate_evals: 0,
            tails: Vec::with_capacity(parts),
            abs_total: 0.0,
            trials: 0.0,
            missing: Missing::default(),
        }
    }

    /// Adds the result `r` of part (channel `k`, `sign`).
    fn add(&mut self, k: usize, sign: Sign, r: &'a IntegrationResult) {
        let v = r.std_err * r.std_err;
        self.value += sign.factor() * r.value;
        self.var += v;
        self.report.means[k] += sign.factor() * r.value;
        self.report.std_errs[k] += v;
        let evals: u64 = r.iterations.iter().map(|i| i.evals).sum();
        self.report.evals[k] += evals;
        self.estimate_evals += evals;
        self.split |= add_to_signs(&mut self.signs, sign, r.value, v, evals);
        let dof = r.iterations.len().saturating_sub(1) as f64;
        if r.chi2_per_dof.is_finite() && dof > 0.0 {
            self.chi2_sum += r.chi2_per_dof * dof;
            self.chi2_dof += dof;
        }
        if let Some(t) = &r.tail {
            self.tails.push((t, 1.0 / t.count().max(1) as f64));
        }
        self.abs_total += r.value.abs();
        if r.unweighting_efficiency > 0.0 {
            self.trials += r.value.abs() / r.unweighting_efficiency;
        }
        self.warnings.extend(part_warnings(k, sign, r));
        self.missing.add(r);
    }

    /// The result of the sums, `n_eval` every evaluation spent.
    fn finish(mut self, n_eval: u64, started: Instant) -> IntegrationResult {
        let mut report = self.report;
        report.std_errs.iter_mut().for_each(|v| *v = v.sqrt());
        if self.split {
            report.signs = Some(finished(self.signs));
        }
        let chi2 = if self.chi2_dof > 0.0 {
            self.chi2_sum / self.chi2_dof
        } else {
            f64::NAN
        };
        let (value, var) = (self.value, self.var);
        let pooled = WeightTail::pooled(&self.tails);
        let convergence = self.missing.convergence(var.sqrt());
        together_warnings(&mut self.warnings, chi2, &pooled, &convergence);
        IntegrationResult {
            value,
            std_err: var.sqrt(),
            chi2_per_dof: chi2,
            n_eval,
            rel_var_per_eval: self.estimate_evals as f64 * var / (value * value),
            unweighting_efficiency: if self.trials > 0.0 {
                self.abs_total / self.trials
            } else {
                0.0
            },
            pareto_k: pooled.pareto_k,
            pareto_k_limit: pooled.pareto_k_limit,
            tail_end_p: pooled.tail_end_p,
            ess: pooled.ess,
            var_rel_err: pooled.var_rel_err,
            seconds: started.elapsed().as_secs_f64(),
            warnings: self.warnings,
            convergence,
            channels: Some(report),
            ..IntegrationResult::default()
        }
    }
}

/// The warnings of the parts judged together, after the parts' own: their summed χ²/dof, their
/// pooled weights' tail, and their summed missing mass.
fn together_warnings(
    warnings: &mut Vec<String>,
    chi2: f64,
    pooled: &Reliability,
    convergence: &Convergence,
) {
    if chi2 > CHI2_LIMIT {
        warnings.push(format!("the channels together: {}", chi2_warning(chi2)));
    }
    if let Some(w) = pooled.warning() {
        warnings.push(format!("the channels' weights together: {w}"));
    }
    for w in convergence.recalled_warnings() {
        warnings.push(format!("the channels together: {}", w.sentence));
    }
}

/// The parts' missing masses ([`Convergence::missing_mass`]) summed, each in absolute units,
/// so that the sum is judged against the combined error bar the user sees.
#[derive(Default)]
struct Missing {
    mass: f64,
    var: f64,
    beyond: u64,
    largest_shift: f64,
    seen: bool,
}

impl Missing {
    fn add(&mut self, r: &IntegrationResult) {
        let c = &r.convergence;
        if let Some(m) = c.missing_mass {
            self.seen = true;
            self.mass += m * r.std_err;
            self.var += (c.missing_mass_err.unwrap_or(0.0) * r.std_err).powi(2);
            self.beyond += c.recalled_beyond.unwrap_or(0);
            self.largest_shift = self
                .largest_shift
                .max(c.recalled_shift.unwrap_or(0.0) * r.std_err);
        }
    }

    fn convergence(&self, std_err: f64) -> Convergence {
        if !self.seen || std_err <= 0.0 || !std_err.is_finite() {
            return Convergence::default();
        }
        Convergence {
            missing_mass: Some(self.mass / std_err),
            missing_mass_err: Some(self.var.sqrt() / std_err),
            recalled_beyond: Some(self.beyond),
            recalled_shift: Some(self.largest_shift / std_err),
            ..Convergence::default()
        }
    }
}

/// Adds a part's `value`, variance `v` and `evals` to F⁺ or F⁻ (sums of variances until
/// [`finished`]); whether the part is one of a sign split.
fn add_to_signs(signs: &mut SignReport, sign: Sign, value: f64, v: f64, evals: u64) -> bool {
    match sign {
        Sign::Plus => {
            signs.positive += value;
            signs.positive_err += v;
            signs.positive_evals += evals;
        }
        Sign::Minus => {
            signs.negative += value;
            signs.negative_err += v;
            signs.negative_evals += evals;
        }
        Sign::Both => return false,
    }
    true
}

/// F⁺ and F⁻ with their standard errors (from the sums of variances) and the share of negative
/// weights.
fn finished(mut signs: SignReport) -> SignReport {
    signs.positive_err = signs.positive_err.sqrt();
    signs.negative_err = signs.negative_err.sqrt();
    let total = signs.positive + signs.negative;
    signs.negative_fraction = if total > 0.0 {
        signs.negative / total
    } else {
        0.0
    };
    signs
}

/// The warnings of part (channel `k`, `sign`), labelled with it; none for a part that is zero
/// wherever it looked, which is normal here (the negative part of a channel where f > 0), and
/// neither its own k̂ nor its missing mass or hole, which are judged on the parts together.
fn part_warnings(k: usize, sign: Sign, r: &IntegrationResult) -> Vec<String> {
    if r.value == 0.0 && r.std_err == 0.0 {
        return Vec::new();
    }
    let label = match sign {
        Sign::Both => format!("channel {k}"),
        Sign::Plus => format!("channel {k} (f > 0)"),
        Sign::Minus => format!("channel {k} (f < 0)"),
    };
    let own_k = r.reliability().warning();
    let own_chi2 = chi2_warning(r.chi2_per_dof);
    let own: Vec<String> = r
        .convergence
        .recalled_warnings()
        .into_iter()
        .map(|w| w.sentence)
        .collect();
    r.warnings
        .iter()
        .filter(|w| own_k.as_ref() != Some(*w) && **w != own_chi2 && !own.contains(w))
        .map(|w| format!("{label}: {w}"))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::integrate::estimate::chi2_warning;
    use crate::integrate::iteration::Iteration;

    /// A part's result of `k` iterations with χ²/dof `chi2` and its warning where it warns.
    fn part(k: usize, chi2: f64) -> IntegrationResult {
        let it = Iteration {
            estimate: 1.0,
            variance: 0.01,
            evals: 100,
            source: Default::default(),
            max_abs_w: 1.0,
            sum_abs_w: 100.0,
            components: None,
        };
        IntegrationResult {
            value: 1.0,
            std_err: 0.1,
            chi2_per_dof: chi2,
            iterations: vec![it; k],
            warnings: (chi2 > CHI2_LIMIT)
                .then(|| chi2_warning(chi2))
                .into_iter()
                .collect(),
            ..IntegrationResult::default()
        }
    }

    #[test]
    fn the_parts_chi_square_is_summed_over_their_degrees_of_freedom_and_tested_once() {
        let index = [(0, Sign::Both), (1, Sign::Both), (2, Sign::Both)];
        let combined = |parts: &[IntegrationResult]| {
            combine(&index, parts, &[1.0 / 3.0; 3], 3, 900, Instant::now())
        };
        // One part at 4.0 on 2 dof beside two at 1.0 on 8: (8 + 8 + 8)/18 = 1.33, no warning,
        // and the part's own warning is not passed on.
        let r = combined(&[part(3, 4.0), part(9, 1.0), part(9, 1.0)]);
        assert!(
            (r.chi2_per_dof - 24.0 / 18.0).abs() < 1e-12,
            "{}",
            r.chi2_per_dof
        );
        assert!(
            r.warnings.iter().all(|w| !w.contains("χ²")),
            "{:?}",
            r.warnings
        );
        // A part far off (χ²/dof 40 on 2 dof) moves the sum past the limit: one warning.
        let r = combined(&[part(3, 40.0), part(9, 1.0), part(9, 1.0)]);
        assert!((r.chi2_per_dof - 96.0 / 18.0).abs() < 1e-12);
        let chi2: Vec<_> = r.warnings.iter().filter(|w| w.contains("χ²")).collect();
        assert_eq!(chi2.len(), 1, "{:?}", r.warnings);
        assert!(
            chi2[0].starts_with("the channels together: χ²/dof = 5.33"),
            "{chi2:?}"
        );
        // Parts of one iteration have no χ²: neither has the sum.
        assert!(
            combined(&[part(1, f64::NAN), part(1, f64::NAN), part(1, f64::NAN)])
                .chi2_per_dof
                .is_nan()
        );
    }
}
