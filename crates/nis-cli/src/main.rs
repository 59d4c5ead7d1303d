//! `nis`: neural importance sampling from the command line. A thin layer over the `nis` library:
//! it parses arguments, shows progress and prints; all logic lives in the library.

mod bench;
mod channels;
mod density;
mod fit_image;
mod guiding;
mod integrate;
mod render;

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use nis::comm::Comm;

#[derive(Parser)]
#[command(
    name = "nis",
    version,
    about = "Neural importance sampling: Monte Carlo integration with normalizing flows",
    long_about = "Neural importance sampling: Monte Carlo integration whose sampling density is a \
                  normalizing flow learned from the integrand itself.\n\nExample:\n  nis integrate camel --dim 4"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Integrate a built-in integrand with NIS, VEGAS+ and plain Monte Carlo.
    ///
    /// Example: nis integrate camel --dim 4
    Integrate(integrate::IntegrateArgs),
    /// List the built-in integrands.
    List,
    /// Serve values of a built-in integrand over stdin/stdout, for baselines in other languages
    /// (scripts/bench/bench-vegas.sh): frames of a little-endian u64 n and n×dim f64 points in, n f64
    /// values out; n = 0 ends.
    ///
    /// Example: nis eval camel-sharp --dim 8
    Eval(integrate::EvalArgs),
    /// Write unweighted samples of a built-in integrand (CSV or binary).
    ///
    /// Example: nis sample camel --dim 2 --n 10000 --out camel.csv
    Sample(integrate::SampleArgs),
    /// Render a scene with the CPU path tracer.
    ///
    /// Example: nis render cornell-box --spp 64 --out cornell.exr
    Render(render::RenderArgs),
    /// Compare an image with a reference (MAPE, relMSE, error map).
    ///
    /// Example: nis compare cornell.exr reference.exr
    Compare(render::CompareArgs),
    /// Fit a 2-D flow to an image (or a built-in pattern) and plot how close it gets.
    ///
    /// Example: nis fit-image --target rings --coupling pq --layers 2 --out out/rings
    FitImage(fit_image::FitImageArgs),
    /// Density estimation of real images (train, sample, interpolate), as in the paper's Figure 4.
    ///
    /// Example: nis density train --dataset digits --coupling pq --epochs 50 --out out/digits-pq
    #[command(subcommand)]
    Density(density::DensityCommand),
    /// Measure throughput and write it to docs/results/.
    #[command(subcommand)]
    Bench(BenchCommand),
}

