//! `nis bench flow`, `nis bench integrate`, `nis bench memory`, `nis bench coverage`, `nis
//! bench time-to-precision` and `nis bench reuse`: the drivers are `nis_paper::bench::{flow,
//! integrate, memory, coverage, time_to_precision, reuse}`; results go to stdout and to sections of `docs/results/integration.md`
//! (coverage: `docs/results/robustness.md`). `nis bench mpi` (driver `nis_paper::bench::mpi`) writes a
//! section and the model in `docs/results/scaling.md`.

use std::path::{Path, PathBuf};

use indicatif::{ProgressBar, ProgressStyle};

/// `nis bench flow`: runs and records; with `torch`, also the PyTorch eager baseline of R1.
pub fn run_flow(
    batch: usize,
    torch: bool,
    only: Option<&str>,
    docs: &Path,
) -> Result<(), Box<dyn std::error::Error>> {
    let md = nis_paper::bench::flow::run(batch, torch, only, docs, &mut |row| eprint!("{row}"))?;
    println!("{md}");
    Ok(())
}

/// `nis bench flow --device cuda`: the reference flows on the GPU against the CPU.
#[cfg(feature = "cuda")]
pub fn run_flow_gpu(
    batches: &[usize],
    only: Option<&str>,
) -> Result<(), Box<dyn std::error::Error>> {
    let md = nis_paper::bench::flow_gpu::run(batches, 5, only, &mut |row| eprint!("{row}"))?;
    println!("{md}");
    Ok(())
}

/// Without the `cuda` feature: says how to get it.
#[cfg(not(feature = "cuda"))]
pub fn run_flow_gpu(
    _batches: &[usize],
    _only: Option<&str>,
) -> Result<(), Box<dyn std::error::Error>> {
    Err(
        "this nis was built without the GPU back end: build it with `cargo build --release \
         -p nis-cli --features cuda` (CUDA itself is loaded at run time)"
            .into(),
    )
}

/// `nis bench integrate`: the suite × methods at one budget; Markdown tables.
pub fn run_integrate(
    options: &nis_paper::bench::integrate::Options,
    docs: &Path,
) -> Result<(), Box<dyn std::error::Error>> {
    let md = nis_paper::bench::integrate::run(options, docs, &mut |line| eprintln!("{line}"))?;
    println!("{md}");
    Ok(())
}

/// Arguments of `nis bench coverage`.
#[derive(clap::Args)]
pub struct BenchCoverageArgs {
    /// Every suite integrand in every dimension (hours) instead of the default cells (~30 min).
    #[arg(long)]
    full: bool,
    /// Only this integrand (with --peaked, a multi-channel example's cell through its channels
    /// too).
    #[arg(long)]
    only: Option<String>,
    /// The peaked cells (camel-sharp, gauss-sharp, gauss-diagonal, peaks, ridge in d = 4, 6 and
    /// 8, and the signed pair gauss-pm in d = 2), and resonances-4d, dalitz and gauss-pm through
    /// their channels, instead of the default cells, into a section of their own.
    #[arg(long)]
    peaked: bool,
    /// Seeds per cell instead of each budget's own.
    #[arg(long)]
    seeds: Option<u64>,
    /// Only the small budget (2·10⁴ evaluations × 200 seeds).
    #[arg(long)]
    small_only: bool,
    /// Where finished cells are cached (delete it to start afresh).
    #[arg(long, default_value = "target/coverage-cache")]
    cache: PathBuf,
    /// Markdown file the results go to.
    #[arg(long, default_value = "docs/results/robustness.md")]
    docs: PathBuf,
}

