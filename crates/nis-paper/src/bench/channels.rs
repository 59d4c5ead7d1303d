//! `nis bench channels`: multi-channel integration and sign splitting (issue 39), measured.
//!
//! - **Channels**: on the built-in multi-channel examples, the relative variance per evaluation
//!   (every evaluation counted, adapting and pilot included: σ²·n_eval/F²) of NIS with a flow per
//!   channel and with one shared flow (with and without the weight network), NIS without
//!   channels, the classic multi-channel estimator (uniform points per channel, fixed equal
//!   weights) and multi-channel VEGAS+, with the worst |pull| and the wall time over seeds. The variance per evaluation is given as the mean of the seeds' σ̂² (an
//!   unbiased estimate of the estimator's variance) and as their median: a heavy-tailed sampler
//!   has a skewed σ̂², whose median reads low.
//! - **Signs**: a positive and a negative Gaussian peak in 4-d (weights 1 and −0.6) and MadNIS's
//!   ±Gaussian toy (∫ = 0): NIS with a sampler per sign against NIS trained on |f|.
//! - **Machinery**: the wall time per evaluation of NIS through identity channels against NIS on
//!   the integrand alone, same batches and budget: what the channels cost besides the K channel
//!   densities every point needs.
//!
//! Writes the section "channels" of `docs/results/integration.md`.

use std::path::Path;
use std::time::Instant;

use nis::channels::{examples, Channel, ChannelFn, ChannelSet};
use nis::integrate::multichannel::{MultiChannel, MultiChannelConfig, Signs};
use nis::integrate::{integrator, Integrand, IntegrationResult, Integrator, Method, Settings};

use crate::error::Result;
use crate::report;

/// What to run.
#[derive(Clone, Debug)]
pub struct Options {
    /// The multi-channel examples.
    pub examples: Vec<String>,
    /// Evaluations per run on the examples.
    pub evals: u64,
    /// Evaluations per run of the signed comparison.
    pub signed_evals: u64,
    /// Seeds 1..=seeds.
    pub seeds: u64,
}

impl Default for Options {
    fn default() -> Self {
        Options {
            examples: ["resonances-4d", "phase-space-8d", "dalitz"]
                .map(String::from)
                .to_vec(),
            evals: 1_000_000,
            signed_evals: 2_000_000,
            seeds: 3,
        }
    }
}

/// A contender on a multi-channel example.
#[derive(Clone, Copy)]
enum Row {
    /// A method through the channels, weights adapted unless `fixed`; `densities`: the channel
    /// weights made of the densities, not of the channels' enhancements.
    Channels {
        method: Method,
        fixed: bool,
        densities: bool,
    },
    /// NIS through the channels with one flow conditioned on the channel; `net`: with the
    /// weight network (the default).
    Shared { densities: bool, net: bool },
    /// A method on the integrand alone.
    Plain(Method),
}

impl Row {
    fn label(self, k: usize) -> String {
        let by = |densities: bool| if densities { ", α ∝ a_k g_k" } else { "" };
        match self {
            Row::Channels {
                method,
                fixed,
                densities,
            } => format!(
                "{} ×{k}{}{}{}",
                method.label(),
                if method == Method::Nis {
                    ", a flow per channel"
                } else {
                    ""
                },
                if fixed { ", equal fixed weights" } else { "" },
                by(densities)
            ),
            Row::Shared { densities, net } => format!(
                "{} ×{k}, one shared flow{}",
                Method::Nis.label(),
                match (densities, net) {
                    (true, _) => by(true),
                    (false, true) => " (default)",
                    (false, false) => ", no weight network",
                }
            ),
            Row::Plain(m) => format!("{}, no channels", m.label()),
        }
    }

    /// Whether the row weights the channels by their densities.
    fn densities(self) -> bool {
        matches!(
            self,
            Row::Channels {
                densities: true,
                ..
            } | Row::Shared {
                densities: true,
                ..
            }
        )
    }
}

