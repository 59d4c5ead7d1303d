//! `nis integrate` and `nis list`: integrate a built-in integrand with NIS, VEGAS+ and plain MC.

use std::path::PathBuf;

use clap::builder::{PossibleValuesParser, TypedValueParser};
use indicatif::{ProgressBar, ProgressStyle};
use nis::comm::Comm;

use crate::channels::{channel_lines, sample_events, ChannelArgs, EventsRequest};
use nis::flow::mask::Masks;
use nis::flow::Density;
use nis::integrands::{self, Builtin, SUITE};
use nis::integrate::multichannel::by_default;
use nis::integrate::unweight::{SampleFormat, SampleWriter};
use nis::integrate::{
    disagreements, nis::NisConfig, nis::NisIntegrator, IntegrationResult, Integrator, Method,
    Settings, Target, DISAGREEMENT_SIGMAS,
};
use nis::loss::Loss;

/// `--method`: the library's method names, listed in `--help`.
fn method_parser() -> impl TypedValueParser<Value = Method> {
    PossibleValuesParser::new(Method::ALL.map(Method::name))
        .map(|s| s.parse::<Method>().expect("a listed method"))
}

/// `--coupling`: the names of the library's `coupling` keyword.
#[derive(Clone, Copy, clap::ValueEnum)]
pub enum Coupling {
    Pq,
    Pl,
    Rq,
    Affine,
}

impl Coupling {
    fn name(self) -> &'static str {
        match self {
            Coupling::Pq => "pq",
            Coupling::Pl => "pl",
            Coupling::Rq => "rq",
            Coupling::Affine => "affine",
        }
    }
}

#[derive(clap::Args)]
pub struct IntegrateArgs {
    /// Built-in integrand (see `nis list`).
    pub name: String,
    /// Dimension (default: the integrand's smallest).
    #[arg(long)]
    pub dim: Option<usize>,
    /// Method; without it, NIS, VEGAS+ and plain MC run side by side.
    #[arg(long, value_parser = method_parser())]
    pub method: Option<Method>,
    /// Coupling transform of the flow (default: NisConfig's, pq).
    #[arg(long, value_enum, conflicts_with = "load")]
    pub coupling: Option<Coupling>,
    /// Bins of the coupling transform (default: NisConfig's, 16).
    #[arg(long, conflicts_with = "load")]
    pub bins: Option<usize>,
    /// Training loss: kl, chi2 or auto (the default: kl for one integrand, chi2 for the parts of a
    /// multi-channel integral).
    #[arg(long, conflicts_with = "load")]
    pub loss: Option<Loss>,
    /// How the flow's coupling layers split the dimensions: binary (the paper's masks, the
    /// default) or codes (fewer layers: a faster flow with a higher variance per evaluation, for
    /// cheap integrands; it misses modes more often, so check it against the side-by-side run;
    /// docs/results/integration.md, "Flow masks: binary against codes"). Without it, a run to a
    /// target switches to codes when its first batches show a smooth integrand; with it, never.
    #[arg(long, conflicts_with = "load")]
    pub masks: Option<Masks>,
    /// Evaluations per method (NIS training included). A target (--rel-err, --abs-err)
    /// replaces it.
    #[arg(long, default_value_t = 1_000_000, conflicts_with_all = ["rel_err", "abs_err"])]
    pub evals: u64,
    /// Integrate until the standard error is at most this fraction of |value| (or --abs-err is
    /// met), or a limit (--max-evals, --seconds) is reached; the result says which.
    #[arg(long, conflicts_with = "load")]
    pub rel_err: Option<f64>,
    /// Integrate until the standard error is at most this (or --rel-err is met).
    #[arg(long, conflicts_with = "load")]
    pub abs_err: Option<f64>,
    #[command(flatten)]
    pub channel: ChannelArgs,
    /// With a target: the most evaluations per method, training included [default: 10^8].
    #[arg(long, conflicts_with = "load")]
    pub max_evals: Option<u64>,
    /// With a target: the most wall-clock seconds per method, training included.
    #[arg(long, conflicts_with = "load")]
    pub seconds: Option<f64>,
    /// Random seed.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Print one JSON object (for one method; NIS if none is given).
    #[arg(long)]
    pub json: bool,
    /// Save the trained NIS integrator to this file.
    #[arg(long, conflicts_with = "load")]
    pub save: Option<PathBuf>,
    /// Load a trained NIS integrator and spend all evaluations on the estimate (with the
    /// settings it was saved with: --coupling, --bins, --loss and --nis-config conflict with it).
    #[arg(long)]
    pub load: Option<PathBuf>,
    /// NIS settings to change, as JSON merged into the defaults, e.g.
    /// '{"batch": 2048, "flow": {"hidden_width": 64}, "adam": {"learning_rate": 0.001}}';
    /// '{"stratify": null}' draws the final phase's latents i.i.d. instead of stratified,
    /// '{"stratify": {"beta": 0}}' keeps equal counts per hypercube.
    #[arg(long, value_name = "JSON", conflicts_with = "load")]
    pub nis_config: Option<String>,
}

