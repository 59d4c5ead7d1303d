//! The two traits every flow speaks, and what passes through them.
//!
//! - [`Density`]: a trainable density on [0, 1]^D — draw points with their log-density, evaluate
//!   the log-density of given points, and, from the tape of either pass, the parameter gradient
//!   of L = −Σ_i w_i ln q(x_i; θ). Every training loss of this crate (KL, χ², NLL; [`crate::loss`])
//!   is such a weighted log-likelihood, so this is all a trainer needs ([`crate::train::descend`]).
//!   Implemented by the coupling flow ([`crate::flow::Flow`]), the multi-scale flow
//!   ([`crate::flow::multiscale::MultiScale`]) and the defensive mixture
//!   ([`crate::flow::mixture::DefensiveMixture`]).
//! - [`Bijection`]: a density that is a bijection of the cube onto a uniform latent, with both
//!   directions and their log-determinants (zuko's `Transform.call_and_ladj`, nflows'
//!   `CompositeTransform`). Implemented by the two flows.
//!
//! Both traits are object safe: a front end can hold a `Box<dyn Bijection>` chosen at run time.

use std::any::Any;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

use rand::RngCore;

use crate::error::{Error, Result};

/// A trainable density on the unit hypercube, optionally conditioned on context features.
///
/// ```
/// use nis::flow::{Density, Flow, FlowConfig};
/// use rand::SeedableRng;
/// let flow = Flow::new(FlowConfig::new(3)).unwrap();
/// let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(1);
/// let s = flow.sample(1000, None, &mut rng).unwrap();
/// // A new flow is the identity: the uniform density, log q = 0.
/// assert!(s.log_q.iter().all(|l| l.abs() < 1e-6));
/// let log_q = flow.log_density(&s.x, None).unwrap();
/// assert!((log_q[0] - s.log_q[0]).abs() < 1e-6);
/// ```
pub trait Density: Send + Sync {
    /// Dimension D.
    fn dim(&self) -> usize;

    /// Number of context features per point (0: unconditional).
    fn context_dim(&self) -> usize {
        0
    }

    /// Draws `n` points with their log-density (`ctx`: `n × context_dim` features, or `None`).
    fn sample(&self, n: usize, ctx: Option<&[f32]>, rng: &mut dyn RngCore) -> Result<Samples>;

    /// Draws `n` points and keeps the tape for [`Density::backward`] (the on-policy training
    /// step, which then needs no second pass).
    fn sample_for_training(
        &self,
        n: usize,
        ctx: Option<&[f32]>,
        rng: &mut dyn RngCore,
    ) -> Result<Samples>;

    /// ln q(x) of each row of `x` (`n × D`, inside [0, 1]).
    fn log_density(&self, x: &[f32], ctx: Option<&[f32]>) -> Result<Vec<f64>>;

    /// ln q(x) with the tape for [`Density::backward`] (training on given points).
    fn log_density_for_training(&self, x: &[f32], ctx: Option<&[f32]>) -> Result<Evaluated>;

    /// All trainable parameters, flat.
    fn params(&self) -> &[f32];

    /// Mutable parameters; invalidates every tape recorded before.
    fn params_mut(&mut self) -> &mut [f32];

    /// Number of trainable parameters.
    fn param_count(&self) -> usize {
        self.params().len()
    }

    /// Gradient of L = −Σ_i w_i ln q(x_i; θ) with respect to all parameters, for the points
    /// whose pass recorded `tape`, with the points held fixed (the score-function gradients of
    /// the KL, χ² and NLL losses). Deterministic: the same for any thread count.
    fn backward(&self, tape: &Tape, weights: &[f32]) -> Result<Vec<f32>>;
}

/// A density that is a bijection h of [0, 1]^D onto a uniform latent: q(x) = |det ∂h/∂x|.
///
/// ```
/// use nis::flow::{Bijection, Flow, FlowConfig};
/// let flow = Flow::new(FlowConfig::new(2)).unwrap();
/// let (z, log_det) = flow.forward(&[0.25, 0.5], None).unwrap();
/// let (x, log_det_inv) = flow.inverse(&z, None).unwrap();
/// assert!((x[0] - 0.25).abs() < 1e-6 && (log_det[0] + log_det_inv[0]).abs() < 1e-9);
/// ```
pub trait Bijection: Density {
    /// Data to latent: z = h(x) and ln|det ∂z/∂x| = ln q(x).
    fn forward(&self, x: &[f32], ctx: Option<&[f32]>) -> Result<(Vec<f32>, Vec<f64>)>;

