//! One-dimensional monotone transforms of [0, 1] onto itself: the coupling transforms.
//!
//! Each transform is a CDF whose shape is set by a short vector of *unnormalised* parameters that a
//! conditioner network predicts (Müller et al. 2019, "Neural Importance Sampling", Sec. 3; Durkan et
//! al. 2019 for the rational-quadratic spline). All four share one small surface, [`Transform`]:
//! forward (x ↦ y and log dy/dx), inverse (y ↦ x and the same log-derivative), and the reverse-mode
//! gradient of a scalar loss with respect to the input and the unnormalised parameters. The
//! coupling layer knows transforms only through this surface and the [`TransformKind`] enum.
//!
//! Parameters arrive as `f32` (the network's precision). The affine, piecewise-linear and
//! rational-quadratic transforms compute in `f64`, so a round trip loses only what storing y as
//! `f32` loses, and gradient checks can be tight. The piecewise-quadratic transform, the default
//! of the integrator and of the path guide and their hottest code, computes in `f32` (twice the
//! lanes per instruction); its tests check it against an `f64` twin and bound its round trips by
//! the f32 rounding (`quadratic.rs`).

mod affine;
mod batch;
mod linear;
mod quadratic;
mod rational_quadratic;

pub use affine::Affine;
pub use linear::Linear;
pub use quadratic::Quadratic;
pub use rational_quadratic::RationalQuadratic;

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

/// The most bins a spline may have; per-scalar work buffers live on the stack at this size.
pub const MAX_BINS: usize = 256;

/// The surface every coupling transform implements.
///
/// `p` holds the [`Transform::param_count`] unnormalised parameters of one transformed scalar.
pub trait Transform {
    /// Number of unnormalised parameters per transformed dimension.
    fn param_count(&self) -> usize;
    /// y = C(x) and log C'(x), for x in [0, 1].
    fn forward(&self, p: &[f32], x: f64) -> (f64, f64);
    /// x = C⁻¹(y) and log C'(x), for y in [0, 1].
    fn inverse(&self, p: &[f32], y: f64) -> (f64, f64);
    /// The bin edges in x (K + 1 values from 0 to 1; `[0, 1]` for the affine transform).
    fn bin_edges(&self, p: &[f32]) -> Vec<f64>;
    /// Reverse mode at x: given ∂L/∂y and ∂L/∂log C'(x), writes ∂L/∂p into `g_p` (overwriting it)
    /// and returns ∂L/∂x.
    fn backward(&self, p: &[f32], x: f64, g_y: f64, g_log_det: f64, g_p: &mut [f32]) -> f64;

    /// [`Transform::forward`] of `x.len()` scalars at once, their parameters feature-major:
    /// parameter j of scalar i at `p[j·n + i]` with n = `x.len()` (as a conditioner's output
    /// layer writes them, [`crate::kernels::dense::Layout::Features`], so a kernel working across
    /// scalars reads each parameter's values side by side). `x[i]` becomes y_i and ln C'(x_i)
    /// is added to `log_det[i]`. A transform may override it with a kernel that works across
    /// scalars; it must give the same numbers as the per-scalar method (the default, and the
    /// reference the overrides are tested against).
    fn forward_batch(&self, p: &[f32], x: &mut [f64], log_det: &mut [f64]) {
        forward_each(self, p, x, log_det);
    }

    /// [`Transform::inverse`] of `y.len()` scalars at once, laid out as in
    /// [`Transform::forward_batch`]: `y[i]` becomes x_i and ln C'(x_i) is added to `log_det[i]`.
    fn inverse_batch(&self, p: &[f32], y: &mut [f64], log_det: &mut [f64]) {
        inverse_each(self, p, y, log_det);
    }

    /// [`Transform::backward`] of `x.len()` scalars at once, laid out as in
    /// [`Transform::forward_batch`]: `g[i]` holds ∂L/∂y_i on entry and ∂L/∂x_i on exit; ∂L/∂p
    /// is written to `g_p` (overwriting it) in the layout of `p`.
    fn backward_batch(
        &self,
        p: &[f32],
        x: &[f64],
        g: &mut [f64],
        g_log_det: &[f64],
        g_p: &mut [f32],
    ) {
        backward_each(self, p, x, g, g_log_det, g_p);
    }
}

/// [`Transform::forward_batch`] by the per-scalar method: the reference the batched kernels are
/// tested and benchmarked against.
pub fn forward_each<T: Transform + ?Sized>(t: &T, p: &[f32], x: &mut [f64], log_det: &mut [f64]) {
    map_each(t.param_count(), p, x, log_det, |p, x| t.forward(p, x));
}

