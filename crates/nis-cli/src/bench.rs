//! `nis bench flow` and `nis bench integrate`: the drivers are `nis_paper::bench::flow` and
//! `nis_paper::bench::integrate`; results go to stdout and to sections of `docs/BENCHMARKS.md`.

use std::path::Path;

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
