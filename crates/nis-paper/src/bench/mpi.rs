//! `nis bench mpi`: strong scaling of data-parallel NIS over MPI ranks on this machine (1 against
//! 2 ranks, one thread each), for an integrand of ~100 µs per point and a cheap one; the
//! communication of one training step; and the scaling model those numbers give for clusters
//! (`docs/results/scaling.md`). It starts `mpirun` with a `nis` built with the feature `mpi` and the
//! library's `mpi_ranks` example (`scripts/bench/bench-mpi.sh` builds both and runs this).
//!
//! Other processes may share the machine, so every timing is the median of `runs` runs.

use std::path::Path;
use std::process::Command;

use serde_json::Value;

use crate::error::{Error, Result};
use crate::report::write_section;

/// The programs the benchmark starts under `mpirun`.
pub struct MpiPrograms<'a> {
    /// `nis` built with the feature `mpi`.
    pub nis: &'a Path,
    /// The library's `mpi_ranks` example, built with the feature `mpi`.
    pub example: &'a Path,
}

/// Assumed interconnect of a cluster for the model (the measured shared-memory numbers are a
/// floor, not a cluster): latency per message and bandwidth per link.
const LATENCY_S: f64 = 2e-6;
const BANDWIDTH_BYTES_PER_S: f64 = 10e9;
/// The integrand cost the model is asked about.
const MODEL_COST_S: f64 = 1e-3;

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// `mpirun -n ranks program args…` with one thread per rank; its stdout as JSON.
fn mpirun(ranks: usize, program: &Path, args: &[&str]) -> Result<Value> {
    mpirun_threads(ranks, 1, program, args)
}

/// `mpirun -n ranks program args…` with `threads` threads per rank.
fn mpirun_threads(ranks: usize, threads: usize, program: &Path, args: &[&str]) -> Result<Value> {
    let out = Command::new("mpirun")
        .args([
            "--oversubscribe",
            "--bind-to",
            "none",
            "-n",
            &ranks.to_string(),
        ])
        .arg(program)
        .args(args)
        .env("RAYON_NUM_THREADS", threads.to_string())
        .env("OMPI_ALLOW_RUN_AS_ROOT", "1")
        .env("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM", "1")
        .output()
        .map_err(|e| Error::Config(format!("cannot start mpirun: {e}")))?;
    if !out.status.success() {
        return Err(Error::Config(format!(
            "mpirun -n {ranks} {} {args:?} failed: {}",
            program.display(),
            String::from_utf8_lossy(&out.stderr)
        )));
    }
    serde_json::from_slice(&out.stdout)
        .map_err(|e| Error::Config(format!("{} {args:?}: not JSON: {e}", program.display())))
}

/// One integration under `ranks` ranks: (seconds, n_eval).
fn integrate(
    programs: &MpiPrograms,
    ranks: usize,
    name: &str,
    method: &str,
    evals: u64,
) -> Result<(f64, f64)> {
    let evals = evals.to_string();
    let args = [
        "integrate",
        name,
        "--dim",
        "4",
        "--method",
        method,
        "--evals",
        &evals,
        "--json",
        "--seed",
        "1",
    ];
    let v = mpirun(ranks, programs.nis, &args)?;
    let get = |k: &str| {
        v[k].as_f64()
            .ok_or_else(|| Error::Config(format!("no {k} in {v}")))
    };
    Ok((get("seconds")?, get("n_eval")?))
}