#[derive(Subcommand)]
enum BenchCommand {
    /// Samples/s of sampling and of a training step on the reference flows (R1, R2), against
    /// bare gemm. Example: nis bench flow
    Flow {
        /// Batch size.
        #[arg(long, default_value_t = 16384)]
        batch: usize,
        /// Also time the PyTorch eager baseline of R1 (scripts/bench/bench-torch.py; installs torch
        /// into target/torch-venv on first use).
        #[arg(long)]
        torch: bool,
        /// Only the reference flows whose name starts with this (e.g. `R2`), for profiling; the
        /// docs are then left alone.
        #[arg(long)]
        only: Option<String>,
        /// Markdown file the results go to.
        #[arg(long, default_value = "docs/results/integration.md")]
        docs: PathBuf,
        /// `cuda`: sampling, density and a training step of the reference flows on the GPU against
        /// every CPU core (needs a build with `--features cuda` and an NVIDIA driver); prints the
        /// table and writes nothing (`--batch`, `--torch` and `--docs` are the CPU run's).
        #[arg(long, default_value = "cpu", value_parser = ["cpu", "cuda"])]
        device: String,
        /// Batch sizes of the GPU benchmark.
        #[arg(long, value_delimiter = ',', default_value = "65536,1048576")]
        gpu_batches: Vec<usize>,
    },
    /// The built-in suite with plain MC, VEGAS+, NIS-PQ/KL, NIS-PQ/χ², NIS-RQ/KL and NIS-PQ/KL
    /// with i.i.d. latents at one budget, medians over seeds.
    /// Example: nis bench integrate --evals 1000000 --dims 2 --seeds 3
    Integrate {
        /// Evaluations per integrand and method.
        #[arg(long, default_value_t = 1_000_000)]
        evals: u64,
        /// Only these integrands (comma-separated).
        #[arg(long)]
        only: Option<String>,
        /// Only these dimensions (comma-separated; default: all of the suite's).
        #[arg(long, value_delimiter = ',')]
        dims: Vec<usize>,
        /// Seeds per cell, 0..seeds (the table shows medians and every seed's pull).
        #[arg(long, default_value_t = 1)]
        seeds: u64,
        /// Markdown file the results go to.
        #[arg(long, default_value = "docs/results/integration.md")]
        docs: PathBuf,
    },
    /// Are the error bars honest? Suite integrands × NIS-KL, NIS-χ², VEGAS+ and plain MC at
    /// 2·10⁴ evaluations × 200 seeds and 2·10⁵ × 50: coverage, pulls, χ²/dof and the Pareto-k̂
    /// flag, into docs/results/robustness.md (cells cached: an interrupted run resumes).
    /// Example: nis bench coverage --small-only
    Coverage(bench::BenchCoverageArgs),
    /// The paper's Figure 3: affine L=2 and L=16 against PL-32, PQ-32 and RQ-32 with L=2 on
    /// every built-in 2-D target; writes a montage and a table to docs/results/paper.md.
    /// Example: nis bench fit-image --steps 400
    FitImage(fit_image::BenchFitImageArgs),
    /// Path guiding: unidirectional path tracing and every guide against a path-traced
    /// reference at equal samples and equal time; writes montages and a table to
    /// docs/results/guiding.md. Example: nis bench guiding --scene two-rooms-door
    Guiding(guiding::BenchGuidingArgs),
    /// Piecewise-quadratic against affine couplings at the same architecture and training time
    /// on the real digits and MNIST; writes a table and PNGs to docs/results/paper.md.
    /// Example: nis bench density --minutes-digits 2 --minutes-mnist 4
    Density(density::BenchDensityArgs),
    /// Peak memory (RSS) and wall time against the budget, each case in a fresh process: NIS
    /// on camel d4 at 10^6, 10^7, 10^8 evaluations, the Cornell box at 256² with 64, 256, 1024
    /// spp (path tracing) and 16, 64 spp (NIS-KL guiding). The full run takes ~30 minutes on
    /// two cores. Example: nis bench memory --quick
    Memory(bench::BenchMemoryArgs),
    /// Wall time of NIS, our VEGAS+, plain MC and the Python `vegas` package (installed into its
    /// own venv on first use) to reach relative errors 1e-3 and 1e-4 with an honest answer: fresh
    /// runs at budgets doubling from 10⁴, 3 seeds, median, each ladder capped; a table into
    /// docs/results/integration.md and a plot per integrand. The full run takes hours: run it on a quiet
    /// machine. Example: nis bench time-to-precision --only camel-sharp:8 --targets 1e-3 --cap 60 --seeds 1
    TimeToPrecision(bench::BenchTimeToPrecisionArgs),
    /// Every evaluation counts: the NIS error bar of camel d4, d8 at 10⁶ evaluations with the
    /// final phase alone and with the last training batches in the estimate (3 seeds), and the
    /// variance per evaluation after training with and without replaying earlier batches (camel
    /// d4, d8, gauss d8), with the training's wall time; into docs/results/integration.md (~10 minutes on
    /// two cores). Example: nis bench reuse --evals 200000 --seeds 1
    Reuse(bench::BenchReuseArgs),
    /// Multi-channel integration against one channel on the built-in multi-channel examples
    /// (NIS with a flow per channel and with one shared flow, NIS without channels, the classic
    /// estimator with equal fixed weights, VEGAS+ per channel), and a flow per sign against one
    /// on |f|, 3 seeds; into docs/results/integration.md. Example: nis bench channels --evals 200000 --seeds 1
    Channels(bench::BenchChannelsArgs),
    /// Strong scaling over MPI ranks (1 vs 2, one thread each) for a ~100 µs/point and a cheap
    /// integrand, the communication of a training step, and the scaling model in
    /// docs/results/scaling.md. Starts mpirun with binaries built with the feature `mpi`
    /// (scripts/bench/bench-mpi.sh builds them and runs this).
    /// Example: nis bench mpi --mpi-nis target/mpi/nis --mpi-example target/mpi/mpi_ranks
    Mpi {
        /// `nis` built with `--features mpi`.
        #[arg(long)]
        mpi_nis: PathBuf,
        /// The library's `mpi_ranks` example built with `--features mpi`.
        #[arg(long)]
        mpi_example: PathBuf,
        /// Runs per measurement (their median is reported).
        #[arg(long, default_value_t = 3)]
        runs: usize,
        /// Markdown file the measurements go to.
        #[arg(long, default_value = "docs/results/scaling.md")]
        docs: PathBuf,
        /// Markdown file the scaling model goes to.
        #[arg(long, default_value = "docs/results/scaling.md")]
        scaling: PathBuf,
    },
}