/// [`Transform::inverse_batch`] by the per-scalar method.
pub fn inverse_each<T: Transform + ?Sized>(t: &T, p: &[f32], y: &mut [f64], log_det: &mut [f64]) {
    map_each(t.param_count(), p, y, log_det, |p, y| t.inverse(p, y));
}

/// Replaces each `v[i]` by the first value of `map(p_i, v[i])` and adds the second to
/// `log_det[i]`, `p_i` being scalar i's `np` parameters gathered from the feature-major `p`.
fn map_each(
    np: usize,
    p: &[f32],
    v: &mut [f64],
    log_det: &mut [f64],
    map: impl Fn(&[f32], f64) -> (f64, f64),
) {
    let n = v.len();
    let mut p_i = vec![0.0f32; np];
    for (i, (v, ld)) in v.iter_mut().zip(log_det.iter_mut()).enumerate() {
        for (j, q) in p_i.iter_mut().enumerate() {
            *q = p[j * n + i];
        }
        let (w, l) = map(&p_i, *v);
        *v = w;
        *ld += l;
    }
}

/// [`Transform::backward_batch`] by the per-scalar method.
pub fn backward_each<T: Transform + ?Sized>(
    t: &T,
    p: &[f32],
    x: &[f64],
    g: &mut [f64],
    g_log_det: &[f64],
    g_p: &mut [f32],
) {
    let (n, np) = (x.len(), t.param_count());
    let (mut p_i, mut g_i) = (vec![0.0f32; np], vec![0.0f32; np]);
    for (i, (&x, g)) in x.iter().zip(g.iter_mut()).enumerate() {
        for (j, q) in p_i.iter_mut().enumerate() {
            *q = p[j * n + i];
        }
        *g = t.backward(&p_i, x, *g, g_log_det[i], &mut g_i);
        for (j, &v) in g_i.iter().enumerate() {
            g_p[j * n + i] = v;
        }
    }
}

/// Whether the environment variable `NIS_SCALAR_SPLINES` is set (to anything): coupling layers
/// then run their transforms through the per-scalar reference ([`forward_each`], …) instead of
/// the batched kernels, so a benchmark can time both in one binary. The numbers are the same.
pub fn scalar_reference() -> bool {
    static SCALAR: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *SCALAR.get_or_init(|| std::env::var_os("NIS_SCALAR_SPLINES").is_some())
}

/// Which coupling transform a flow uses, with its bin count.
///
/// ```
/// use nis::transform::{Transform, TransformKind};
/// let t = TransformKind::Quadratic { bins: 8 };
/// let p = vec![0.0_f32; t.param_count()]; // zero parameters: the identity
/// let (y, log_det) = t.forward(&p, 0.3);
/// // the piecewise-quadratic spline computes in f32: the identity holds to f32 round-off
/// assert!((y - 0.3).abs() < 1e-6 && log_det.abs() < 1e-6);
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum TransformKind {
    /// RealNVP's affine coupling, moved to [0, 1] through logit and sigmoid.
    Affine,
    /// Piecewise-linear CDF (piecewise-constant density), `bins` equal bins.
    Linear { bins: usize },
    /// Piecewise-quadratic CDF (piecewise-linear density), `bins` adaptive bins.
    Quadratic { bins: usize },
    /// Monotone rational-quadratic spline, `bins` adaptive bins.
    RationalQuadratic { bins: usize },
}

impl TransformKind {
    /// Checks the bin count.
    pub fn validate(&self) -> Result<()> {
        match *self {
            TransformKind::Affine => Ok(()),
            TransformKind::Linear { bins }
            | TransformKind::Quadratic { bins }
            | TransformKind::RationalQuadratic { bins } => {
                if bins == 0 || bins > MAX_BINS {
                    Err(Error::Config(format!(
                        "a spline needs between 1 and {MAX_BINS} bins, got {bins}"
                    )))
                } else {
                    Ok(())
                }
            }
        }
    }

    /// A short name for tables: `affine`, `pl32`, `pq32`, `rq8`.
    pub fn label(&self) -> String {
        match *self {
            TransformKind::Affine => "affine".into(),
            TransformKind::Linear { bins } => format!("pl{bins}"),
            TransformKind::Quadratic { bins } => format!("pq{bins}"),
            TransformKind::RationalQuadratic { bins } => format!("rq{bins}"),
        }
    }
}