/// The rows; those weighting by densities run only for channels with enhancements.
const ROWS: [Row; 10] = [
    Row::Channels {
        method: Method::Nis,
        fixed: false,
        densities: false,
    },
    Row::Shared {
        densities: false,
        net: true,
    },
    Row::Shared {
        densities: false,
        net: false,
    },
    Row::Shared {
        densities: true,
        net: true,
    },
    Row::Plain(Method::Nis),
    Row::Channels {
        method: Method::Uniform,
        fixed: true,
        densities: false,
    },
    Row::Channels {
        method: Method::Uniform,
        fixed: true,
        densities: true,
    },
    Row::Channels {
        method: Method::Vegas,
        fixed: false,
        densities: false,
    },
    Row::Channels {
        method: Method::Vegas,
        fixed: false,
        densities: true,
    },
    Row::Plain(Method::Vegas),
];

/// One run: the result and its wall time.
fn timed(run: impl FnOnce() -> nis::Result<IntegrationResult>) -> Result<(IntegrationResult, f64)> {
    let t = Instant::now();
    let r = run()?;
    Ok((r, t.elapsed().as_secs_f64()))
}

/// σ²·n_eval/scale² (scale: F, or 1 for an integral of zero).
fn rel_var(r: &IntegrationResult, scale: f64) -> f64 {
    r.std_err * r.std_err * r.n_eval as f64 / (scale * scale)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// One row's runs over the seeds.
#[derive(Default)]
struct Runs {
    vars: Vec<f64>,
    pulls: Vec<f64>,
    secs: Vec<f64>,
}

impl Runs {
    fn push(&mut self, var: f64, pull: f64, secs: f64) {
        self.vars.push(var);
        self.pulls.push(pull.abs());
        self.secs.push(secs);
    }

    /// The table's cells: mean and median rel. var./eval, worst |pull|, median seconds.
    fn cells(self) -> String {
        let mean = self.vars.iter().sum::<f64>() / self.vars.len() as f64;
        format!(
            "{mean:.3e} | {:.3e} | {:.2} | {:.1}",
            median(self.vars),
            self.pulls.iter().fold(0.0f64, |a, b| a.max(*b)),
            median(self.secs)
        )
    }
}

/// The tables' header.
const HEADER: &str = "| rel. var./eval (mean) | (median) | worst \\|pull\\| | seconds |\n";

/// Runs both comparisons; `log(line)` after every run. Writes the section "channels" of `docs`
/// (when given) and returns its Markdown.
pub fn run(o: &Options, docs: Option<&Path>, log: &mut dyn FnMut(&str)) -> Result<String> {
    let mut md = format!(
        "Command: `nis bench channels` (defaults). Relative variance per evaluation σ²·n_eval/F² with every evaluation counted (the sign \
         pilot and adapting included), over seeds 1–{}: the mean of the seeds' σ̂² (unbiased) \
         and their median (a heavy-tailed sampler's σ̂² is skewed: its median reads low); worst \
         |pull| over the seeds; median wall time (2 cores, shared machine). {} evaluations per \
         run. Channels are each example's own (docs/INTEGRANDS.md, \"Multi-channel examples\").\n\n\
         | example | d | method {HEADER}|---|---:|---|---:|---:|---:|---:|\n",
        o.seeds, o.evals
    );
    for name in &o.examples {
        let ex = examples::by_name(name)?;
        let (dim, k, exact) = (ex.integrand.dim, ex.channels.len(), ex.exact);
        let enhanced = ChannelSet::new(examples::by_name(name)?.channels)?.enhanced();
        for row in ROWS {
            if row.densities() && !enhanced {
                continue;
            }
            let mut runs = Runs::default();
            for seed in 1..=o.seeds {
                let settings = Settings::default().seed(seed);
                let (r, s) = match row {
                    Row::Channels { .. } | Row::Shared { .. } => {
                        let (method, fixed) = match row {
                            Row::Channels { method, fixed, .. } => (method, fixed),
                            _ => (Method::Nis, false),
                        };
                        let mut set = ChannelSet::new(examples::by_name(name)?.channels)?;
                        if row.densities() {
                            set = set.without_enhancements();
                        }
                        let config = MultiChannelConfig {
                            adapt_weights: !fixed,
                            shared_flow: matches!(row, Row::Shared { .. }),
                            weight_network: !matches!(row, Row::Shared { net: false, .. }),
                            ..MultiChannelConfig::default()
                        };
                        let mut mc = MultiChannel::new(set, method, settings, config)?;
                        timed(|| mc.integrate(&ex.integrand, o.evals))?
                    }
                    Row::Plain(method) => {
                        let mut integ = integrator(method, dim, &settings)?;
                        timed(|| integ.integrate(&ex.integrand, o.evals))?
                    }
                };
                let v = rel_var(&r, exact);
                let pull = (r.value - exact) / r.std_err;
                log(&format!(
                    "{name} {} seed {seed}: rel.var {v:.3e}, pull {pull:.2}, {s:.1} s",
                    row.label(k)
                ));
                runs.push(v, pull, s);
            }
            md.push_str(&format!(
                "| {name} | {dim} | {} | {} |\n",
                row.label(k),
                runs.cells()
            ));
        }
    }
    md.push_str(&signed(o, log)?);
    md.push_str(&machinery(o, log)?);
    if let Some(docs) = docs {
        report::write_section(
            docs,
            "channels",
            "Channels and signed integrands (`nis bench channels`)",
            &md,
        )?;
    }
    Ok(md)
}

/// f = N(x; 0.3, σ) − 0.6·N(x; 0.7, σ) in 4-d, σ = 0.05, Gaussians normalised over R⁴.
fn signed_pair(x: &[f64]) -> f64 {
    let g = |c: f64| {
        let s2 = 0.05f64 * 0.05;
        let r2: f64 = x.iter().map(|v| (v - c).powi(2)).sum();
        (-r2 / (2.0 * s2)).exp() / (2.0 * std::f64::consts::PI * s2).powi(2)
    };
    g(0.3) - 0.6 * g(0.7)
}

/// ∫ over [0, 1]⁴ of [`signed_pair`]: each Gaussian's mass in the cube, Π ½[erf((1−c)/√2σ) +
/// erf(c/√2σ)].
fn signed_pair_exact() -> f64 {
    let mass = |c: f64| {
        let s = 0.05 * std::f64::consts::SQRT_2;
        (0.5 * (libm::erf((1.0 - c) / s) + libm::erf(c / s))).powi(4)
    };
    mass(0.3) - 0.6 * mass(0.7)
}

/// The signed comparison: a sampler per sign against one trained on |f|.
fn signed(o: &Options, log: &mut dyn FnMut(&str)) -> Result<String> {
    let mut md = format!(
        "\nSigned integrands, {} evaluations per run, seeds 1–{}: NIS split by sign \
         (`MultiChannel::single`, `signs: split`; one flow for both signs, the default, or a flow \
         per sign) against NIS whose flow learns |f|. For \
         MadNIS's ±Gaussian toy (∫ = 0) the figure is the absolute σ²·n_eval.\n\n\
         | integrand | d | method {HEADER}|---|---:|---|---:|---:|---:|---:|\n",
        o.signed_evals, o.seeds
    );
    let toy = examples::by_name("gauss-pm")?;
    let cases: [(&str, usize, &dyn Integrand, f64, f64); 2] = [
        (
            "± peaks (1, −0.6)",
            4,
            &signed_pair,
            signed_pair_exact(),
            signed_pair_exact(),
        ),
        // ∫ = 0: the absolute variance per evaluation.
        ("gauss-pm", 2, &toy.integrand, 0.0, 1.0),
    ];
    for (label, dim, f, exact, scale) in cases {
        // Split with one shared flow, split with a flow per sign, whole.
        for (split, shared) in [(true, true), (true, false), (false, false)] {
            let mut runs = Runs::default();
            for seed in 1..=o.seeds {
                let settings = Settings::default().seed(seed);
                let (r, s) = if split {
                    let config = MultiChannelConfig {
                        signs: Signs::Split,
                        shared_flow: shared,
                        ..MultiChannelConfig::default()
                    };
                    let mut mc = MultiChannel::single(dim, Method::Nis, settings, config)?;
                    timed(|| mc.integrate(f, o.signed_evals))?
                } else {
                    let mut integ = integrator(Method::Nis, dim, &settings)?;
                    timed(|| integ.integrate(f, o.signed_evals))?
                };
                let v = rel_var(&r, scale);
                let pull = (r.value - exact) / r.std_err;
                log(&format!(
                    "{label} split {split} shared {shared} seed {seed}: rel.var {v:.3e}, pull \
                     {pull:.2}, {s:.1} s"
                ));
                runs.push(v, pull, s);
            }
            md.push_str(&format!(
                "| {label} | {dim} | {} | {} |\n",
                if split && shared {
                    "nis, one flow for both signs"
                } else if split {
                    "nis, a flow per sign"
                } else {
                    "nis on \\|f\\|"
                },
                runs.cells()
            ));
        }
    }
    Ok(md)
}

/// The channel machinery's cost: NIS on camel d = 4 alone, through one identity channel, and
/// through four identity channels (one shared flow, and a flow each), at `o.evals`; median wall
/// time per evaluation over the seeds and its ratio to NIS alone.
fn machinery(o: &Options, log: &mut dyn FnMut(&str)) -> Result<String> {
    const DIM: usize = 4;
    let f = nis::integrands::by_name("camel", Some(DIM))?;
    let identity = || -> Box<dyn Channel> {
        Box::new(ChannelFn::new(
            DIM,
            |u: &[f64], x: &mut [f64]| x.copy_from_slice(u),
            |_| 1.0,
        ))
    };
    let mut md = format!(
        "\nThe channels' own cost: NIS on camel d = {DIM} alone and through identity channels \
         (x = u, g = 1: the parts are f/K), {} evaluations per run, seeds 1–{}, the default \
         batches, 40 % of the evaluations in training for all (`adapt_fraction` 0.5 through the \
         channels; by default they train on 20 %), without the weight network but in the last \
         row (its fit is a fixed cost, not the channels'); median wall time per evaluation \
         (training included) and its ratio to NIS alone, in the same run.\n\n\
         | NIS | µs per evaluation | ratio |\n|---|---:|---:|\n",
        o.evals, o.seeds
    );
    let rows: [(&str, usize, bool, bool); 5] = [
        ("alone", 0, false, false),
        ("through 1 channel", 1, true, false),
        ("through 4 channels, one shared flow", 4, true, false),
        ("through 4 channels, a flow each", 4, false, false),
        (
            "through 4 channels, one shared flow, weight network",
            4,
            true,
            true,
        ),
    ];
    let mut base = f64::NAN;
    for (label, k, shared, net) in rows {
        let mut secs = Vec::new();
        for seed in 1..=o.seeds {
            let settings = Settings::default().seed(seed);
            let (r, s) = if k == 0 {
                let mut integ = integrator(Method::Nis, DIM, &settings)?;
                timed(|| integ.integrate(&f, o.evals))?
            } else {
                let set = ChannelSet::new((0..k).map(|_| identity()).collect())?;
                // Adapting on half the budget trains on 4/5 of it: 40 %, as NIS alone does.
                let config = MultiChannelConfig {
                    signs: Signs::Whole,
                    shared_flow: shared,
                    adapt_fraction: 0.5,
                    weight_network: net,
                    ..MultiChannelConfig::default()
                };
                let mut mc = MultiChannel::new(set, Method::Nis, settings, config)?;
                timed(|| mc.integrate(&f, o.evals))?
            };
            let us = s * 1e6 / r.n_eval as f64;
            log(&format!("machinery {label} seed {seed}: {us:.2} µs/eval"));
            secs.push(us);
        }
        let us = median(secs);
        if k == 0 {
            base = us;
        }
        md.push_str(&format!("| {label} | {us:.2} | {:.2} |\n", us / base));
    }
    Ok(md)
}