type Error = Box<dyn std::error::Error>;

impl IntegrateArgs {
    /// Every method's settings: the named flags as the library's keywords (as Python's are;
    /// `--seed` seeds every method), then `--nis-config` laid over the NIS section, both read
    /// by the library's one reader of settings.
    pub fn settings(&self) -> Result<Settings, Error> {
        use serde_json::json;
        let mut keywords = vec![("seed", json!(self.seed))];
        if let Some(c) = self.coupling {
            keywords.push(("coupling", json!(c.name())));
        }
        if let Some(b) = self.bins {
            keywords.push(("bins", json!(b)));
        }
        if let Some(l) = self.loss {
            keywords.push(("loss", serde_json::to_value(l)?));
        }
        if let Some(m) = self.masks {
            keywords.push(("masks", serde_json::to_value(m)?));
        }
        let mut s = Settings::default().with_keywords(Method::Nis, keywords)?;
        if let Some(patch) = &self.nis_config {
            let patch: serde_json::Value = serde_json::from_str(patch)
                .map_err(|e| format!("--nis-config is not JSON: {e}"))?;
            s.nis = s
                .nis
                .patched(patch)
                .map_err(|e| format!("--nis-config: {e}"))?;
        }
        Ok(s)
    }
}

impl IntegrateArgs {
    /// The precision target of --rel-err/--abs-err with its limits, `None` for a budget
    /// (--evals); an error for limits without a target.
    pub fn target(&self) -> Result<Option<Target>, Error> {
        Ok(Target::from_options(
            self.rel_err,
            self.abs_err,
            self.max_evals,
            self.seconds,
        )?)
    }
}

/// A progress observer that moves `pb`.
fn shows_on(pb: &ProgressBar) -> impl FnMut(u64, u64, &str) + Send + 'static {
    let pb = pb.clone();
    move |done: u64, total: u64, msg: &str| {
        pb.set_length(total.max(1));
        pb.set_position(done);
        pb.set_message(msg.to_string());
    }
}

fn bar(label: &str) -> ProgressBar {
    ProgressBar::new(1)
        .with_style(
            ProgressStyle::with_template("{prefix:>8} {bar:40} {percent:>3}% {msg}")
                .expect("valid template"),
        )
        .with_prefix(label.to_string())
}

/// What one method gave: the result and, for NIS on several ranks, every rank's checksum of its
/// flow's parameters (in rank order; all equal when the ranks trained in step).
pub struct MethodRun {
    pub result: IntegrationResult,
    pub rank_checksums: Option<Vec<String>>,
}

/// FNV-1a over the parameters' bits.
fn checksum(params: &[f32]) -> u64 {
    params
        .iter()
        .flat_map(|p| p.to_le_bytes())
        .fold(0xcbf2_9ce4_8422_2325, |h, b| {
            (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3)
        })
}

/// Every rank's checksum of `params`, in rank order (`None` on one process).
fn rank_checksums(comm: &Comm, params: &[f32]) -> Option<Vec<String>> {
    (comm.size() > 1).then(|| {
        let mine = format!("{:016x}", checksum(params)).into_bytes();
        comm.all_gather_bytes(mine)
            .into_iter()
            .map(|b| String::from_utf8_lossy(&b).into_owned())
            .collect()
    })
}

