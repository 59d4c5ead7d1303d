//! `nis bench coverage`: are the error bars honest? For suite integrands × methods (NIS-KL,
//! NIS-χ², VEGAS+, plain MC) at a small and a moderate budget, many seeds each: the fraction of
//! runs whose 1σ and 2σ intervals cover the exact value, the mean and worst pull, the mean χ²/dof,
//! and how well the reliability diagnostic (PSIS's Pareto k̂, [`nis::integrate::diagnostics`])
//! sorts the runs: how many of those more than 4σ off it flags, and whether the unflagged ones
//! cover at their nominal rate. Every cell is cached as JSON as soon as it is done, so an
//! interrupted run resumes where it stopped. Writes a section of `docs/results/robustness.md` and a plot.
//! The peaked run also integrates multi-channel examples through their channels (`channels.rs`).

use std::path::{Path, PathBuf};

use nis::integrands::{self, Builtin, SUITE};
use nis::integrate::{
    integrator, Convergence, Method, Reliability, Settings, CHI2_LIMIT, DIVERGENCE_LIMIT,
    HOLE_LIMIT, MISSING_MASS_LIMIT, PARETO_K_LIMIT, PARETO_K_Z,
};
use nis::loss::Loss;
use plotters::prelude::*;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::image::figure::{canvas, draw_legend, figure_error, has_font, png_bytes};
use crate::report;

mod channels;
mod section;
pub use channels::{part_labels, run_channel_cell, PEAKED_CHANNELS};
use section::*;
pub use section::{band, converged, warning_labels};

/// A budget and how many seeds run at it.
#[derive(Clone, Copy, Debug)]
pub struct Budget {
    /// Evaluations per run, adaptation included.
    pub evals: u64,
    /// Seeds 0..seeds.
    pub seeds: u64,
}

/// The two budgets: ~2·10⁴ evaluations × 200 seeds and ~2·10⁵ × 50.
pub const BUDGETS: [Budget; 2] = [
    Budget {
        evals: 20_000,
        seeds: 200,
    },
    Budget {
        evals: 200_000,
        seeds: 50,
    },
];

/// The cells of the default run: one or two dimensions of each kind of integrand — smooth and
/// separable, sharp peaks, non-separable shapes (scattered peaks, a curved ridge),
/// discontinuities, a sign change — chosen so the run fits in about 30 minutes on 2 cores;
/// `--full` runs every suite entry in every dimension.
pub const DEFAULT_CELLS: &[(&str, usize)] = &[
    ("camel", 4),
    ("camel-sharp", 2),
    ("gauss-sharp", 4),
    ("annulus", 2),
    ("corner-peak", 4),
    ("oscillatory", 2),
    ("peaks", 4),
    ("ridge", 4),
];

/// The peaked cells of issue 40, where small budgets leave the sampler unconverged, and a signed
/// pair of peaks integrated whole (`--peaked`; its split by sign is the channel cell of
/// [`PEAKED_CHANNELS`]).
pub const PEAKED_CELLS: &[(&str, usize)] = &[
    ("camel-sharp", 4),
    ("camel-sharp", 6),
    ("camel-sharp", 8),
    ("gauss-sharp", 4),
    ("gauss-sharp", 6),
    ("gauss-sharp", 8),
    ("gauss-diagonal", 4),
    ("gauss-diagonal", 6),
    ("gauss-diagonal", 8),
    ("peaks", 4),
    ("peaks", 6),
    ("peaks", 8),
    ("ridge", 4),
    ("ridge", 6),
    ("ridge", 8),
    ("gauss-pm", 2),
];

/// The methods, as the table names them.
pub const METHODS: [&str; 4] = ["NIS-KL", "NIS-χ²", "VEGAS+", "MC"];