/// `nis bench coverage`: a bar over the cells, a line per finished cell.
pub fn run_coverage(a: &BenchCoverageArgs) -> Result<(), Box<dyn std::error::Error>> {
    let pb = ProgressBar::new(0);
    pb.set_style(
        ProgressStyle::with_template("{bar:30} {pos}/{len} cells  {elapsed_precise}  {msg}")
            .expect("a valid template"),
    );
    let options = nis_paper::bench::coverage::Options {
        full: a.full,
        only: a.only.clone(),
        peaked: a.peaked,
        seeds: a.seeds,
        small_only: a.small_only,
        cache: a.cache.clone(),
        docs: a.docs.clone(),
    };
    let md = nis_paper::bench::coverage::run(&options, &mut |done, total, line| {
        pb.set_length(total as u64);
        pb.set_position(done as u64);
        pb.println(line);
    })?;
    pb.finish_and_clear();
    println!("{md}");
    Ok(())
}

/// Arguments of `nis bench memory`.
#[derive(clap::Args)]
pub struct BenchMemoryArgs {
    /// Drop the largest budget of each workload (10^8 evaluations, 1024 and 256 spp).
    #[arg(long)]
    quick: bool,
    /// Only the cases whose workload or budget contains this text (e.g. "render", "1e7").
    #[arg(long)]
    only: Option<String>,
    /// The `nis` binary to measure (default: this one), e.g. an older build to compare.
    #[arg(long)]
    program: Option<PathBuf>,
    /// Markdown file the results go to (not written with --only or --program).
    #[arg(long, default_value = "docs/results/integration.md")]
    docs: PathBuf,
}

/// `nis bench memory`: peak RSS per case, each in a fresh child process.
pub fn run_memory(args: &BenchMemoryArgs) -> Result<(), Box<dyn std::error::Error>> {
    use nis_paper::bench::memory;
    let program = match &args.program {
        Some(p) => p.clone(),
        None => std::env::current_exe()?,
    };
    let cases: Vec<memory::Case> = memory::cases(args.quick)
        .into_iter()
        .filter(|c| {
            args.only.as_deref().is_none_or(|o| {
                let o = o.to_lowercase();
                c.workload.to_lowercase().contains(&o)
                    || c.budget.to_lowercase().contains(&o)
                    || c.args.join(" ").contains(&o)
            })
        })
        .collect();
    if cases.is_empty() {
        return Err("--only matches no case".into());
    }
    let pb = ProgressBar::new(cases.len() as u64).with_style(
        ProgressStyle::with_template("memory [{elapsed_precise}] {bar:20} {pos}/{len} {msg}")
            .expect("a valid template"),
    );
    pb.enable_steady_tick(std::time::Duration::from_millis(500));
    // A partial run (a subset, another binary) must not replace the recorded table.
    let docs = (args.only.is_none() && args.program.is_none()).then_some(args.docs.as_path());
    let md = memory::run(&program, &cases, docs, &mut |c, m| match m {
        None => pb.set_message(format!("{} {}", c.args[0], c.budget)),
        Some(m) => {
            let line = format!(
                "{:<60} {:>12}  {:>8.1} MiB  {:>7.1} s",
                c.args[..c.args.len().min(6)].join(" "),
                c.budget,
                m.peak_rss as f64 / (1024.0 * 1024.0),
                m.seconds
            );
            if pb.is_hidden() {
                eprintln!("{line}");
            } else {
                pb.println(line);
            }
            pb.inc(1);
        }
    })?;
    pb.finish_and_clear();
    println!("{md}");
    Ok(())
}

