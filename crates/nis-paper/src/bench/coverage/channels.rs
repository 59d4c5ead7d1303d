//! The multi-channel cells of `nis bench coverage --peaked`: a built-in example integrated
//! through its channels (`nis integrate EX --channels`), each seed a [`MultiChannel`] with the
//! example's channels and the default [`MultiChannelConfig`], judged by the same warnings as the
//! single-channel cells. A multi-channel result carries the χ²/dof, the pooled k̂, the missing
//! mass and the hole of its parts together, but the divergence warning only as its parts'
//! sentences ("channel k: …"); [`part_labels`] reads those back into the warnings' labels.

use nis::channels::{examples, ChannelSet};
use nis::integrate::multichannel::{MultiChannel, MultiChannelConfig};
use nis::integrate::{IntegrationResult, Integrator};
use rayon::prelude::*;

use super::{settings, Budget, Cell};
use crate::error::Result;

/// The multi-channel examples the peaked run integrates through their channels: narrow
/// resonances (with their propagators as enhancements), the Dalitz plot's interfering ones, and
/// the signed pair, which the channels split by sign.
pub const PEAKED_CHANNELS: &[&str] = &["resonances-4d", "dalitz", "gauss-pm"];

/// The warnings' labels of the parts of a multi-channel result `r`, read from its sentences
/// ("channel k: …", "channel k (f > 0): …"): "divergence" for its divergence, "other" for
/// anything else a part says; each once, in that order. (A part's own χ², k̂, missing mass and
/// hole are not among them: the result judges those on the parts together.)
pub fn part_labels(r: &IntegrationResult) -> Vec<String> {
    let mut found = [false; 2];
    for w in &r.warnings {
        let Some(rest) = w.strip_prefix("channel ") else {
            continue;
        };
        let Some((_, sentence)) = rest.split_once(": ") else {
            continue;
        };
        let i = if sentence.starts_with("the sampler is far from the integrand's shape") {
            0
        } else {
            1
        };
        found[i] = true;
    }
    ["divergence", "other"]
        .iter()
        .zip(found)
        .filter(|(_, f)| *f)
        .map(|(l, _)| l.to_string())
        .collect()
}

/// One seed of `name` through its channels with `method` (a label of [`super::METHODS`]).
fn run_one(
    name: &str,
    method: &str,
    seed: u64,
    evals: u64,
    f: &nis::integrands::Builtin,
) -> nis::Result<IntegrationResult> {
    let (m, s) = settings(method, seed, true);
    let set = ChannelSet::new(examples::by_name(name)?.channels)?;
    MultiChannel::new(set, m, s, MultiChannelConfig::default())?.integrate(f, evals)
}

/// Runs the channel cell of example `name` and `method`: every seed of `budget`, in parallel
/// (each run is deterministic by its seed).
pub fn run_channel_cell(name: &str, method: &str, budget: Budget) -> Result<Cell> {
    let ex = examples::by_name(name)?;
    let f = &ex.integrand;
    let outcomes: Vec<(u64, nis::Result<IntegrationResult>)> = (0..budget.seeds)
        .into_par_iter()
        .map(|seed| (seed, run_one(name, method, seed, budget.evals, f)))
        .collect();
    Ok(Cell::of(f, method, true, budget, outcomes))
}

#[cfg(test)]
mod tests {
    use super::super::{warning_labels, DIVERGENCE_LIMIT};
    use super::*;
    use nis::integrate::Convergence;

    #[test]
    fn a_part_s_divergence_and_other_sentences_read_back_as_their_labels() {
        let c = Convergence {
            divergence: Some(2.0 * DIVERGENCE_LIMIT),
            ..Convergence::default()
        };
        let r = IntegrationResult {
            warnings: vec![
                format!("channel 1 (f > 0): {}", c.warnings()[0].sentence),
                "the channels together: χ²/dof = 4.20 between iterations: …".into(),
                "the channels' weights together: the weights f/q are heavy-tailed".into(),
                "channel 2: the integrand was zero at every sampled point".into(),
            ],
            ..IntegrationResult::default()
        };
        assert_eq!(part_labels(&r), ["divergence", "other"]);
        // A run without parts' warnings has none; the pooled k̂ and χ² are not a part's.
        let quiet = IntegrationResult {
            warnings: vec![
                "the channels' weights together: k̂".into(),
                "the channels together: χ²/dof = 4.20".into(),
            ],
            ..IntegrationResult::default()
        };
        assert!(part_labels(&quiet).is_empty());
    }

    #[test]
    fn a_channel_cell_reads_its_figures_and_its_parts_warnings() {
        let budget = Budget {
            evals: 20_000,
            seeds: 3,
        };
        let cell = run_channel_cell("resonances-4d", "NIS-χ²", budget).unwrap();
        assert!(cell.errors.is_empty(), "{:?}", cell.errors);
        assert_eq!((cell.runs.len(), cell.dim), (3, 4));
        assert_eq!(cell.label(), "resonances-4d d4 channels");
        for r in &cell.runs {
            // Through channels: the parts' labels are recorded (maybe none), k̂ pooled over the
            // parts, the missing mass summed over the NIS parts, and no divergence of its own.
            assert!(r.part_warnings.is_some());
            assert!(r.pareto_k.is_some() && r.pareto_k_limit.is_some());
            assert!(r.convergence.missing_mass.is_some());
            assert!(r.convergence.divergence.is_none());
            assert!(cell.pull(r).abs() < 10.0, "{}", cell.pull(r));
        }
        // Plain MC through channels keeps no training points: no missing mass to read.
        let mc = run_channel_cell("resonances-4d", "MC", budget).unwrap();
        assert!(mc.runs.iter().all(|r| r.convergence.missing_mass.is_none()));
        let mut warned = mc.runs[0].clone();
        warned.pareto_k = None;
        warned.part_warnings = Some(vec!["divergence".into()]);
        assert_eq!(warning_labels(&warned, "NIS-KL"), ["divergence"]);
    }
}