/// Runs one method on a built-in integrand (all ranks of `comm` together; rank 0 shows progress
/// and writes `--save`).
pub fn run_method(
    f: &Builtin,
    method: Method,
    args: &IntegrateArgs,
    comm: &Comm,
) -> Result<MethodRun, Error> {
    let pb = if comm.is_root() {
        bar(method.name())
    } else {
        ProgressBar::hidden()
    };
    let progress = shows_on(&pb);
    args.channel.check()?;
    if let (Some(path), Method::Nis) = (&args.load, method) {
        let mut nis = NisIntegrator::load(path)?;
        if nis.flow().dim() != f.dim {
            return Err(format!(
                "{} holds a {}-dimensional integrator, the integrand has {} dimensions",
                path.display(),
                nis.flow().dim(),
                f.dim
            )
            .into());
        }
        nis.set_comm(comm.clone());
        nis.set_seed(args.seed);
        nis.set_progress(Some(Box::new(progress)));
        let r = nis.estimate(f, args.evals)?;
        pb.finish_and_clear();
        return Ok(MethodRun {
            result: r,
            rank_checksums: None,
        });
    }
    // One road for every method, with or without channels: an `Integrator`. Without --channels
    // or --signs, NIS splits a scalar integrand that changes sign (multichannel::by_default).
    let mut integ = if args.channel.multichannel() {
        args.channel.integrator(f, method, args.settings()?)?
    } else {
        by_default(method, f.dim, &args.settings()?)?
    };
    integ.set_comm(comm.clone());
    integ.set_progress(Some(Box::new(progress)));
    let r = match args.target()? {
        Some(t) => integ.integrate_to(f, &t)?,
        None => integ.integrate(f, args.evals)?,
    };
    let mut sums = None;
    if let Some(nis) = integ.as_nis() {
        sums = rank_checksums(comm, nis.flow().params());
        // Every rank holds the same flow; one file, written by rank 0 (atomically).
        if let (Some(path), true) = (&args.save, comm.is_root()) {
            nis.save(path)?;
        }
    }
    pb.finish_and_clear();
    Ok(MethodRun {
        result: r,
        rank_checksums: sums,
    })
}

/// A table row for one method.
pub fn row(label: &str, r: &IntegrationResult, exact: f64) -> String {
    format!(
        "{label:<8} {:>14.7e} ± {:<10.3e} {:>7.2} {:>12.4e} {:>8.2} {:>6.2} {:>9} {:>7.4} {:>8.2}",
        r.value,
        r.std_err,
        (r.value - exact) / r.std_err,
        r.rel_var_per_eval,
        r.chi2_per_dof,
        r.pareto_k,
        r.n_eval,
        r.unweighting_efficiency,
        r.seconds
    )
}

pub const HEADER: &str = "method            value ± std_err          pull  rel.var/eval  χ²/dof     k̂    n_eval  unw.eff  seconds";

/// How to read the table, printed under it.
pub const LEGEND: &str = "\
pull: (value − exact)/std_err; beyond ±3 the error bar is too small.
rel.var/eval: n·std_err²/value², n the evaluations that make the estimate (not those that only
  trained or adapted the sampler): the sampler's quality, lower is better; the error of n such
  evaluations is |value|·√(rel.var/eval / n).
χ²/dof near 1 and k̂ below 0.5: the error bar can be trusted (a warning says why not where
  χ²/dof exceeds 3 or k̂ exceeds 0.5 by more than its own noise).
unw.eff: mean|w|/max|w|, the share of points kept as unweighted events.
n_eval, seconds: the whole run, training included. NIS pays where the integrand is peaked or
  correlated and a point costs more than the flow's pass (docs/results/integration.md).";