/// What to run and where to write.
pub struct Options {
    /// Every suite integrand in every dimension instead of [`DEFAULT_CELLS`].
    pub full: bool,
    /// Only this integrand (all its dimensions in the chosen set).
    pub only: Option<String>,
    /// [`PEAKED_CELLS`] and the examples of [`PEAKED_CHANNELS`] through their channels instead
    /// of [`DEFAULT_CELLS`], into the section "coverage-peaked".
    pub peaked: bool,
    /// Seeds per cell instead of each budget's own.
    pub seeds: Option<u64>,
    /// Only the first budget (small).
    pub small_only: bool,
    /// Directory of the per-cell JSON cache.
    pub cache: PathBuf,
    /// The Markdown file the section goes into.
    pub docs: PathBuf,
}

/// One run's outcome.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Run {
    /// The seed.
    pub seed: u64,
    /// Estimate and its standard error.
    pub value: f64,
    /// Standard error.
    pub std_err: f64,
    /// χ²/dof between the final iterations (`None` where undefined).
    pub chi2: Option<f64>,
    /// Pareto k̂ (`None` where it cannot be fitted).
    pub pareto_k: Option<f64>,
    /// The k̂ above which the run warns (`None` in caches from before the limit depended on the
    /// tail: such runs are judged by [`PARETO_K_LIMIT`] alone).
    #[serde(default)]
    pub pareto_k_limit: Option<f64>,
    /// Where the tail ends ([`nis::integrate::diagnostics::TAIL_END_P`]; `None` without a fit and
    /// in caches from before the check: such runs are judged by k̂ and its limit alone).
    #[serde(default)]
    pub tail_end_p: Option<f64>,
    /// Effective sample size.
    pub ess: f64,
    /// The relative error of the variance estimate (`None` where undefined).
    #[serde(default)]
    pub var_rel_err: Option<f64>,
    /// Wall seconds.
    pub seconds: f64,
    /// The sampler's convergence figures (through channels: the parts' missing mass and hole
    /// together, no divergence).
    #[serde(default)]
    pub convergence: Convergence,
    /// Through channels: the labels of the warnings its parts gave ([`part_labels`]), which
    /// take the place of χ² and the divergence; `None` for a single-channel run.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub part_warnings: Option<Vec<String>>,
}

/// One cell: an integrand, a method and a budget, all its seeds.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Cell {
    /// Integrand name.
    pub integrand: String,
    /// Dimension.
    pub dim: usize,
    /// Method label (one of [`METHODS`]).
    pub method: String,
    /// Whether its runs integrate the example through its channels ([`PEAKED_CHANNELS`]).
    #[serde(default)]
    pub channels: bool,
    /// Evaluations per run.
    pub evals: u64,
    /// The exact value and its uncertainty.
    pub exact: f64,
    /// Uncertainty of `exact` (0 when exact).
    pub exact_err: f64,
    /// The runs that gave a result.
    pub runs: Vec<Run>,
    /// The runs that ended with an error: (seed, message).
    pub errors: Vec<(u64, String)>,
}

/// The statistics of a set of runs.
#[derive(Clone, Copy, Debug, Default)]
pub struct Stats {
    /// Runs.
    pub n: usize,
    /// Fractions whose 1σ and 2σ intervals cover the exact value.
    pub cover1: f64,
    /// See `cover1`.
    pub cover2: f64,
    /// Mean pull (value − exact)/σ.
    pub mean_pull: f64,
    /// The pull largest in magnitude.
    pub worst_pull: f64,
    /// Mean χ²/dof over the runs where it is defined.
    pub mean_chi2: f64,
    /// Fraction whose k̂ warns ([`Run::k_warns`]).
    pub flagged: f64,
    /// Median k̂ over the runs where it is defined.
    pub median_k: f64,
}

