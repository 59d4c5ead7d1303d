//! Peak memory against the budget (`nis bench memory`): each case is a `nis` command run in a
//! fresh child process, and its peak resident set size is the kernel's own account of it,
//! `ru_maxrss` from `wait4` on that child — no sampling, nothing the child must print, and no
//! mixing with earlier children (unlike `getrusage(RUSAGE_CHILDREN)`, which keeps the maximum
//! over all of them). The claim checked: memory does not grow with the number of evaluations
//! or samples per pixel.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Instant;

use crate::error::{Error, Result};
use crate::report;

/// One measured command: `nis ARGS…`.
#[derive(Clone, Debug)]
pub struct Case {
    /// What is measured, e.g. `NIS camel d4` (cases with the same workload share it).
    pub workload: String,
    /// The budget, e.g. `1e7 evals` or `256 spp`.
    pub budget: String,
    /// The arguments after the program name; `{out}` stands for a scratch directory.
    pub args: Vec<String>,
}

/// Peak memory and time of one case.
#[derive(Clone, Copy, Debug)]
pub struct Measurement {
    /// Peak resident set size of the child, in bytes.
    pub peak_rss: u64,
    /// Wall-clock seconds from spawn to exit.
    pub seconds: f64,
}

fn case(workload: &str, budget: String, args: &str) -> Case {
    Case {
        workload: workload.into(),
        budget,
        args: args.split_whitespace().map(String::from).collect(),
    }
}

/// The cases: NIS on camel d4 at 10⁶, 10⁷ and 10⁸ evaluations; the Cornell box at 256² with
/// path tracing at 64, 256 and 1024 spp and guided by NIS-KL at 16 and 64 spp. `quick` drops
/// the largest budget of each workload.
pub fn cases(quick: bool) -> Vec<Case> {
    let mut v = Vec::new();
    let evals: &[u64] = if quick {
        &[1_000_000, 10_000_000]
    } else {
        &[1_000_000, 10_000_000, 100_000_000]
    };
    for &n in evals {
        v.push(case(
            "NIS camel d4 (`nis integrate camel --dim 4 --method nis`)",
            format!("{:.0e} evals", n as f64),
            &format!("integrate camel --dim 4 --method nis --evals {n} --json"),
        ));
    }
    let pt: &[u32] = if quick { &[64, 256] } else { &[64, 256, 1024] };
    for &spp in pt {
        v.push(case(
            "Cornell box 256², path tracing (`nis render cornell-box --res 256`)",
            format!("{spp} spp"),
            &format!("render cornell-box --res 256 --spp {spp} --out {{out}}/pt-{spp}.exr"),
        ));
    }
    let guided: &[u32] = if quick { &[16] } else { &[16, 64] };
    for &spp in guided {
        v.push(case(
            "Cornell box 256², guided by NIS-KL (`… --guide nis-kl`)",
            format!("{spp} spp"),
            &format!(
                "render cornell-box --res 256 --spp {spp} --guide nis-kl --out {{out}}/kl-{spp}.exr"
            ),
        ));
    }
    v
}

/// Runs `program` with `args` in a child process and measures its peak RSS and wall time. The
/// child's standard error goes to `log`, whose end the error quotes if the child fails.
///
/// On Linux the figure is at least the calling process's own peak RSS: `exec` folds the peak of
/// the memory the child had before it into the child's, and a child spawned with `vfork` (as std
/// does) had the caller's. Measure from a small process, as `nis bench memory` is (a few MiB).
pub fn measure(program: &Path, args: &[String], log: &Path) -> Result<Measurement> {
    let io = |source| Error::Io {
        path: log.to_path_buf(),
        source,
    };
    let stderr = std::fs::File::create(log).map_err(io)?;
    let started = Instant::now();
    let child = Command::new(program)
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(stderr)
        .spawn()
        .map_err(|source| Error::Io {
            path: program.to_path_buf(),
            source,
        })?;
    let (status, peak_rss) = wait_with_peak_rss(child.id())
        .map_err(|e| Error::Config(format!("waiting for {}: {e}", program.display())))?;
    let seconds = started.elapsed().as_secs_f64();
    if !status.success() {
        let text = std::fs::read_to_string(log).unwrap_or_default();
        let tail: Vec<&str> = text.lines().rev().take(5).collect();
        return Err(Error::Config(format!(
            "`{} {}` failed ({status}): {}",
            program.display(),
            args.join(" "),
            tail.into_iter().rev().collect::<Vec<_>>().join(" / ")
        )));
    }
    Ok(Measurement { peak_rss, seconds })
}