/// Arguments of `nis bench time-to-precision`.
#[derive(clap::Args)]
pub struct BenchTimeToPrecisionArgs {
    /// Only these cells, as NAME:D (e.g. camel-sharp:8) or NAME (its default dimensions);
    /// default: camel and camel-sharp d = 4, 8, 16, gauss d = 16, gauss-diagonal, peaks and
    /// ridge d = 4.
    #[arg(long, num_args = 1.., value_delimiter = ',')]
    only: Vec<String>,
    /// Methods, from nis-target and vegas+-target (one run to each target), nis, nis-codes (the
    /// flow of fewer layers), vegas+, mc (ladders of budgets), vegas-py (the Python package).
    #[arg(
        long,
        num_args = 1..,
        value_delimiter = ',',
        default_value = "nis-target,nis,vegas+-target,vegas+,mc,vegas-py"
    )]
    methods: Vec<String>,
    /// Target relative errors.
    #[arg(long, num_args = 1.., value_delimiter = ',', default_value = "1e-3,1e-4")]
    targets: Vec<f64>,
    /// Seeds per (method, integrand): 1..=SEEDS, the median reported.
    #[arg(long, default_value_t = 3)]
    seeds: u64,
    /// Wall-time cap of one ladder (method, integrand, seed), in seconds.
    #[arg(long, default_value_t = 300.0)]
    cap: f64,
    /// Synthetic cost per point in wall µs (calibrated on this machine, the same on both sides).
    #[arg(long, default_value_t = 0.0)]
    cost_us: f64,
    /// Markdown file the results go to (plots in img/ beside it).
    #[arg(long, default_value = "docs/results/integration.md")]
    docs: PathBuf,
    /// Count only answers that carry no warning: a result of ours that warns does not reach a
    /// target however small its error bar (a section of its own in the docs).
    #[arg(long)]
    trusted: bool,
}

/// The cells `--only` names: NAME:D, or NAME in the dimensions of the default cells that have it
/// (else its suite dimensions).
fn ttp_cells(only: &[String]) -> Result<Vec<(String, usize)>, Box<dyn std::error::Error>> {
    use nis_paper::bench::time_to_precision::DEFAULT_CELLS;
    if only.is_empty() {
        return Ok(DEFAULT_CELLS
            .iter()
            .map(|&(n, d)| (n.to_string(), d))
            .collect());
    }
    let mut cells = Vec::new();
    for item in only {
        match item.split_once(':') {
            Some((name, d)) => cells.push((name.to_string(), d.parse()?)),
            None => {
                let defaults: Vec<usize> = DEFAULT_CELLS
                    .iter()
                    .filter(|c| c.0 == item)
                    .map(|c| c.1)
                    .collect();
                let dims = if defaults.is_empty() {
                    nis::integrands::SUITE
                        .iter()
                        .find(|e| e.name == item)
                        .ok_or_else(|| format!("unknown integrand {item:?} (see nis list)"))?
                        .dims
                        .to_vec()
                } else {
                    defaults
                };
                cells.extend(dims.into_iter().map(|d| (item.clone(), d)));
            }
        }
    }
    Ok(cells)
}

/// `nis bench time-to-precision`: a bar over the ladders, a line per finished ladder.
pub fn run_time_to_precision(
    a: &BenchTimeToPrecisionArgs,
) -> Result<(), Box<dyn std::error::Error>> {
    use nis_paper::bench::time_to_precision as ttp;
    let contenders = a
        .methods
        .iter()
        .map(|m| m.parse())
        .collect::<Result<Vec<ttp::Contender>, _>>()?;
    let options = ttp::Options {
        cells: ttp_cells(&a.only)?,
        contenders,
        targets: a.targets.clone(),
        seeds: a.seeds,
        cap: a.cap,
        cost_us: a.cost_us,
        cli: Some(std::env::current_exe()?),
        docs: Some(a.docs.clone()),
        trusted: a.trusted,
    };
    let pb = ProgressBar::new(0);
    pb.set_style(
        ProgressStyle::with_template("{bar:30} {pos}/{len} ladders  {elapsed_precise}  {msg}")
            .expect("a valid template"),
    );
    pb.enable_steady_tick(std::time::Duration::from_millis(500));
    let (_, md) = ttp::run(&options, &mut |p| {
        pb.set_length(p.total as u64);
        pb.set_position(p.done as u64);
        if p.finished {
            // Without a terminal the bar is hidden: keep the lines as a log.
            if pb.is_hidden() {
                eprintln!("{}", p.message);
            } else {
                pb.println(p.message);
            }
        } else {
            pb.set_message(p.message.to_string());
        }
    })?;
    pb.finish_and_clear();
    println!("{md}");
    Ok(())
}