impl Run {
    /// The figures of result `r` of `seed`.
    pub fn of(seed: u64, r: &nis::integrate::IntegrationResult) -> Run {
        Run {
            seed,
            value: r.value,
            std_err: r.std_err,
            chi2: r.chi2_per_dof.is_finite().then_some(r.chi2_per_dof),
            pareto_k: r.pareto_k.is_finite().then_some(r.pareto_k),
            pareto_k_limit: r.pareto_k_limit.is_finite().then_some(r.pareto_k_limit),
            tail_end_p: r.tail_end_p.is_finite().then_some(r.tail_end_p),
            ess: r.ess,
            var_rel_err: r.var_rel_err.is_finite().then_some(r.var_rel_err),
            seconds: r.seconds,
            convergence: r.convergence,
            part_warnings: r.channels.is_some().then(|| part_labels(r)),
        }
    }

    /// Whether its k̂ warns, by the result's own rule ([`Reliability::k_warns`]) on its figures:
    /// a figure the cache lacks is NaN, which neither warns nor quiets (a run without its own
    /// limit is judged by [`PARETO_K_LIMIT`]).
    pub fn k_warns(&self) -> bool {
        let nan = f64::NAN;
        Reliability {
            pareto_k: self.pareto_k.unwrap_or(nan),
            pareto_k_limit: self.pareto_k_limit.unwrap_or(PARETO_K_LIMIT),
            tail_end_p: self.tail_end_p.unwrap_or(nan),
            ess: self.ess,
            var_rel_err: self.var_rel_err.unwrap_or(nan),
        }
        .k_warns()
    }

    /// How many standard errors of k̂ it lies above [`PARETO_K_LIMIT`] (the test's statistic;
    /// its limit is [`PARETO_K_Z`]), from the limit it was judged by.
    pub fn k_excess(&self) -> Option<f64> {
        let (k, limit) = (self.pareto_k?, self.pareto_k_limit?);
        let se = (limit - PARETO_K_LIMIT) / PARETO_K_Z;
        (se > 0.0).then(|| (k - PARETO_K_LIMIT) / se)
    }
}

impl Cell {
    /// The cell of integrand `f` (its name, dimension and exact value) and `method` from its
    /// runs' outcomes, seed by seed.
    fn of(
        f: &Builtin,
        method: &str,
        channels: bool,
        budget: Budget,
        outcomes: Vec<(u64, nis::Result<nis::integrate::IntegrationResult>)>,
    ) -> Cell {
        let mut cell = Cell {
            integrand: f.name.clone(),
            dim: f.dim,
            method: method.into(),
            channels,
            evals: budget.evals,
            exact: f.exact,
            exact_err: f.exact_err,
            runs: Vec::new(),
            errors: Vec::new(),
        };
        for (seed, o) in outcomes {
            match o {
                Ok(r) => cell.runs.push(Run::of(seed, &r)),
                Err(e) => cell.errors.push((seed, e.to_string())),
            }
        }
        cell
    }

    /// Its row label: "camel d4", or "resonances-4d d4 channels" through channels.
    pub fn label(&self) -> String {
        let through = if self.channels { " channels" } else { "" };
        format!("{} d{}{through}", self.integrand, self.dim)
    }

    /// The pull of a run, with the exact value's own uncertainty folded in.
    pub fn pull(&self, r: &Run) -> f64 {
        (r.value - self.exact) / r.std_err.hypot(self.exact_err)
    }

    /// The statistics of its runs.
    pub fn stats(&self) -> Stats {
        stats(self.runs.iter().map(|r| (self.pull(r), r)))
    }
}

/// Statistics of (pull, run) pairs.
fn stats<'a>(runs: impl Iterator<Item = (f64, &'a Run)>) -> Stats {
    let mut s = Stats::default();
    let (mut chi2_sum, mut chi2_n) = (0.0, 0usize);
    let mut ks = Vec::new();
    for (p, r) in runs {
        ks.extend(r.pareto_k);
        s.n += 1;
        s.cover1 += (p.abs() <= 1.0) as u8 as f64;
        s.cover2 += (p.abs() <= 2.0) as u8 as f64;
        s.mean_pull += p;
        if p.abs() > s.worst_pull.abs() || s.worst_pull.is_nan() {
            s.worst_pull = p;
        }
        if let Some(c) = r.chi2.filter(|c| c.is_finite()) {
            chi2_sum += c;
            chi2_n += 1;
        }
        s.flagged += r.k_warns() as u8 as f64;
    }
    let n = s.n.max(1) as f64;
    s.cover1 /= n;
    s.cover2 /= n;
    s.mean_pull /= n;
    s.flagged /= n;
    ks.sort_by(f64::total_cmp);
    s.median_k = ks.get(ks.len() / 2).copied().unwrap_or(f64::NAN);
    s.mean_chi2 = if chi2_n > 0 {
        chi2_sum / chi2_n as f64
    } else {
        f64::NAN
    };
    s
}