/// The processes of this run: MPI's world when built with the feature `mpi` (one rank when
/// started without `mpirun`), else this process alone.
fn comm() -> Result<Comm, nis::Error> {
    #[cfg(feature = "mpi")]
    return nis::comm::mpi::MpiComm::init();
    #[cfg(not(feature = "mpi"))]
    Ok(Comm::default())
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let comm = match comm() {
        Ok(comm) => comm,
        Err(e) => {
            eprintln!("error: {e}");
            return ExitCode::FAILURE;
        }
    };
    let result = match cli.command {
        Command::Integrate(args) => integrate::run(&args, &comm),
        Command::Render(args) => render::run_render(&args, &comm),
        _ if comm.size() > 1 => Err(format!(
            "only `nis integrate` and `nis render` run on several MPI ranks ({} here)",
            comm.size()
        )
        .into()),
        Command::Sample(args) => integrate::sample(&args),
        Command::Eval(args) => integrate::eval(&args),
        Command::List => {
            integrate::list();
            Ok(())
        }
        Command::Compare(args) => render::run_compare(&args),
        Command::Bench(BenchCommand::Flow {
            device,
            gpu_batches,
            only,
            ..
        }) if device == "cuda" => bench::run_flow_gpu(&gpu_batches, only.as_deref()),
        Command::Bench(BenchCommand::Flow {
            batch,
            torch,
            only,
            docs,
            ..
        }) => bench::run_flow(batch, torch, only.as_deref(), &docs),
        Command::Bench(BenchCommand::Integrate {
            evals,
            only,
            dims,
            seeds,
            docs,
        }) => {
            let options = nis_paper::bench::integrate::Options {
                evals,
                only: only.as_deref(),
                dims: &dims,
                seeds,
            };
            bench::run_integrate(&options, &docs)
        }
        Command::Bench(BenchCommand::Coverage(args)) => bench::run_coverage(&args),
        Command::FitImage(args) => fit_image::run(&args),
        Command::Bench(BenchCommand::FitImage(args)) => fit_image::run_bench(&args),
        Command::Bench(BenchCommand::Guiding(args)) => guiding::run_bench(&args),
        Command::Density(cmd) => density::run(&cmd),
        Command::Bench(BenchCommand::Density(args)) => density::run_bench(&args),
        Command::Bench(BenchCommand::Memory(args)) => bench::run_memory(&args),
        Command::Bench(BenchCommand::TimeToPrecision(args)) => bench::run_time_to_precision(&args),
        Command::Bench(BenchCommand::Reuse(args)) => bench::run_reuse(&args),
        Command::Bench(BenchCommand::Channels(args)) => bench::run_channels(&args),
        Command::Bench(BenchCommand::Mpi {
            mpi_nis,
            mpi_example,
            runs,
            docs,
            scaling,
        }) => bench::run_mpi(&mpi_nis, &mpi_example, runs, &docs, &scaling),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) if comm.size() > 1 => {
            // Every rank failed at the same batch (the library's failure flag) or this one alone
            // did; rank 0 says why. Exiting without finalising MPI makes mpirun end the other
            // ranks, should any still wait for this one.
            if comm.is_root() {
                eprintln!("error: {e}");
            }
            std::process::exit(1)
        }
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