/// Runs the measurements `runs` times each, writes the `mpi` section of `docs` and the model's
/// section of `scaling` (docs/results/scaling.md), and returns the Markdown of both.
pub fn run(
    programs: &MpiPrograms,
    runs: usize,
    docs: &Path,
    scaling: &Path,
    log: &mut dyn FnMut(&str),
) -> Result<String> {
    let runs = runs.max(1);
    let load_before = load_average();
    // Cost per point of each integrand alone: plain MC on one rank (its sampling is negligible).
    let mut cost = Vec::new();
    for (name, evals) in [("costly", 20_000u64), ("camel", 4_000_000)] {
        let t: Vec<f64> = (0..runs)
            .map(|_| integrate(programs, 1, name, "uniform", evals).map(|(s, n)| s / n))
            .collect::<Result<_>>()?;
        log(&format!(
            "{name}: {:.2} µs per point",
            median(t.clone()) * 1e6
        ));
        cost.push(median(t));
    }
    let mut table = String::from(
        "| integrand | cost per point | evaluations | 1 rank (s) | 2 ranks (s) | speed-up | efficiency |\n|---|---:|---:|---:|---:|---:|---:|\n",
    );
    let mut flow_per_point = f64::NAN;
    for ((name, evals), t_f) in [("costly", 40_000u64), ("camel", 400_000)]
        .into_iter()
        .zip(&cost)
    {
        let mut by_ranks = Vec::new();
        for ranks in [1, 2] {
            let t: Vec<f64> = (0..runs)
                .map(|_| integrate(programs, ranks, name, "nis", evals).map(|(s, _)| s))
                .collect::<Result<_>>()?;
            log(&format!("nis {name} {ranks} rank(s): {t:.2?} s"));
            by_ranks.push(median(t));
        }
        if name == "camel" {
            // What NIS adds to each evaluation: sampling, training and the estimate's weights.
            flow_per_point = (by_ranks[0] - evals as f64 * t_f) / evals as f64;
        }
        let speedup = by_ranks[0] / by_ranks[1];
        table.push_str(&format!(
            "| {name} (d = 4) | {:.2} µs | {evals} | {:.2} | {:.2} | {speedup:.2} | {:.0} % |\n",
            t_f * 1e6,
            by_ranks[0],
            by_ranks[1],
            50.0 * speedup
        ));
    }
    // The control: does this machine give a second core right now? Plain MC on one process with
    // 1 and with 2 threads (no MPI involved).
    let mut control = Vec::new();
    for threads in [1, 2] {
        let t: Vec<f64> = (0..runs)
            .map(|_| {
                let args = ["integrate", "costly", "--dim", "4", "--method", "uniform"];
                let args = [&args[..], &["--evals", "20000", "--json"]].concat();
                let v = mpirun_threads(1, threads, programs.nis, &args)?;
                v["seconds"]
                    .as_f64()
                    .ok_or_else(|| Error::Config(format!("no seconds in {v}")))
            })
            .collect::<Result<_>>()?;
        control.push(median(t));
    }
    log(&format!(
        "control: plain MC on 1 and 2 threads: {control:.2?} s"
    ));
    table.push_str(&format!(
        "| control: costly, plain MC, one process, 1 vs 2 threads | | 20000 | {:.2} | {:.2} | {:.2} | {:.0} % |\n",
        control[0],
        control[1],
        control[0] / control[1],
        50.0 * control[0] / control[1]
    ));
    let comm: Vec<Value> = (0..runs)
        .map(|_| mpirun(2, programs.example, &["comm-time", "4"]))
        .collect::<Result<_>>()?;
    let field = |k: &str| median(comm.iter().filter_map(|v| v[k].as_f64()).collect());
    let (params, comm_us, adam_us) = (field("params"), field("median_us"), field("adam_us"));
    log(&format!("one step's communication on 2 ranks: {comm_us:.1} µs for {params} parameters, Adam {adam_us:.1} µs"));
    let load = format!(
        "Load average (1 min) of the machine before and after: {load_before} and {} — \
         above 2, other processes competed for the 2 cores. The control row says how much of a second \
         core there was to be had: where two threads of one process are not faster than one, the \
         1-vs-2-rank comparison measures the contention, not the scaling (and waiting ranks, which \
         Open MPI lets spin, take CPU from the computing one: on shared nodes set \
         `OMPI_MCA_mpi_yield_when_idle=1`).",
        load_average()
    );
    let body = format!(
        "Strong scaling of `nis integrate NAME --dim 4 --method nis` (default flow and batch of \
         1024, 40 % training) under `mpirun -n 1` and `-n 2` with `RAYON_NUM_THREADS=1` (one \
         core per rank), median of {runs} runs each (`scripts/bench/bench-mpi.sh`; the machine is \
         shared with other builds, so single runs are noisy). Cost per point: plain MC on one \
         rank.\n\n{table}\nCommunication of one training step on 2 ranks (five one-number \
         reductions and the sum of the gradient of {params} f32 parameters = {} bytes, \
         `mpi_ranks comm-time 4`): median {comm_us:.1} µs; Adam's update, replicated on every \
         rank: {adam_us:.1} µs. What NIS itself costs per evaluation (sampling, training, \
         weights; from the cheap integrand): {:.2} µs. The model for clusters built on these \
         numbers is in the section \"The numbers\" below.\n\n{load}\n",
        4.0 * params,
        flow_per_point * 1e6
    );
    write_section(docs, "mpi", "MPI: strong scaling on this machine", &body)?;
    let model = model(params, comm_us * 1e-6, adam_us * 1e-6, flow_per_point);
    write_section(scaling, "scaling-model", "The numbers", &model)?;
    Ok(format!("{body}\n{model}"))
}