/// The settings of a method by its label, for a whole integrand or for the parts of a
/// multi-channel one (`channels`: there the default loss is χ², so NIS-KL asks for KL).
fn settings(method: &str, seed: u64, channels: bool) -> (Method, Settings) {
    let mut s = Settings::default().seed(seed);
    let m = match method {
        "NIS-KL" => {
            if channels {
                s.nis.loss = Loss::Kl;
            }
            Method::Nis
        }
        "NIS-χ²" => {
            s.nis.loss = Loss::ChiSquare;
            Method::Nis
        }
        "VEGAS+" => Method::Vegas,
        _ => Method::Uniform,
    };
    (m, s)
}

/// Runs one cell: every seed of `budget`, in parallel (each run is deterministic by its seed).
pub fn run_cell(f: &Builtin, method: &str, budget: Budget) -> Cell {
    let outcomes: Vec<(u64, nis::Result<nis::integrate::IntegrationResult>)> = (0..budget.seeds)
        .into_par_iter()
        .map(|seed| {
            let (m, s) = settings(method, seed, false);
            (
                seed,
                integrator(m, f.dim, &s).and_then(|mut i| i.integrate(f, budget.evals)),
            )
        })
        .collect();
    Cell::of(f, method, false, budget, outcomes)
}

/// What a cached run records: raised when the warnings read a figure older caches lack (2: the
/// k̂ limit of each run's own tail; 3: where the tail ends), so that such a cache is run anew
/// instead of misjudged.
const RECORD: u32 = 3;

/// As [`RECORD`], for the channel cells alone (2: χ² of the parts together, not any part's; 3:
/// the pooled variance estimate's relative error).
const CHANNEL_RECORD: u32 = 3;

/// The cache file of a cell, named by the cell and by a hash of the default settings of every
/// method and of [`RECORD`], so that cells run under other defaults (a training batch, an
/// encoding, i.i.d. latents) cannot pass for this run's; a channel cell's name says
/// "channels" and its hash covers the multi-channel defaults too (a single-channel cell's hash
/// is as before). (The hash changes with the Rust version too; that only costs a rerun.)
fn cache_path(dir: &Path, spec: &Spec, method: &str, budget: Budget) -> PathBuf {
    use std::hash::{DefaultHasher, Hash, Hasher};
    let method = method.replace("χ²", "chi2").to_lowercase();
    let mut hasher = DefaultHasher::new();
    serde_json::to_string(&Settings::default())
        .expect("settings serialise")
        .hash(&mut hasher);
    RECORD.hash(&mut hasher);
    let through = if spec.channels {
        serde_json::to_string(&nis::integrate::multichannel::MultiChannelConfig::default())
            .expect("settings serialise")
            .hash(&mut hasher);
        CHANNEL_RECORD.hash(&mut hasher);
        "-channels"
    } else {
        ""
    };
    let (name, dim) = (&spec.name, spec.dim);
    dir.join(format!(
        "{name}-d{dim}{through}-{method}-{}-{}-{:016x}.json",
        budget.evals,
        budget.seeds,
        hasher.finish()
    ))
}

/// A cell of the run without its method: an integrand, its dimension, and whether it goes
/// through the example's channels.
#[derive(Clone, Debug)]
struct Spec {
    name: String,
    dim: usize,
    channels: bool,
}

