//! `nis bench time-to-precision`: how long each method takes to reach a relative error with an
//! honest answer, on the cheap built-in integrands and with a synthetic cost per point.
//!
//! For each integrand, method (NIS, our VEGAS+, plain MC, the Python `vegas` package) and seed, a
//! ladder of fresh runs at budgets doubling from 10⁴ ([`ladder`]); the time to a target is the
//! wall time of the first run whose relative error is below it with |pull| < 4, the median over
//! seeds, or "> cap" with the error reached. Writes a table into a section of
//! `docs/results/integration.md` and a plot of relative error against wall time per integrand.

pub mod cost;
pub mod ladder;
mod plot;
mod section;
pub mod vegas_package;

use std::path::PathBuf;
use std::time::Instant;

use nis::integrate::{integrator, Integrand, IntegrationResult, Method, Settings, Target};

use self::cost::SyntheticCost;
use self::ladder::{Outcome, Run};
pub use self::section::cell_text;
use crate::error::{Error, Result};

/// The default cells: the camel families where NIS should win, a wide Gaussian, and the
/// non-separable integrands (VEGAS+'s weak spot).
pub const DEFAULT_CELLS: &[(&str, usize)] = &[
    ("camel", 4),
    ("camel", 8),
    ("camel", 16),
    ("camel-sharp", 4),
    ("camel-sharp", 8),
    ("camel-sharp", 16),
    ("gauss", 16),
    ("gauss-diagonal", 4),
    ("peaks", 4),
    ("ridge", 4),
];

/// The default targets of relative error.
pub const DEFAULT_TARGETS: [f64; 2] = [1e-3, 1e-4];

/// Points of the calibration batch on the Python side.
const PYTHON_CALIBRATION_POINTS: usize = 1 << 15;

/// A method in the race.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Contender {
    /// Our NIS integrator with its defaults.
    Nis,
    /// Our VEGAS+ with its defaults.
    Vegas,
    /// Plain Monte Carlo.
    Uniform,
    /// The Python `vegas` package, as its documentation runs it.
    VegasPackage,
    /// NIS with the flow of fewer layers (`"masks": "codes"`), for cheap integrands.
    NisCodes,
    /// NIS asked for the target itself (`integrate_to`): one run per target, no ladder.
    NisTarget,
    /// Our VEGAS+ asked for the target itself.
    VegasTarget,
}

impl Contender {
    /// Every contender, in table order.
    pub const ALL: [Contender; 7] = [
        Contender::NisTarget,
        Contender::Nis,
        Contender::NisCodes,
        Contender::VegasTarget,
        Contender::Vegas,
        Contender::Uniform,
        Contender::VegasPackage,
    ];

    /// The contenders a run has unless told otherwise.
    pub const DEFAULT: [Contender; 6] = [
        Contender::NisTarget,
        Contender::Nis,
        Contender::VegasTarget,
        Contender::Vegas,
        Contender::Uniform,
        Contender::VegasPackage,
    ];

    /// The name `--methods` reads and the table shows.
    pub fn name(self) -> &'static str {
        match self {
            Contender::Nis => "nis",
            Contender::Vegas => "vegas+",
            Contender::Uniform => "mc",
            Contender::VegasPackage => "vegas-py",
            Contender::NisCodes => "nis-codes",
            Contender::NisTarget => "nis-target",
            Contender::VegasTarget => "vegas+-target",
        }
    }

    /// Our library's settings for this contender with `seed`.
    fn settings(self, seed: u64) -> Settings {
        let mut settings = Settings::default().seed(seed);
        if self == Contender::NisCodes {
            settings.nis.flow.masks = nis::flow::mask::Masks::Codes;
        }
        settings
    }

    /// Whether it integrates to each target itself instead of running a ladder of budgets.
    fn asks_for_target(self) -> bool {
        matches!(self, Contender::NisTarget | Contender::VegasTarget)
    }

    /// Our library's method, if it is one of ours.
    fn method(self) -> Option<Method> {
        match self {
            Contender::Nis | Contender::NisCodes | Contender::NisTarget => Some(Method::Nis),
            Contender::Vegas | Contender::VegasTarget => Some(Method::Vegas),
            Contender::Uniform => Some(Method::Uniform),
            Contender::VegasPackage => None,
        }
    }
}

impl std::str::FromStr for Contender {
    type Err = Error;
    fn from_str(s: &str) -> Result<Contender> {
        Contender::ALL
            .into_iter()
            .find(|c| c.name() == s)
            .ok_or_else(|| {
                Error::Config(format!(
                    "unknown method {s:?}: expected nis-target, nis, nis-codes, vegas+-target, \
                     vegas+, mc or vegas-py"
                ))
            })
    }
}

