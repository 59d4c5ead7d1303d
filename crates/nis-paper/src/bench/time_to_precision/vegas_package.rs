//! The Python `vegas` package as a contender: `scripts/bench/ttp-vegas.py` in the venv
//! `scripts/setup/vegas-venv.sh` makes, asked for one run at a time over a pipe, so the measurement rule
//! stays in [`super::ladder`] for every method. It integrates the integrand `nis eval` serves
//! (with the same synthetic cost as ours).

use std::io::{BufRead, BufReader, Write};
use std::path::{Path, PathBuf};
use std::process::{Child, ChildStdin, ChildStdout, Command, Stdio};

use serde::Deserialize;

use super::ladder::Run;
use crate::error::{Error, Result};

const SCRIPT: &str = "scripts/bench/ttp-vegas.py";
const VENV: &str = "scripts/setup/vegas-venv.sh";

/// What the Python side measured of its integrand through the pipe.
#[derive(Clone, Debug, Deserialize)]
pub struct Calibration {
    /// Wall µs per point of one batch through `nis eval`.
    pub us_per_point: f64,
    /// The `vegas` package's version.
    pub vegas: String,
    /// Python's version.
    pub python: String,
}

#[derive(Deserialize)]
struct Answer {
    evals: u64,
    seconds: f64,
    value: f64,
    std_err: f64,
}

/// A running `scripts/bench/ttp-vegas.py` for one integrand.
pub struct VegasPackage {
    child: Child,
    stdin: Option<ChildStdin>,
    stdout: BufReader<ChildStdout>,
}

fn failed(what: impl std::fmt::Display) -> Error {
    Error::Config(format!("the `vegas` package baseline ({SCRIPT}): {what}"))
}

/// Makes the venv (first use) and returns its python.
pub fn python() -> Result<PathBuf> {
    let out = Command::new("bash")
        .arg(VENV)
        .stderr(Stdio::inherit())
        .output()
        .map_err(|source| Error::Io {
            path: VENV.into(),
            source,
        })?;
    if !out.status.success() {
        return Err(failed(format!("{VENV} failed ({})", out.status)));
    }
    Ok(PathBuf::from(String::from_utf8_lossy(&out.stdout).trim()))
}

impl VegasPackage {
    /// Starts the script with `python`, serving `name` in `dim` dimensions through `cli` (a `nis`
    /// binary) with `spins` of synthetic cost per point.
    pub fn start(python: &Path, cli: &Path, name: &str, dim: usize, spins: u64) -> Result<Self> {
        let mut child = Command::new(python)
            .arg(SCRIPT)
            .arg("--cli")
            .arg(cli)
            .args(["--name", name, "--dim", &dim.to_string()])
            .args(["--spins", &spins.to_string()])
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .map_err(|source| Error::Io {
                path: python.to_path_buf(),
                source,
            })?;
        let stdin = child.stdin.take();
        let stdout = BufReader::new(child.stdout.take().ok_or_else(|| failed("no stdout"))?);
        Ok(VegasPackage {
            child,
            stdin,
            stdout,
        })
    }

    fn ask<T: for<'de> Deserialize<'de>>(&mut self, request: &str) -> Result<T> {
        let stdin = self.stdin.as_mut().ok_or_else(|| failed("closed"))?;
        writeln!(stdin, "{request}")
            .and_then(|()| stdin.flush())
            .map_err(failed)?;
        let mut line = String::new();
        self.stdout.read_line(&mut line).map_err(failed)?;
        if line.is_empty() {
            return Err(failed(format!("exited on {request:?}")));
        }
        serde_json::from_str(&line).map_err(|e| failed(format!("answer {line:?}: {e}")))
    }

    /// Wall µs per point of a batch of `n` points through the pipe, and the versions.
    pub fn calibrate(&mut self, n: usize) -> Result<Calibration> {
        self.ask(&format!("calibrate {n}"))
    }

    /// One fresh run at `evals` evaluations with `seed`.
    pub fn run(&mut self, seed: u64, evals: u64) -> Result<Run> {
        let a: Answer = self.ask(&format!("run {seed} {evals}"))?;
        Ok(Run {
            evals: a.evals,
            seconds: a.seconds,
            value: a.value,
            std_err: a.std_err,
            disowned: false,
        })
    }
}

impl Drop for VegasPackage {
    fn drop(&mut self) {
        // Closing stdin ends the script's loop; it then closes `nis eval`.
        drop(self.stdin.take());
        let _ = self.child.wait();
    }
}