/// Waits for the child `pid` (reaping it) and returns its exit status and peak RSS in bytes.
#[cfg(unix)]
fn wait_with_peak_rss(pid: u32) -> std::io::Result<(std::process::ExitStatus, u64)> {
    use std::os::unix::process::ExitStatusExt;
    let pid = libc::pid_t::try_from(pid).map_err(std::io::Error::other)?;
    let mut status = 0;
    // SAFETY: rusage is plain old data, valid when zeroed; wait4 writes it and the status for
    // our own child, which std's Child handle never waits for afterwards (it is only dropped).
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    loop {
        let r = unsafe { libc::wait4(pid, &mut status, 0, &mut usage) };
        if r == pid {
            break;
        }
        let e = std::io::Error::last_os_error();
        if e.kind() != std::io::ErrorKind::Interrupted {
            return Err(e);
        }
    }
    // Linux reports kibibytes, macOS bytes.
    let unit = if cfg!(target_os = "macos") { 1 } else { 1024 };
    let peak = u64::try_from(usage.ru_maxrss).unwrap_or(0) * unit;
    Ok((std::process::ExitStatus::from_raw(status), peak))
}

#[cfg(not(unix))]
fn wait_with_peak_rss(_pid: u32) -> std::io::Result<(std::process::ExitStatus, u64)> {
    Err(std::io::Error::other(
        "peak RSS of a child needs wait4 (Unix only)",
    ))
}

/// Runs `cases` with `program` (a `nis` binary), one fresh process each, and writes the table
/// to the section `memory` of `docs` when given. `on_case` hears of each case before (`None`)
/// and after it runs. Returns the Markdown.
pub fn run(
    program: &Path,
    cases: &[Case],
    docs: Option<&Path>,
    on_case: &mut dyn FnMut(&Case, Option<&Measurement>),
) -> Result<String> {
    let scratch: PathBuf =
        std::env::temp_dir().join(format!("nis-bench-memory-{}", std::process::id()));
    report::create_dir(&scratch)?;
    let mut rows = Vec::new();
    let result = (|| -> Result<()> {
        for c in cases {
            on_case(c, None);
            let args: Vec<String> = c
                .args
                .iter()
                .map(|a| a.replace("{out}", &scratch.display().to_string()))
                .collect();
            let m = measure(program, &args, &scratch.join("stderr.log"))?;
            on_case(c, Some(&m));
            rows.push((c.clone(), m));
        }
        Ok(())
    })();
    let _ = std::fs::remove_dir_all(&scratch);
    result?;
    let md = table(&rows);
    if let Some(docs) = docs {
        report::write_section(docs, "memory", "Peak memory against the budget", &md)?;
    }
    Ok(md)
}

/// The Markdown: one row per case, and per workload the ratio of the largest peak to the
/// smallest next to the ratio of the budgets.
pub fn table(rows: &[(Case, Measurement)]) -> String {
    let mib = |b: u64| b as f64 / (1024.0 * 1024.0);
    let mut md = String::from(
        "Each case runs alone in a fresh `nis` process; peak RSS is the kernel's `ru_maxrss` of \
         that process (`wait4`), wall time from spawn to exit; on Linux it includes the peak of \
         the small spawning process (a few MiB), which a child shares until it runs `nis`. Run \
         with `nis bench memory` (`--quick` drops the largest budgets, `--only TEXT` keeps matching cases). \
         Wall times are upper bounds where other processes share the machine; the memory \
         figures do not depend on that.\n\n\
         | workload | budget | peak RSS (MiB) | wall (s) |\n|---|---|---:|---:|\n",
    );
    for (c, m) in rows {
        md.push_str(&format!(
            "| {} | {} | {:.1} | {:.1} |\n",
            c.workload,
            c.budget,
            mib(m.peak_rss),
            m.seconds
        ));
    }
    let mut workloads: Vec<&str> = rows.iter().map(|(c, _)| c.workload.as_str()).collect();
    workloads.dedup();
    md.push('\n');
    for w in workloads {
        let peaks: Vec<u64> = rows
            .iter()
            .filter(|(c, _)| c.workload == w)
            .map(|(_, m)| m.peak_rss)
            .collect();
        if peaks.len() > 1 {
            let (lo, hi) = (
                *peaks.iter().min().expect("non-empty"),
                *peaks.iter().max().expect("non-empty"),
            );
            md.push_str(&format!(
                "- {w}: peak RSS from {:.1} to {:.1} MiB over {} budgets (largest/smallest {:.2}).\n",
                mib(lo),
                mib(hi),
                peaks.len(),
                hi as f64 / lo.max(1) as f64
            ));
        }
    }
    md
}
