//! `nis bench flow`, `nis bench integrate` and `nis bench coverage`: the drivers are
//! `nis_paper::bench::{flow, integrate, coverage}`; results go to stdout and to sections of
//! `docs/BENCHMARKS.md` (coverage: `docs/ROBUSTNESS.md`).

use std::path::{Path, PathBuf};

use indicatif::{ProgressBar, ProgressStyle};

/// `nis bench flow`: runs and records; with `torch`, also the PyTorch eager baseline of R1.
pub fn run_flow(batch: usize, torch: bool, docs: &Path) -> Result<(), Box<dyn std::error::Error>> {
    let md = nis_paper::bench::flow::run(batch, torch, docs, &mut |row| eprint!("{row}"))?;
    println!("{md}");
    Ok(())
}

/// `nis bench integrate`: the suite × methods at one budget; Markdown tables.
pub fn run_integrate(
    evals: u64,
    only: Option<&str>,
    docs: &Path,
) -> Result<(), Box<dyn std::error::Error>> {
    let md = nis_paper::bench::integrate::run(evals, only, docs, &mut |line| eprintln!("{line}"))?;
    println!("{md}");
    Ok(())
}

/// Arguments of `nis bench coverage`.
#[derive(clap::Args)]
pub struct BenchCoverageArgs {
    /// Every suite integrand in every dimension (hours) instead of the default cells (~30 min).
    #[arg(long)]
    full: bool,
    /// Only this integrand.
    #[arg(long)]
    only: Option<String>,
    /// Only the small budget (2·10⁴ evaluations × 200 seeds).
    #[arg(long)]
    small_only: bool,
    /// Where finished cells are cached (delete it to start afresh).
    #[arg(long, default_value = "target/coverage-cache")]
    cache: PathBuf,
    /// Markdown file the results go to.
    #[arg(long, default_value = "docs/ROBUSTNESS.md")]
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