/// `nis integrate`: every rank of `comm` runs it; rank 0 alone prints.
pub fn run(args: &IntegrateArgs, comm: &Comm) -> Result<(), Error> {
    let f = integrands::by_name(&args.name, args.dim)?;
    let root = comm.is_root();
    let methods = match args.method {
        Some(m) => vec![m],
        None => Method::ALL.to_vec(),
    };
    let integrand = format!("{} (d = {})", f.name, f.dim);
    if args.json && args.method.is_some() {
        let run = run_method(&f, methods[0], args, comm)?;
        let r = run.result;
        let mut v = serde_json::to_value(&r)?;
        v["exact"] = serde_json::json!(f.exact);
        v["integrand"] = serde_json::json!(integrand);
        v["warnings"] = serde_json::json!(r.warnings);
        v["convergence"] = serde_json::to_value(r.convergence)?;
        if let Some(sums) = run.rank_checksums {
            v["rank_checksums"] = serde_json::json!(sums);
        }
        if !root {
            return Ok(());
        }
        println!("{}", serde_json::to_string(&v)?);
        for w in &r.warnings {
            eprintln!("warning: {w}");
        }
        return Ok(());
    }
    if !args.json && root {
        println!(
            "{} in {} dimensions: exact {:.7e}{}  ({})",
            f.name,
            f.dim,
            f.exact,
            if f.exact_err > 0.0 {
                format!(" ± {:.1e}", f.exact_err)
            } else {
                String::new()
            },
            f.source
        );
        println!("{HEADER}");
    }
    let mut results = Vec::new();
    for m in methods {
        let r = run_method(&f, m, args, comm)?.result;
        if !args.json && root {
            println!("{}", row(m.label(), &r, f.exact));
            if let Some(stop) = r.stop {
                println!("{:<8} stopped by {}", "", stop.name());
            }
            if let Some(by) = r.answered_by {
                println!(
                    "{:<8} estimated by {}: it met the target first, with no warning",
                    "",
                    by.label()
                );
            }
            for line in channel_lines(&r) {
                println!("{line}");
            }
            for w in &r.warnings {
                eprintln!("warning ({}): {w}", m.label());
            }
        }
        results.push((m, r));
    }
    if !args.json && root {
        println!("{LEGEND}");
    }
    let labelled: Vec<(&str, &IntegrationResult)> =
        results.iter().map(|(m, r)| (m.label(), r)).collect();
    let disagree = disagreements(&labelled, DISAGREEMENT_SIGMAS);
    if !root {
        return Ok(());
    }
    // Each method's own warnings, then the disagreements between methods.
    let warnings: Vec<String> = results
        .iter()
        .flat_map(|(m, r)| {
            r.warnings
                .iter()
                .map(move |w| format!("{}: {w}", m.label()))
        })
        .chain(disagree.iter().cloned())
        .collect();
    if args.json {
        let mut by_method = serde_json::Map::new();
        for (m, r) in &results {
            by_method.insert(m.name().to_string(), serde_json::to_value(r)?);
        }
        let v = serde_json::json!({
            "integrand": integrand,
            "exact": f.exact,
            "results": by_method,
            "warnings": warnings,
        });
        println!("{}", serde_json::to_string(&v)?);
        return Ok(());
    }
    for w in &disagree {
        println!("{w}");
    }
    Ok(())
}

#[derive(clap::Args)]
pub struct EvalArgs {
    /// Built-in integrand (see `nis list`).
    pub name: String,
    /// Dimension (default: the integrand's smallest).
    #[arg(long)]
    pub dim: Option<usize>,
    /// Synthetic cost: iterations of dependent arithmetic added per point (the same code as
    /// `nis bench time-to-precision --cost-us` adds to our integrators).
    #[arg(long, default_value_t = 0)]
    pub spins: u64,
}

/// `nis eval`: reads frames (u64 n, then n·dim f64 points, little-endian) from stdin and answers
/// each with the n values; n = 0 or the end of input stops.
pub fn eval(args: &EvalArgs) -> Result<(), Error> {
    use std::io::{Read, Write};
    let plain = integrands::by_name(&args.name, args.dim)?;
    let dim = plain.dim;
    let f = nis_paper::bench::time_to_precision::cost::SyntheticCost::new(&plain, args.spins);
    let (mut input, mut output) = (std::io::stdin().lock(), std::io::stdout().lock());
    let (mut head, mut bytes, mut x, mut values) = ([0u8; 8], Vec::new(), Vec::new(), Vec::new());
    loop {
        match input.read_exact(&mut head) {
            Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => return Ok(()),
            r => r?,
        }
        let n = u64::from_le_bytes(head) as usize;
        if n == 0 {
            return Ok(());
        }
        bytes.resize(n * dim * 8, 0);
        input.read_exact(&mut bytes)?;
        x.clear();
        x.extend(
            bytes
                .chunks_exact(8)
                .map(|b| f64::from_le_bytes(b.try_into().expect("8 bytes"))),
        );
        values.resize(n, 0.0);
        nis::integrate::Integrand::eval_batch(&f, &x, dim, &mut values)?;
        bytes.clear();
        bytes.extend(values.iter().flat_map(|v: &f64| v.to_le_bytes()));
        output.write_all(&bytes)?;
        output.flush()?;
    }
}