/// What to run.
#[derive(Clone, Debug)]
pub struct Options {
    /// (integrand, dimension) cells.
    pub cells: Vec<(String, usize)>,
    /// The methods.
    pub contenders: Vec<Contender>,
    /// Target relative errors.
    pub targets: Vec<f64>,
    /// Seeds 1..=seeds.
    pub seeds: u64,
    /// Wall-time cap of one ladder (one method, integrand and seed), seconds.
    pub cap: f64,
    /// Synthetic cost added per point, wall µs (0: the cheap integrand).
    pub cost_us: f64,
    /// The `nis` binary that serves the integrand to the Python side (`nis eval`).
    pub cli: Option<PathBuf>,
    /// Markdown file the section goes to, with the plots in `img/` beside it;
    /// `None` writes nothing.
    pub docs: Option<PathBuf>,
    /// Count only answers that carry no warning (ours; the `vegas` package has none).
    pub trusted: bool,
}

impl Default for Options {
    fn default() -> Options {
        Options {
            cells: DEFAULT_CELLS
                .iter()
                .map(|&(n, d)| (n.to_string(), d))
                .collect(),
            contenders: Contender::DEFAULT.to_vec(),
            targets: DEFAULT_TARGETS.to_vec(),
            seeds: 3,
            cap: 300.0,
            cost_us: 0.0,
            cli: None,
            docs: None,
            trusted: false,
        }
    }
}

impl Options {
    fn check(&self) -> Result<()> {
        let bad = |m: String| Err(Error::Config(m));
        if self.cells.is_empty() || self.contenders.is_empty() || self.targets.is_empty() {
            return bad("time-to-precision: no cell, method or target to run".into());
        }
        if self.seeds == 0 {
            return bad("time-to-precision: --seeds must be at least 1".into());
        }
        if !(self.cap.is_finite() && self.cap > 0.0) {
            return bad(format!(
                "time-to-precision: cap {} s is not positive",
                self.cap
            ));
        }
        if !(self.cost_us.is_finite() && self.cost_us >= 0.0) {
            return bad(format!(
                "time-to-precision: cost {} µs is negative",
                self.cost_us
            ));
        }
        if let Some(t) = self.targets.iter().find(|t| !(t.is_finite() && **t > 0.0)) {
            return bad(format!("time-to-precision: target {t} is not positive"));
        }
        if self.contenders.contains(&Contender::VegasPackage) && self.cli.is_none() {
            return bad("time-to-precision: the vegas package needs the nis binary".into());
        }
        Ok(())
    }
}

/// The runs of one method and seed on one cell.
#[derive(Clone, Debug)]
pub struct Ladder {
    pub contender: Contender,
    pub seed: u64,
    pub runs: Vec<Run>,
}

/// The measured cost per point of one cell's integrand, on both sides.
#[derive(Clone, Debug)]
pub struct CostReport {
    /// Spins per point (see [`cost`]).
    pub spins: u64,
    /// Wall µs per point in process, with the cost.
    pub ours_us: f64,
    /// Wall µs per point through `nis eval` from Python, with the cost.
    pub python_us: Option<f64>,
}

/// Everything measured on one (integrand, dimension).
#[derive(Clone, Debug)]
pub struct CellResult {
    pub name: String,
    pub dim: usize,
    pub exact: f64,
    pub ladders: Vec<Ladder>,
    pub cost: CostReport,
}

impl CellResult {
    /// The median outcome of `contender` for `target` (None if it did not run).
    pub fn median(&self, contender: Contender, target: f64, cap: f64) -> Option<Outcome> {
        let outcomes: Vec<Outcome> = self
            .ladders
            .iter()
            .filter(|l| l.contender == contender)
            .map(|l| ladder::outcome(&l.runs, target, self.exact, cap))
            .collect();
        ladder::median(&outcomes)
    }
}

/// Where a run is, for progress bars: `done` of `total` ladders finished; `message` says what
/// just ran, and `finished` whether it ended a ladder (a line worth keeping).
pub struct Progress<'a> {
    pub done: usize,
    pub total: usize,
    pub message: &'a str,
    pub finished: bool,
}