/// The 1-minute load average, as /proc/loadavg has it.
fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .ok()
        .and_then(|s| s.split_whitespace().next().map(str::to_string))
        .unwrap_or_else(|| "unknown".into())
}

/// Communication of one training step on `ranks` ranks of the assumed cluster: five one-number
/// reductions and one sum of `params` f32 values, each a tree of ⌈log₂ P⌉ levels up and a
/// broadcast of as many down.
fn comm_seconds(ranks: f64, params: f64) -> f64 {
    let levels = ranks.log2().ceil().max(0.0);
    let scalar = 2.0 * levels * LATENCY_S;
    let vector = 2.0 * levels * (LATENCY_S + 4.0 * params / BANDWIDTH_BYTES_PER_S);
    5.0 * scalar + vector
}

/// The model's Markdown: efficiency of a training step at 64, 1 000 and 10 000 ranks for a
/// 1 ms/point integrand, and the batch each needs for 80 %.
fn model(params: f64, comm_2: f64, adam: f64, flow_per_point: f64) -> String {
    let per_point = MODEL_COST_S + flow_per_point.max(0.0);
    let mut rows = String::from(
        "| ranks | communication per step | efficiency at batch 1 024 | at batch 65 536 | batch for ≥ 80 % | points per rank then |\n|---:|---:|---:|---:|---:|---:|\n",
    );
    for ranks in [64.0f64, 1_000.0, 10_000.0] {
        let overhead = adam + comm_seconds(ranks, params);
        // The useful work is B/P points per rank, but the step waits for the ranks with ⌈B/P⌉.
        let eff = |batch: f64| {
            let (mean, most) = (batch / ranks, (batch / ranks).ceil());
            if batch < ranks {
                f64::NAN
            } else {
                mean * per_point / (most * per_point + overhead)
            }
        };
        // With m points on every rank: m·t/(m·t + overhead) ≥ 0.8 ⇔ m ≥ 4·overhead/t.
        let need = ranks * (4.0 * overhead / per_point).max(1.0).ceil();
        let pct = |e: f64| {
            if e.is_nan() {
                "— (batch < ranks)".to_string()
            } else {
                format!("{:.1} %", 100.0 * e)
            }
        };
        rows.push_str(&format!(
            "| {ranks} | {:.1} µs | {} | {} | {need} | {} |\n",
            (overhead - adam) * 1e6,
            pct(eff(1024.0)),
            pct(eff(65_536.0)),
            (need / ranks).ceil()
        ));
    }
    format!(
        "Inputs: {params} f32 parameters (the default flow in 4 dimensions: {:.0} bytes summed per \
         step), Adam's replicated update {:.1} µs, NIS's own cost {:.2} µs per point (all measured \
         above), measured communication per step on 2 ranks of this machine {:.1} µs (shared \
         memory); for the cluster an assumed {:.0} µs per message and {:.0} GB/s per link. An \
         integrand of {:.0} ms per point.\n\n{rows}",
        4.0 * params,
        adam * 1e6,
        flow_per_point * 1e6,
        comm_2 * 1e6,
        LATENCY_S * 1e6,
        BANDWIDTH_BYTES_PER_S / 1e9,
        MODEL_COST_S * 1e3,
    )
}