    /// Latent to data: x = h⁻¹(z) and ln|det ∂x/∂z| = −ln q(x).
    fn inverse(&self, z: &[f32], ctx: Option<&[f32]>) -> Result<(Vec<f32>, Vec<f64>)>;
}

/// Points drawn from a density with their log-density, and optionally the tape of the pass that
/// made them (for the on-policy training step, which then needs no second network pass).
#[derive(Clone, Debug)]
pub struct Samples {
    /// Row-major points, `n × D`.
    pub x: Vec<f32>,
    /// ln q(x) of each point.
    pub log_q: Vec<f64>,
    pub tape: Option<Tape>,
}

impl Samples {
    /// Number of points.
    pub fn len(&self) -> usize {
        self.log_q.len()
    }

    /// Whether there are no points.
    pub fn is_empty(&self) -> bool {
        self.log_q.is_empty()
    }
}

/// Log-densities of given points, with the tape of the pass.
#[derive(Clone, Debug)]
pub struct Evaluated {
    pub log_q: Vec<f64>,
    pub tape: Tape,
}

/// What a pass recorded for a later [`Density::backward`]: opaque to callers, stamped with the
/// parameter version it was recorded at, so a tape that outlived a parameter update (or belongs
/// to another density) is an error rather than a wrong gradient.
#[derive(Clone)]
pub struct Tape {
    version: u64,
    rows: usize,
    records: Arc<dyn Any + Send + Sync>,
}

impl std::fmt::Debug for Tape {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Tape")
            .field("version", &self.version)
            .field("rows", &self.rows)
            .finish_non_exhaustive()
    }
}

impl Tape {
    /// A tape of `rows` points recorded at parameter version `version`.
    pub fn new<T: Any + Send + Sync>(version: u64, rows: usize, records: T) -> Tape {
        Tape {
            version,
            rows,
            records: Arc::new(records),
        }
    }

    /// Number of points the pass saw.
    pub fn rows(&self) -> usize {
        self.rows
    }

    /// The records, checked against the density's current parameter `version` and the number of
    /// `weights` a backward pass got.
    pub fn records<T: Any>(&self, version: u64, weights: usize) -> Result<&T> {
        if self.version != version {
            return Err(Error::Config(
                "the tape was recorded before the parameters changed, or by another density".into(),
            ));
        }
        if weights != self.rows {
            return Err(Error::Dimension {
                what: "sample weights",
                expected: self.rows,
                got: weights,
            });
        }
        self.records
            .downcast_ref::<T>()
            .ok_or_else(|| Error::Config("the tape belongs to another kind of density".into()))
    }
}

/// A fresh parameter version, unique in the process: bumped by every `params_mut`, so a tape is
/// accepted only by the density, and the parameters, that recorded it.
pub fn next_version() -> u64 {
    static NEXT: AtomicU64 = AtomicU64::new(1);
    NEXT.fetch_add(1, Ordering::Relaxed)
}

/// The index of the first value of `v` that fails `ok`. The check of every value is a fold
/// without early exit, which vectorises; the index is looked for only when one fails.
fn first_failing(v: &[f32], ok: impl Fn(f32) -> bool) -> Option<usize> {
    if v.iter().fold(true, |all, &x| all & ok(x)) {
        return None;
    }
    v.iter().position(|&x| !ok(x))
}

/// Checks that `x` holds whole rows of `dim` values inside [0, 1] (`what` names the rows in the
/// error); returns the number of rows.
pub fn check_points(x: &[f32], dim: usize, what: &'static str) -> Result<usize> {
    if x.len() % dim != 0 {
        return Err(Error::Dimension {
            what,
            expected: dim * (x.len() / dim + 1),
            got: x.len(),
        });
    }
    if let Some(i) = first_failing(x, |v| (0.0..=1.0).contains(&v)) {
        return Err(Error::OutOfDomain {
            index: i / dim,
            coord: i % dim,
            value: x[i] as f64,
        });
    }
    Ok(x.len() / dim)
}

/// Checks that `ctx` holds `n` finite rows of `cdim` context features (none when `cdim` = 0).
pub fn check_context(n: usize, cdim: usize, ctx: Option<&[f32]>) -> Result<()> {
    let got = ctx.map_or(0, <[f32]>::len);
    if got != n * cdim || (cdim > 0 && ctx.is_none()) {
        return Err(Error::Dimension {
            what: "context features",
            expected: n * cdim,
            got,
        });
    }
    let Some(c) = ctx else { return Ok(()) };
    match first_failing(c, f32::is_finite) {
        Some(i) => Err(Error::NonFinite {
            what: "context feature",
            index: i / cdim,
            value: c[i] as f64,
        }),
        None => Ok(()),
    }
}