/// `nis list`.
pub fn list() {
    println!("{:<14} {:<14} description", "name", "dimensions");
    let multi = integrands::MULTI_CHANNEL;
    for e in SUITE.iter().chain([&integrands::COSTLY]).chain(multi) {
        let dims: Vec<String> = e.dims.iter().map(|d| d.to_string()).collect();
        println!("{:<14} {:<14} {}", e.name, dims.join(","), e.description);
    }
}

#[derive(clap::Args)]
pub struct SampleArgs {
    /// Built-in integrand (see `nis list`).
    pub name: String,
    /// Dimension (default: the integrand's smallest).
    #[arg(long)]
    pub dim: Option<usize>,
    /// Number of unweighted points.
    #[arg(long, default_value_t = 100_000)]
    pub n: usize,
    /// Output: `.csv` (text) or anything else for the binary format (see the docs of
    /// `nis::integrate::unweight::Unweighted::to_binary`).
    #[arg(long)]
    pub out: PathBuf,
    /// Training evaluations (ignored with --load).
    #[arg(long, default_value_t = 400_000)]
    pub evals: u64,
    /// Use a trained integrator saved by `nis integrate --save`.
    #[arg(long)]
    pub load: Option<PathBuf>,
    /// Tolerated share of the weight mass above the robust maximum weight.
    #[arg(long, default_value_t = 1e-3)]
    pub overweight: f64,
    /// Random seed.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Through the example's channels (the multi-channel examples of `nis list`): a flow per
    /// channel and sign, integrated on --evals, then events that carry their channel (a column
    /// `channel`; binary files `NISSMPL2`).
    #[arg(long, conflicts_with = "load")]
    pub channels: bool,
}

/// `nis sample`: trains (or loads) a NIS integrator and writes unweighted points.
pub fn sample(args: &SampleArgs) -> Result<(), Error> {
    if args.channels {
        let f = integrands::by_name(&args.name, args.dim)?;
        let request = EventsRequest {
            seed: args.seed,
            evals: args.evals,
            n: args.n,
            overweight: args.overweight,
            out: &args.out,
        };
        return sample_events(&f, &request);
    }
    let f = integrands::by_name(&args.name, args.dim)?;
    let pb = bar("sample");
    let progress = shows_on(&pb);
    let mut nis = match &args.load {
        Some(path) => {
            let mut nis = NisIntegrator::load(path)?;
            nis.set_seed(args.seed);
            nis
        }
        None => NisIntegrator::new(
            f.dim,
            NisConfig {
                seed: args.seed,
                ..NisConfig::default()
            },
        )?,
    };
    nis.set_progress(Some(Box::new(progress)));
    if args.load.is_none() {
        nis.train(&f, args.evals)?;
    }
    // Streamed to the file as accepted: memory does not grow with --n.
    let mut out = SampleWriter::create(
        &args.out,
        SampleFormat::for_path(&args.out),
        f.dim,
        args.n as u64,
    )?;
    let mut over = 0usize;
    let u = nis.unweighted_each(&f, args.n, args.overweight, &mut |p, w| {
        over += usize::from(w.abs() > 1.0);
        out.push(p, w)
    })?;
    out.finish()?;
    pb.finish_and_clear();
    println!(
        "{} unweighted points of {} (d = {}) written to {}: efficiency {:.4}, robust maximum \
         weight {:.4e}, {} points carry a residual weight > 1 ({:.2e} of the weight mass)",
        args.n,
        f.name,
        f.dim,
        args.out.display(),
        u.efficiency,
        u.w_max,
        over,
        u.overweight
    );
    Ok(())
}