/// `nis bench mpi`: strong scaling over MPI ranks and the scaling model.
pub fn run_mpi(
    nis: &Path,
    example: &Path,
    runs: usize,
    docs: &Path,
    scaling: &Path,
) -> Result<(), Box<dyn std::error::Error>> {
    let programs = nis_paper::bench::mpi::MpiPrograms { nis, example };
    let md = nis_paper::bench::mpi::run(&programs, runs, docs, scaling, &mut |line| {
        eprintln!("{line}")
    })?;
    println!("{md}");
    Ok(())
}

/// Arguments of `nis bench channels`.
#[derive(clap::Args)]
pub struct BenchChannelsArgs {
    /// The multi-channel examples.
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "resonances-4d,phase-space-8d,dalitz"
    )]
    examples: Vec<String>,
    /// Evaluations per run on the examples.
    #[arg(long, default_value_t = 1_000_000)]
    evals: u64,
    /// Evaluations per run of the signed comparison.
    #[arg(long, default_value_t = 2_000_000)]
    signed_evals: u64,
    /// Seeds 1..=SEEDS.
    #[arg(long, default_value_t = 3)]
    seeds: u64,
    /// Markdown file the results go to ("-": none).
    #[arg(long, default_value = "docs/results/integration.md")]
    docs: PathBuf,
}

/// `nis bench channels`: a line per run.
pub fn run_channels(a: &BenchChannelsArgs) -> Result<(), Box<dyn std::error::Error>> {
    let options = nis_paper::bench::channels::Options {
        examples: a.examples.clone(),
        evals: a.evals,
        signed_evals: a.signed_evals,
        seeds: a.seeds,
    };
    let docs = (a.docs.as_os_str() != "-").then_some(a.docs.as_path());
    let md = nis_paper::bench::channels::run(&options, docs, &mut |line| eprintln!("{line}"))?;
    println!("{md}");
    Ok(())
}

/// Arguments of `nis bench reuse`.
#[derive(clap::Args)]
pub struct BenchReuseArgs {
    /// Evaluations of the error-bar comparison (camel d4, d8).
    #[arg(long, default_value_t = 1_000_000)]
    evals: u64,
    /// Seeds of the error-bar comparison.
    #[arg(long, default_value_t = 3)]
    seeds: u64,
    /// Share of the training batches reused in the estimate, compared with none.
    #[arg(long, default_value_t = 0.5)]
    reuse: f64,
    /// Training budgets of the replay comparison.
    #[arg(long, value_delimiter = ',', default_values_t = [100_000u64, 400_000])]
    train_budgets: Vec<u64>,
    /// Markdown file the results go to.
    #[arg(long, default_value = "docs/results/integration.md")]
    docs: PathBuf,
}

/// `nis bench reuse`: a bar over the runs, a line per finished run.
pub fn run_reuse(a: &BenchReuseArgs) -> Result<(), Box<dyn std::error::Error>> {
    let pb = ProgressBar::new(0);
    pb.set_style(
        ProgressStyle::with_template("{bar:30} {pos}/{len} runs  {elapsed_precise}  {msg}")
            .expect("a valid template"),
    );
    pb.enable_steady_tick(std::time::Duration::from_millis(500));
    let options = nis_paper::bench::reuse::Options {
        evals: a.evals,
        seeds: a.seeds,
        reuse: a.reuse,
        train_budgets: a.train_budgets.clone(),
        ..Default::default()
    };
    let md = nis_paper::bench::reuse::run(&options, &a.docs, &mut |done, total, line| {
        pb.set_length(total as u64);
        pb.set_position(done as u64);
        // Without a terminal the bar is hidden: keep the lines as a log.
        if pb.is_hidden() {
            eprintln!("{line}");
        } else {
            pb.println(line);
        }
    })?;
    pb.finish_and_clear();
    println!("{md}");
    Ok(())
}