/// Runs the race; writes the section and the plots when `o.docs` is set; returns the cells and
/// the Markdown.
pub fn run(
    o: &Options,
    progress: &mut dyn FnMut(Progress<'_>),
) -> Result<(Vec<CellResult>, String)> {
    o.check()?;
    let python = if o.contenders.contains(&Contender::VegasPackage) {
        Some(vegas_package::python()?)
    } else {
        None
    };
    let total = o.cells.len() * o.contenders.len() * o.seeds as usize;
    let mut done = 0;
    let mut cells = Vec::new();
    let mut versions = None;
    // Other processes running before the first run: the times below are noisy.
    let shared = load_average() >= SHARED_LOAD;
    for (name, dim) in &o.cells {
        let f = nis::integrands::by_name(name, Some(*dim))?;
        let spins = cost::calibrate(&f, f.dim, o.cost_us)?;
        let costly = SyntheticCost::new(&f, spins);
        let mut cost = CostReport {
            spins,
            ours_us: cost::micros_per_point(&costly, f.dim)?,
            python_us: None,
        };
        let mut ladders = Vec::new();
        for &contender in &o.contenders {
            let mut package = match (&python, &o.cli) {
                (Some(py), Some(cli)) if contender == Contender::VegasPackage => {
                    let mut p = vegas_package::VegasPackage::start(py, cli, name, f.dim, spins)?;
                    let c = p.calibrate(PYTHON_CALIBRATION_POINTS)?;
                    cost.python_us = Some(c.us_per_point);
                    versions = Some((c.vegas, c.python));
                    Some(p)
                }
                _ => None,
            };
            let mut outcomes = vec![Vec::new(); o.targets.len()];
            for seed in 1..=o.seeds {
                if !ladder::worth_more_seeds(&outcomes, o.seeds as usize) {
                    done += 1;
                    continue;
                }
                let runs = if contender.asks_for_target() {
                    let method = contender.method().expect("one of ours");
                    to_targets(
                        method,
                        &contender.settings(seed),
                        &costly,
                        f.dim,
                        &o.targets,
                        o.cap,
                        o.trusted,
                    )?
                } else {
                    ladder::ladder(&o.targets, f.exact, o.cap, |evals| {
                        let r = match (contender.method(), package.as_mut()) {
                            (Some(method), _) => ours(
                                method,
                                &contender.settings(seed),
                                &costly,
                                f.dim,
                                evals,
                                o.trusted,
                            ),
                            (None, Some(p)) => p.run(seed, evals),
                            (None, None) => Err(Error::Config("no vegas package".into())),
                        }?;
                        progress(Progress {
                        done,
                        total,
                        message: &format!(
                            "{name} d={dim} {} seed {seed}: {evals} evals, rel. err {:.2e}, {:.1} s",
                            contender.name(),
                            r.rel_err(),
                            r.seconds
                        ),
                        finished: false,
                    });
                        Ok::<Run, Error>(r)
                    })?
                };
                for (t, out) in o.targets.iter().zip(&mut outcomes) {
                    out.push(ladder::outcome(&runs, *t, f.exact, o.cap));
                }
                done += 1;
                let line = format!(
                    "{name:<14} d={dim:<2} {:<8} seed {seed}: {}",
                    contender.name(),
                    o.targets
                        .iter()
                        .zip(&outcomes)
                        .map(|(t, out)| format!("{t:.0e}: {}", cell_text(out.last(), o.cap)))
                        .collect::<Vec<_>>()
                        .join(", ")
                );
                progress(Progress {
                    done,
                    total,
                    message: &line,
                    finished: true,
                });
                ladders.push(Ladder {
                    contender,
                    seed,
                    runs,
                });
            }
        }
        cells.push(CellResult {
            name: name.clone(),
            dim: f.dim,
            exact: f.exact,
            ladders,
            cost,
        });
    }
    let mut md = section::table(o, &cells, shared, versions.as_ref());
    if let Some(docs) = &o.docs {
        section::write_docs(o, docs, &cells, &mut md)?;
    }
    Ok((cells, md))
}

/// One fresh run of our `method`, timed around building the integrator and integrating;
/// `trusted`: a warning disowns it.
fn ours(
    method: Method,
    settings: &Settings,
    f: &dyn Integrand,
    dim: usize,
    evals: u64,
    trusted: bool,
) -> Result<Run> {
    let start = Instant::now();
    let r = integrator(method, dim, settings)?.integrate(f, evals)?;
    Ok(record(&r, evals, start, trusted))
}

/// The record of result `r` of `evals` evaluations, started at `start`; `trusted`: a warning
/// disowns it.
fn record(r: &IntegrationResult, evals: u64, start: Instant, trusted: bool) -> Run {
    Run {
        evals,
        seconds: start.elapsed().as_secs_f64(),
        value: r.value,
        std_err: r.std_err,
        disowned: trusted && !r.warnings.is_empty(),
    }
}

/// One run to each target (loosest first, so that [`ladder::outcome`] takes each target's own
/// run), capped at `cap` seconds; `trusted`: a warning disowns a run.
fn to_targets(
    method: Method,
    settings: &Settings,
    f: &dyn Integrand,
    dim: usize,
    targets: &[f64],
    cap: f64,
    trusted: bool,
) -> Result<Vec<Run>> {
    let mut sorted = targets.to_vec();
    sorted.sort_by(|a, b| b.total_cmp(a));
    sorted
        .iter()
        .map(|&t| {
            let start = Instant::now();
            let r = integrator(method, dim, settings)?
                .integrate_to(f, &Target::rel(t).max_seconds(cap))?;
            Ok(record(&r, r.n_eval, start, trusted))
        })
        .collect()
}

/// The 1-minute load average at the start above which the section says the machine was shared.
const SHARED_LOAD: f64 = 0.5;

/// The 1-minute load average (how busy the machine was), NaN where unknown.
fn load_average() -> f64 {
    std::fs::read_to_string("/proc/loadavg")
        .ok()
        .and_then(|s| s.split_whitespace().next()?.parse().ok())
        .unwrap_or(f64::NAN)
}
