//! `nis bench flow`, `nis bench integrate` and `nis bench mpi`: the drivers are
//! `nis_paper::bench::flow`, `nis_paper::bench::integrate` and `nis_paper::bench::mpi`; results go to stdout and to sections of `docs/BENCHMARKS.md`.

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