/// Every cell of the run.
fn cells(o: &Options) -> Result<Vec<Spec>> {
    let spec = |name: &str, dim, channels| Spec {
        name: name.to_string(),
        dim,
        channels,
    };
    let mut all: Vec<Spec> = if o.full {
        SUITE
            .iter()
            .flat_map(|e| e.dims.iter().map(|&d| spec(e.name, d, false)))
            .collect()
    } else {
        let set = if o.peaked {
            PEAKED_CELLS
        } else {
            DEFAULT_CELLS
        };
        set.iter().map(|&(n, d)| spec(n, d, false)).collect()
    };
    if o.peaked && !o.full {
        for name in PEAKED_CHANNELS {
            let dim = nis::channels::examples::by_name(name)?.integrand.dim;
            all.push(spec(name, dim, true));
        }
    }
    Ok(all
        .into_iter()
        .filter(|s| o.only.as_deref().is_none_or(|only| only == s.name))
        .collect())
}

/// Runs (or reads from the cache) every cell, reporting each with `log` (cells done, cells in
/// all, a line); writes the section "coverage" of `o.docs` and its plot beside it, and returns
/// the Markdown.
pub fn run(o: &Options, log: &mut dyn FnMut(usize, usize, &str)) -> Result<String> {
    report::create_dir(&o.cache)?;
    let budgets: Vec<Budget> = BUDGETS[..if o.small_only { 1 } else { 2 }]
        .iter()
        .map(|b| Budget {
            seeds: o.seeds.unwrap_or(b.seeds),
            ..*b
        })
        .collect();
    let budgets = &budgets[..];
    let list = cells(o)?;
    if list.is_empty() {
        return Err(Error::Config(format!(
            "no suite integrand named {:?}",
            o.only.as_deref().unwrap_or("")
        )));
    }
    let mut done = Vec::new();
    let total = budgets.len() * list.len() * METHODS.len();
    for &budget in budgets {
        for spec in &list {
            let f = integrands::by_name(&spec.name, Some(spec.dim))?;
            for method in METHODS {
                let path = cache_path(&o.cache, spec, method, budget);
                let cached = std::fs::read(&path)
                    .ok()
                    .and_then(|b| serde_json::from_slice::<Cell>(&b).ok());
                let cell = match cached {
                    Some(c) => c,
                    None => {
                        let c = if spec.channels {
                            run_channel_cell(&spec.name, method, budget)?
                        } else {
                            run_cell(&f, method, budget)
                        };
                        let json =
                            serde_json::to_vec(&c).map_err(|e| Error::Config(e.to_string()))?;
                        report::write_file(&path, &json)?;
                        c
                    }
                };
                let s = cell.stats();
                log(
                    done.len() + 1,
                    total,
                    &format!(
                        "{} {method:<7} {:>7} evals: 2σ cover {:.3}, worst pull {:+.1}, \
                     k̂-flagged {:.2}, {} errors",
                        cell.label(),
                        budget.evals,
                        s.cover2,
                        s.worst_pull,
                        s.flagged,
                        cell.errors.len()
                    ),
                );
                done.push(cell);
            }
        }
    }
    let md = markdown(&done, budgets);
    let figure = report::images_dir(&o.docs).join(if o.peaked {
        "coverage-peaked.png"
    } else {
        "coverage.png"
    });
    report::create_dir(figure.parent().unwrap_or(Path::new(".")))?;
    report::write_file(&figure, &png_bytes(&plot(&done, budgets)?)?)?;
    let body = format!(
        "{md}\n2σ coverage per cell (x: the cells in the order of the tables) and method:\n\n![2σ coverage per cell and method]({})\n",
        report::relative_to(&o.docs, &figure)
    );
    if o.peaked {
        report::write_section(
            &o.docs,
            "coverage-peaked",
            "Coverage on peaked integrands at small budgets, and the warnings",
            &body,
        )?;
    } else {
        report::write_section(&o.docs, "coverage", "Coverage of the error bars", &body)?;
    }
    Ok(body)
}

#[cfg(test)]
mod tests;
