//! Typed errors of the library. Only front ends (the CLI) turn them into messages.

use std::path::PathBuf;

/// Everything that can go wrong in `nis`, as a value.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// A configuration that cannot describe a valid flow or training run.
    #[error("invalid configuration: {0}")]
    Config(String),
    /// Input of the wrong shape.
    #[error("dimension mismatch in {what}: expected {expected}, got {got}")]
    Dimension {
        what: &'static str,
        expected: usize,
        got: usize,
    },
    /// A point outside the unit hypercube, or not a number.
    #[error("point {index}, coordinate {coord} is {value}, outside [0, 1]")]
    OutOfDomain {
        index: usize,
        coord: usize,
        value: f64,
    },
    /// A NaN or infinite value where a finite one is required.
    #[error("non-finite {what} at sample {index}: {value}")]
    NonFinite {
        what: &'static str,
        index: usize,
        value: f64,
    },
    /// The integrand returned NaN or ±∞.
    #[error("the integrand returned {value} at the point {point:?}")]
    Integrand { point: Vec<f64>, value: f64 },
    /// The integrand reported a failure of its own; the run stopped at that batch.
    #[error("the integrand failed: {message}")]
    IntegrandFailed {
        /// The integrand's own account of what went wrong.
        message: String,
    },
    /// A channel of a multi-channel integration (`nis::channels`) sampled a point outside the
    /// unit cube, or gave a density that is not finite and positive at a point it sampled.
    #[error("channel {channel} at the point {point:?}: {reason}")]
    Channel {
        /// The channel's index in its set.
        channel: usize,
        /// The point (u or x, as `reason` says) where it went wrong.
        point: Vec<f64>,
        /// What went wrong, with the offending value.
        reason: String,
    },
    /// Another MPI rank failed (its own error is this message); every rank stops at that batch.
    #[error("rank {rank} failed: {message}")]
    Rank {
        /// The lowest rank that failed.
        rank: usize,
        /// Its error, as text.
        message: String,
    },
    /// A model file that cannot be read back as the flow it claims to be.
    #[error("model file {path}: {reason}")]
    Model { path: PathBuf, reason: String },
    /// An operating-system error while reading or writing a file.
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
}

/// Shorthand for results of this crate.
pub type Result<T, E = Error> = std::result::Result<T, E>;