/// Calls `$body` with `$s` bound to the concrete transform, so hot loops are monomorphised.
macro_rules! with_transform {
    ($t:expr, $s:ident => $body:expr) => {
        match $t {
            $crate::transform::TransformKind::Affine => {
                let $s = $crate::transform::Affine;
                $body
            }
            $crate::transform::TransformKind::Linear { bins } => {
                let $s = $crate::transform::Linear { bins };
                $body
            }
            $crate::transform::TransformKind::Quadratic { bins } => {
                let $s = $crate::transform::Quadratic { bins };
                $body
            }
            $crate::transform::TransformKind::RationalQuadratic { bins } => {
                let $s = $crate::transform::RationalQuadratic { bins };
                $body
            }
        }
    };
}
pub(crate) use with_transform;

impl Transform for TransformKind {
    fn param_count(&self) -> usize {
        with_transform!(*self, s => s.param_count())
    }
    fn forward(&self, p: &[f32], x: f64) -> (f64, f64) {
        with_transform!(*self, s => s.forward(p, x))
    }
    fn inverse(&self, p: &[f32], y: f64) -> (f64, f64) {
        with_transform!(*self, s => s.inverse(p, y))
    }
    fn bin_edges(&self, p: &[f32]) -> Vec<f64> {
        with_transform!(*self, s => s.bin_edges(p))
    }
    fn backward(&self, p: &[f32], x: f64, g_y: f64, g_log_det: f64, g_p: &mut [f32]) -> f64 {
        with_transform!(*self, s => s.backward(p, x, g_y, g_log_det, g_p))
    }
    // The batched methods of the enum honour [`scalar_reference`]: every caller (couplings, the
    // neural guide) gets the per-scalar reference when it is set.
    fn forward_batch(&self, p: &[f32], x: &mut [f64], log_det: &mut [f64]) {
        if scalar_reference() {
            with_transform!(*self, s => forward_each(&s, p, x, log_det))
        } else {
            with_transform!(*self, s => s.forward_batch(p, x, log_det))
        }
    }
    fn inverse_batch(&self, p: &[f32], y: &mut [f64], log_det: &mut [f64]) {
        if scalar_reference() {
            with_transform!(*self, s => inverse_each(&s, p, y, log_det))
        } else {
            with_transform!(*self, s => s.inverse_batch(p, y, log_det))
        }
    }
    fn backward_batch(
        &self,
        p: &[f32],
        x: &[f64],
        g: &mut [f64],
        g_log_det: &[f64],
        g_p: &mut [f32],
    ) {
        if scalar_reference() {
            with_transform!(*self, s => backward_each(&s, p, x, g, g_log_det, g_p))
        } else {
            with_transform!(*self, s => s.backward_batch(p, x, g, g_log_det, g_p))
        }
    }
}

/// The arithmetic a spline's per-scalar code runs in: f64 for all but the piecewise-quadratic
/// spline, f32 for it (the precision of its lanes, so that both give the same bits).
trait Real:
    Copy
    + Default
    + PartialOrd
    + std::ops::Add<Output = Self>
    + std::ops::Sub<Output = Self>
    + std::ops::Mul<Output = Self>
    + std::ops::Div<Output = Self>
    + std::ops::Neg<Output = Self>
    + std::ops::AddAssign
    + std::ops::SubAssign
    + 'static
{
    fn of(v: f64) -> Self;
    fn widen(self) -> f64;
    fn sqrt(self) -> Self;
    fn max(self, other: Self) -> Self;
    fn clamp01(self) -> Self;
    /// e^(l − max l) for each logit into `out`; returns their sum (from −0, in order).
    fn exponentials(logits: &[f32], out: &mut [Self]) -> Self;
    /// This thread's scratch buffer of the type (see [`with_scratch_of`]).
    fn scratch() -> &'static std::thread::LocalKey<std::cell::RefCell<Vec<Self>>>;
}

thread_local! {
    static SCRATCH_F64: std::cell::RefCell<Vec<f64>> = const { std::cell::RefCell::new(Vec::new()) };
    static SCRATCH_F32: std::cell::RefCell<Vec<f32>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// The methods f32 and f64 share, by name.
macro_rules! real_common {
    ($t:ty, $scratch:ident) => {
        #[inline(always)]
        fn of(v: f64) -> $t {
            v as $t
        }
        #[inline(always)]
        fn widen(self) -> f64 {
            self as f64
        }
        #[inline(always)]
        fn sqrt(self) -> $t {
            <$t>::sqrt(self)
        }
        #[inline(always)]
        fn max(self, other: $t) -> $t {
            <$t>::max(self, other)
        }
        #[inline(always)]
        fn clamp01(self) -> $t {
            self.clamp(0.0, 1.0)
        }
        fn scratch() -> &'static std::thread::LocalKey<std::cell::RefCell<Vec<$t>>> {
            &$scratch
        }
    };
}

impl Real for f64 {
    real_common!(f64, SCRATCH_F64);

    /// Through the vectorised f32 kernel ([`crate::kernels::elementwise::exp_shifted`]); its
    /// relative error (< 4e-7) only perturbs which spline the parameters denote, and forward,
    /// inverse and gradient all see the same one. (libm's scalar f64 exp was the integrator's
    /// hot spot; docs/results/integration.md, "Flow throughput against bare gemm and PyTorch",
    /// lists the kernel work.)
    #[inline]
    fn exponentials(logits: &[f32], out: &mut [f64]) -> f64 {
        let max = logits.iter().fold(f32::NEG_INFINITY, |m, &l| m.max(l));
        crate::kernels::elementwise::exp_shifted(logits, max, out)
    }
}

impl Real for f32 {
    real_common!(f32, SCRATCH_F32);

    /// The same f32 exponentials as [`Real::exponentials`] for f64, kept in f32, summed as the
    /// lanes sum them ([`batch::exponentials`]).
    #[inline]
    fn exponentials(logits: &[f32], out: &mut [f32]) -> f32 {
        let max = logits.iter().fold(f32::NEG_INFINITY, |m, &l| m.max(l));
        for (o, &l) in out.iter_mut().zip(logits) {
            *o = crate::kernels::elementwise::exp(l - max);
        }
        out[..logits.len()].iter().fold(-0.0, |s, &o| s + o)
    }
}

/// Softmax with a floor: `out_k = floor/K + (1 − floor)·softmax(logits)_k`, so the entries sum to
/// one and none is below `floor` times their mean. Shifting by the maximum keeps exp finite.
fn softmax_floor<R: Real>(logits: &[f32], floor: R, out: &mut [R]) {
    let k = logits.len();
    let sum = R::exponentials(logits, &mut out[..k]);
    let scale = (R::of(1.0) - floor) / sum;
    let base = floor / R::of(k as f64);
    for o in out[..k].iter_mut() {
        *o = base + scale * *o;
    }
}

/// Reverse mode of [`softmax_floor`]: from ∂L/∂out and out, writes ∂L/∂logits.
fn softmax_floor_backward<R: Real>(out: &[R], g_out: &[R], floor: R, g_logits: &mut [f32]) {
    let k = g_logits.len();
    let base = floor / R::of(k as f64);
    let inv = R::of(1.0) / (R::of(1.0) - floor);
    // softmax σ_k = (out_k − base)/(1 − floor); ∂L/∂logit_j = (1 − floor)·σ_j·(g_j − Σ σ_k g_k).
    let dot = (0..k).fold(R::of(-0.0), |d, i| d + (out[i] - base) * inv * g_out[i]);
    for j in 0..k {
        g_logits[j] = ((out[j] - base) * (g_out[j] - dot)).widen() as f32;
    }
}

/// Runs `f` on a per-thread scratch buffer of `len` values (contents unspecified). Splines need a
/// few arrays of K values per scalar; stack arrays of the maximum size would be zeroed on every
/// call (kilobytes per scalar), and a heap allocation per call is worse. Not re-entrant.
#[inline]
fn with_scratch_of<E: Real, R>(len: usize, f: impl FnOnce(&mut [E]) -> R) -> R {
    E::scratch().with(|s| {
        let mut v = s.borrow_mut();
        if v.len() < len {
            v.resize(len, E::default());
        }
        f(&mut v[..len])
    })
}

/// [`with_scratch_of`] in f64, the working precision of all but the piecewise-quadratic spline.
#[inline]
fn with_scratch<R>(len: usize, f: impl FnOnce(&mut [f64]) -> R) -> R {
    with_scratch_of(len, f)
}

/// Bin edges 0, w₀, w₀ + w₁, …, 1 from bin widths (the last edge exactly 1).
fn edges_from_widths(widths: &[f64]) -> Vec<f64> {
    let mut edges = Vec::with_capacity(widths.len() + 1);
    let mut x = 0.0;
    edges.push(x);
    for w in widths {
        x += w;
        edges.push(x);
    }
    *edges.last_mut().expect("at least one edge") = 1.0;
    edges
}

/// Bin index and relative position of `x` in `K` equal bins; x = 1 lies at the end of the last bin.
fn equal_bin(x: f64, k: usize) -> (usize, f64) {
    let s = x * k as f64;
    let b = (s.floor() as usize).min(k - 1);
    (b, (s - b as f64).clamp(0.0, 1.0))
}

#[cfg(test)]
pub(crate) mod testing;
