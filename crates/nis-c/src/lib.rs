//! # nis-c: the C ABI of `nis`
//!
//! For C, C++ (the header has `extern "C"` guards) and Fortran (through `iso_c_binding`):
//! build with `cargo build --release -p nis-c`, include `crates/nis-c/include/nis.h` (generated
//! from this crate by cbindgen, see `tests/header.rs`) and link `target/release/libnis_c.a` or
//! `libnis_c.so`.
//!
//! An integrator is an opaque `nis_integrator *` made from a JSON config by [`nis_create`] (or
//! loaded by [`nis_load`]) and released by [`nis_free`]. Every other function returns a status:
//! `NIS_OK` (0) or an `NIS_ERR_*` code, with a message from [`nis_last_error_message`]. No Rust
//! panic crosses the boundary. An integrator may be moved between threads but not used by two at
//! once; distinct integrators are independent.
//!
//! ```c
//! static int f(const double *x, size_t n, size_t dim, double *out, void *user) {
//!     for (size_t i = 0; i < n; i++) out[i] = 2.0 * x[i * dim];   /* ∫ = 1 */
//!     return 0;
//! }
//! nis_integrator *integ;
//! nis_result r;
//! if (nis_create("{\"method\": \"nis\", \"dim\": 2, \"seed\": 1}", &integ) != NIS_OK ||
//!     nis_integrate(integ, f, NULL, 100000, &r) != NIS_OK)
//!     fprintf(stderr, "nis: %s\n", nis_last_error_message());
//! printf("%g +- %g\n", r.value, r.std_err);
//! nis_free(integ);
//! ```

#![allow(non_camel_case_types)]

mod callback;
mod config;
mod multichannel;
mod status;
mod target;

use std::ffi::{c_char, c_int, c_void, CStr};
use std::path::PathBuf;

use nis::flow::mixture;
use nis::integrate::multichannel::by_default;
use nis::integrate::nis::NisIntegrator;
use nis::integrate::{Integrand, IntegrationResult, Integrator};
use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;

pub use callback::{nis_integrand_fn, NIS_CONCURRENT_CHUNK};
pub use multichannel::*;
pub use status::*;
pub use target::*;

use callback::Callback;
use config::Config;
use status::{guard, Failure, Outcome};

/// Major version of the library (and of this header).
pub const NIS_VERSION_MAJOR: u32 = 0;
/// Minor version.
pub const NIS_VERSION_MINOR: u32 = 1;
/// Patch version.
pub const NIS_VERSION_PATCH: u32 = 0;
/// The version as a string, "MAJOR.MINOR.PATCH" (in the header as the macro
/// `NIS_VERSION_STRING`, which the header test writes from this constant).
pub const NIS_VERSION_STRING: &str = "0.1.0";

/// The library's version, "MAJOR.MINOR.PATCH" (static; compare it with `NIS_VERSION_STRING` to
/// detect a header that does not match the library linked).
#[no_mangle]
pub extern "C" fn nis_version() -> *const c_char {
    concat!(env!("CARGO_PKG_VERSION"), "\0").as_ptr().cast()
}

/// Salt of the sampling stream (`nis_sample*`), apart from the integrator's own streams.
const SAMPLE_STREAM: u64 = 0x7361_6d70;

/// An integrator (opaque): the method's adapted state, the callback settings and the last result.
pub struct nis_integrator {
    integrator: Box<dyn Integrator>,
    components: usize,
    concurrent_callback: bool,
    /// The stream of `nis_sample` and `nis_sample_weighted`.
    sample_rng: Pcg64Mcg,
    last: Option<IntegrationResult>,
}

/// `integrator` as NIS, for what only NIS does (sample, unweight, save).
fn as_nis(integrator: &mut dyn Integrator) -> Outcome<&mut NisIntegrator> {
    let method = integrator.method();
    integrator.as_nis().ok_or_else(|| {
        Failure::new(
            NIS_ERR_UNSUPPORTED,
            format!("only a NIS integrator samples and saves, this one is {method}"),
        )
    })
}

/// The scalar summary of a result; a vector integrand's components are read with
/// [`nis_result_estimates`].
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct nis_result {
    /// The estimate of the integral (of component 0 for a vector integrand).
    pub value: f64,
    /// Its standard error.
    pub std_err: f64,
    /// χ² per degree of freedom of the final phase's iteration estimates (NaN with one iteration).
    pub chi2_per_dof: f64,
    /// All evaluations of the integrand in this call, training included.
    pub n_eval: u64,
    /// Var(f/q)/F² per evaluation of the estimate: n·std_err²/value², n the evaluations that make
    /// the estimate (not those that only trained or adapted the sampler).
    pub rel_var_per_eval: f64,
    /// Unweighting efficiency mean(|w|)/max(|w|) of the final phase's weights.
    pub unweighting_efficiency: f64,
    /// Wall time of the call in seconds.
    pub seconds: f64,
    /// Components of the integrand (1: scalar).
    pub components: usize,
    /// PSIS's Pareto k̂ of the final phase's weights: above 0.5 by more than its noise (1.645
    /// standard errors of a k̂ fitted to this tail) the error bar cannot be trusted, and the
    /// result warns (NaN when it cannot be fitted).
    pub pareto_k: f64,
    /// Effective sample size (Σ|w|)²/Σw² of the final phase's weights.
    pub ess: f64,
}

impl From<&IntegrationResult> for nis_result {
    fn from(r: &IntegrationResult) -> nis_result {
        nis_result {
            value: r.value,
            std_err: r.std_err,
            chi2_per_dof: r.chi2_per_dof,
            n_eval: r.n_eval,
            rel_var_per_eval: r.rel_var_per_eval,
            unweighting_efficiency: r.unweighting_efficiency,
            seconds: r.seconds,
            components: r.components.as_ref().map_or(1, |c| c.mean.len()),
            pareto_k: r.pareto_k,
            ess: r.ess,
        }
    }
}

/// A NUL-terminated UTF-8 string argument.
unsafe fn text<'a>(s: *const c_char, what: &str) -> Outcome<&'a str> {
    if s.is_null() {
        return Err(Failure::null(what));
    }
    // SAFETY: the caller passes a NUL-terminated string that outlives the call.
    unsafe { CStr::from_ptr(s) }
        .to_str()
        .map_err(|_| Failure::invalid(format!("{what} is not UTF-8")))
}

/// The integrator behind a handle.
unsafe fn handle<'a>(integ: *mut nis_integrator) -> Outcome<&'a mut nis_integrator> {
    // SAFETY: a non-NULL handle comes from nis_create or nis_load and is not freed (caller's
    // contract).
    unsafe { integ.as_mut() }.ok_or_else(|| Failure::null("the integrator"))
}

/// A caller buffer of `len` values.
unsafe fn buffer<'a>(p: *mut f64, len: usize, what: &str) -> Outcome<&'a mut [f64]> {
    if p.is_null() {
        return Err(Failure::null(what));
    }
    // SAFETY: the caller provides `len` writable values at `p`.
    Ok(unsafe { std::slice::from_raw_parts_mut(p, len) })
}

/// `a · b`, or an error when it overflows.
fn product(a: usize, b: usize, what: &str) -> Outcome<usize> {
    a.checked_mul(b)
        .ok_or_else(|| Failure::invalid(format!("{what} overflows")))
}

/// Stores a new handle in `*out`.
unsafe fn hand_out(out: *mut *mut nis_integrator, integ: nis_integrator) {
    // SAFETY: `out` was checked non-NULL and points to a writable pointer (caller's contract).
    unsafe { *out = Box::into_raw(Box::new(integ)) };
}

/// Creates an integrator from a JSON config and stores it in `*out` (NULL on failure). The config:
/// `"method"` (`"nis"`, `"vegas"` or `"uniform"`) and `"dim"` are required; optional are `"seed"`
/// (seeds everything), `"components"` (values per point, default 1), `"concurrent_callback"`
/// (default false: the callback is never called from two threads at once), `"train_on"`
/// (`{"component": j}` or `"sum_abs"`), and each method's settings `"nis"`, `"vegas"`,
/// `"uniform"` (partial objects; missing fields keep their defaults). Unknown fields are errors.
/// As in every front end, NIS splits a scalar integrand whose first points show both signs
/// (signs auto; `nis_result_signs` then reads F⁺ and F⁻); `nis_create_with_channels` with no
/// channels and `signs` `"whole"` keeps it whole.
///
/// # Safety
/// `json` must be a NUL-terminated string; `out` must point to a writable `nis_integrator *`.
#[no_mangle]
pub unsafe extern "C" fn nis_create(json: *const c_char, out: *mut *mut nis_integrator) -> c_int {
    guard(|| {
        if out.is_null() {
            return Err(Failure::null("out"));
        }
        // SAFETY: checked non-NULL above.
        unsafe { *out = std::ptr::null_mut() };
        let json = unsafe { text(json, "the JSON config") }?;
        let config: Config = serde_json::from_str(json)
            .map_err(|e| Failure::new(NIS_ERR_CONFIG, format!("JSON config: {e}")))?;
        if config.components == 0 {
            return Err(Failure::new(
                NIS_ERR_CONFIG,
                "components must be at least 1",
            ));
        }
        let settings = config.settings()?;
        let integrator = by_default(config.method, config.dim, &settings)?;
        let seed = settings.seed_of(config.method);
        let integ = nis_integrator {
            integrator,
            components: config.components,
            concurrent_callback: config.concurrent_callback,
            sample_rng: Pcg64Mcg::seed_from_u64(seed ^ SAMPLE_STREAM),
            last: None,
        };
        unsafe { hand_out(out, integ) };
        Ok(())
    })
}

/// Loads a NIS integrator saved by [`nis_save`] and stores it in `*out` (NULL on failure). It
/// keeps the seed it was trained with (see [`nis_set_seed`]); its callback settings are the
/// defaults (1 component, no concurrent calls).
///
/// # Safety
/// `path` must be a NUL-terminated string; `out` must point to a writable `nis_integrator *`.
#[no_mangle]
pub unsafe extern "C" fn nis_load(path: *const c_char, out: *mut *mut nis_integrator) -> c_int {
    guard(|| {
        if out.is_null() {
            return Err(Failure::null("out"));
        }
        // SAFETY: checked non-NULL above.
        unsafe { *out = std::ptr::null_mut() };
        let path = PathBuf::from(unsafe { text(path, "the path") }?);
        let nis = NisIntegrator::load(&path)?;
        let seed = nis.config().seed;
        let integ = nis_integrator {
            integrator: Box::new(nis),
            components: 1,
            concurrent_callback: false,
            sample_rng: Pcg64Mcg::seed_from_u64(seed ^ SAMPLE_STREAM),
            last: None,
        };
        unsafe { hand_out(out, integ) };
        Ok(())
    })
}

/// Frees an integrator (NULL is ignored).
///
/// # Safety
/// `integ` must come from [`nis_create`] or [`nis_load`] and not have been freed.
#[no_mangle]
pub unsafe extern "C" fn nis_free(integ: *mut nis_integrator) {
    if integ.is_null() {
        return;
    }
    // Dropping runs only Rust destructors; a panic there must not cross into C either.
    let _ = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        // SAFETY: the handle came from Box::into_raw (caller's contract).
        drop(unsafe { Box::from_raw(integ) });
    }));
}

/// The dimension of an integrator (0 for NULL).
///
/// # Safety
/// `integ` must be NULL or a live integrator.
#[no_mangle]
pub unsafe extern "C" fn nis_dim(integ: *const nis_integrator) -> usize {
    // SAFETY: NULL or live (caller's contract).
    unsafe { integ.as_ref() }.map_or(0, |i| i.integrator.dim())
}

/// Restarts the random streams of a NIS integrator from `seed` (its flow is kept), e.g. to
/// estimate with a loaded integrator under another seed; other methods: `NIS_ERR_UNSUPPORTED`.
///
/// # Safety
/// `integ` must be a live integrator.
#[no_mangle]
pub unsafe extern "C" fn nis_set_seed(integ: *mut nis_integrator, seed: u64) -> c_int {
    guard(|| {
        let integ = unsafe { handle(integ) }?;
        as_nis(integ.integrator.as_mut())?.set_seed(seed);
        integ.sample_rng = Pcg64Mcg::seed_from_u64(seed ^ SAMPLE_STREAM);
        Ok(())
    })
}

/// Integrates `f` with `evals` evaluations: adapts on a share of them (continuing from earlier
/// calls), estimates with the rest, and writes the summary into `*result` (which may be NULL; the
/// result is also kept for [`nis_result_estimates`]). The callback writes the config's
/// `"components"` values per point.
///
/// # Safety
/// `integ` must be a live integrator; `result` NULL or writable; `f` must honour
/// [`nis_integrand_fn`]'s contract with `user`.
#[no_mangle]
pub unsafe extern "C" fn nis_integrate(
    integ: *mut nis_integrator,
    f: nis_integrand_fn,
    user: *mut c_void,
    evals: u64,
    result: *mut nis_result,
) -> c_int {
    // SAFETY: forwarded under the same contract.
    unsafe { integrate(integ, f, user, None, evals, result) }
}

/// [`nis_integrate`] for a callback that writes `components` values per point (row-major),
/// whatever the config said. Every component is estimated from the same points, with their
/// covariance ([`nis_result_estimates`]); `result->value` is component 0.
///
/// # Safety
/// As [`nis_integrate`].
#[no_mangle]
pub unsafe extern "C" fn nis_integrate_vector(
    integ: *mut nis_integrator,
    f: nis_integrand_fn,
    user: *mut c_void,
    components: usize,
    evals: u64,
    result: *mut nis_result,
) -> c_int {
    // SAFETY: forwarded under the same contract.
    unsafe { integrate(integ, f, user, Some(components), evals, result) }
}

/// Runs `body` with the callback as an integrand, turning a callback failure into its status.
fn with_callback<T>(
    integ: &mut nis_integrator,
    f: nis_integrand_fn,
    user: *mut c_void,
    components: Option<usize>,
    body: impl FnOnce(&mut dyn Integrator, &dyn Integrand) -> nis::Result<T>,
) -> Outcome<T> {
    let f = f.ok_or_else(|| Failure::null("the integrand callback"))?;
    let k = components.unwrap_or(integ.components);
    if k == 0 {
        return Err(Failure::invalid("components must be at least 1"));
    }
    let dim = integ.integrator.dim();
    let callback = Callback::new(f, user, dim, k, integ.concurrent_callback);
    body(integ.integrator.as_mut(), &callback).map_err(|e| callback.failure(e))
}

/// Writes the summary of `r` into `*result` when it is not NULL.
///
/// # Safety
/// `result` must be NULL or writable.
unsafe fn write_result(result: *mut nis_result, r: &IntegrationResult) {
    // SAFETY: NULL or writable (caller's contract).
    if let Some(out) = unsafe { result.as_mut() } {
        *out = nis_result::from(r);
    }
}

unsafe fn integrate(
    integ: *mut nis_integrator,
    f: nis_integrand_fn,
    user: *mut c_void,
    components: Option<usize>,
    evals: u64,
    result: *mut nis_result,
) -> c_int {
    guard(|| {
        let integ = unsafe { handle(integ) }?;
        if evals < 2 {
            return Err(Failure::invalid(format!(
                "evals must be at least 2, got {evals}"
            )));
        }
        let r = with_callback(integ, f, user, components, |m, f| m.integrate(f, evals))?;
        // SAFETY: NULL or writable (caller's contract).
        unsafe { write_result(result, &r) };
        integ.last = Some(r);
        Ok(())
    })
}

/// Copies the last result's per-component estimates: `mean[k]`, `std_err[k]` and the row-major
/// `k × k` covariance `cov[k * k]` (`cov[i * k + j]` = Cov(mean_i, mean_j)). Any of the three may
/// be NULL to skip it; `k` must equal the result's `components`. A scalar result has k = 1.
///
/// # Safety
/// `integ` must be a live integrator; non-NULL buffers must hold `k` (`k * k` for `cov`) values.
#[no_mangle]
pub unsafe extern "C" fn nis_result_estimates(
    integ: *const nis_integrator,
    mean: *mut f64,
    std_err: *mut f64,
    cov: *mut f64,
    k: usize,
) -> c_int {
    guard(|| {
        // SAFETY: NULL or live (caller's contract).
        let integ = unsafe { integ.as_ref() }.ok_or_else(|| Failure::null("the integrator"))?;
        let r = integ
            .last
            .as_ref()
            .ok_or_else(|| Failure::new(NIS_ERR_NO_RESULT, "no integration has succeeded yet"))?;
        let e = r.estimates();
        if k != e.mean.len() {
            return Err(Failure::invalid(format!(
                "k = {k}, but the result has {} components",
                e.mean.len()
            )));
        }
        for (p, v) in [(mean, &e.mean), (std_err, &e.std_err), (cov, &e.cov)] {
            if !p.is_null() {
                unsafe { buffer(p, v.len(), "") }?.copy_from_slice(v);
            }
        }
        Ok(())
    })
}

/// Draws `n` points of a NIS integrator's frozen sampler (the flow mixed with a share of uniform
/// points, which come last) into `x` (`n × dim`, row-major) with their density q into `pdf`
/// (`n`): a point weighs f(x)/q(x). Continues the integrator's sampling stream.
///
/// # Safety
/// `integ` must be a live integrator; `x` must hold `n * dim` values and `pdf` `n`.
#[no_mangle]
pub unsafe extern "C" fn nis_sample(
    integ: *mut nis_integrator,
    n: usize,
    x: *mut f64,
    pdf: *mut f64,
) -> c_int {
    guard(|| {
        let integ = unsafe { handle(integ) }?;
        if x.is_null() || pdf.is_null() {
            return Err(Failure::null(if x.is_null() { "x" } else { "pdf" }));
        }
        let (xs, log_q) = draw(integ, n)?;
        let len = xs.len();
        unsafe { buffer(x, len, "x") }?.copy_from_slice(&xs);
        let pdf = unsafe { buffer(pdf, n, "pdf") }?;
        for (p, l) in pdf.iter_mut().zip(&log_q) {
            *p = l.exp();
        }
        Ok(())
    })
}

/// `n` points of the sampler and their log-density, for [`nis_sample`] and
/// [`nis_sample_weighted`].
fn draw(integ: &mut nis_integrator, n: usize) -> Outcome<(Vec<f64>, Vec<f64>)> {
    if n == 0 {
        return Err(Failure::invalid("n must be at least 1"));
    }
    let nis = as_nis(integ.integrator.as_mut())?;
    product(n, nis.dim(), "n * dim")?;
    let lambda = nis.config().uniform_fraction;
    let b = mixture::draw(
        nis.flow(),
        lambda,
        n,
        &mut integ.sample_rng,
        mixture::Record::Nothing,
    )?;
    Ok((b.x.iter().map(|&v| v as f64).collect(), b.log_q_mix))
}

/// [`nis_sample`] with the weights f(x)/q(x) of the callback `f` (`components` of the config per
/// point) written into `w` (`n × components`) instead of the density.
///
/// # Safety
/// As [`nis_sample`], with `w` holding `n * components` values, and `f` as in [`nis_integrate`].
#[no_mangle]
pub unsafe extern "C" fn nis_sample_weighted(
    integ: *mut nis_integrator,
    f: nis_integrand_fn,
    user: *mut c_void,
    n: usize,
    x: *mut f64,
    w: *mut f64,
) -> c_int {
    guard(|| {
        let integ = unsafe { handle(integ) }?;
        if f.is_none() {
            return Err(Failure::null("the integrand callback"));
        }
        if x.is_null() || w.is_null() {
            return Err(Failure::null(if x.is_null() { "x" } else { "w" }));
        }
        let (xs, log_q) = draw(integ, n)?;
        let dim = integ.integrator.dim();
        let fx = with_callback(integ, f, user, None, |_, f| {
            nis::integrate::evaluate(f, &xs, dim)
        })?;
        let k = fx.len() / n;
        unsafe { buffer(x, xs.len(), "x") }?.copy_from_slice(&xs);
        let w = unsafe { buffer(w, fx.len(), "w") }?;
        for ((w, v), l) in w.chunks_exact_mut(k).zip(fx.chunks_exact(k)).zip(&log_q) {
            let inv_q = (-l).exp();
            for (w, v) in w.iter_mut().zip(v) {
                *w = v * inv_q;
            }
        }
        Ok(())
    })
}

/// Draws `n` unweighted points (distributed as |f|/∫|f| of the component the flow learned) from a
/// trained NIS integrator by rejection against a robust maximum weight, into `x` (`n × dim`) and
/// `weights` (`n`: ±1, or ±|w|/w_max for the rare overweight points). `overweight` in [0, 0.5) is
/// the tolerated share of weight mass above that maximum (e.g. 1e-3).
///
/// # Safety
/// As [`nis_sample`], with `weights` holding `n` values, and `f` as in [`nis_integrate`].
#[no_mangle]
pub unsafe extern "C" fn nis_unweighted(
    integ: *mut nis_integrator,
    f: nis_integrand_fn,
    user: *mut c_void,
    n: usize,
    overweight: f64,
    x: *mut f64,
    weights: *mut f64,
) -> c_int {
    guard(|| {
        let integ = unsafe { handle(integ) }?;
        if n == 0 {
            return Err(Failure::invalid("n must be at least 1"));
        }
        if !(0.0..0.5).contains(&overweight) {
            return Err(Failure::invalid(format!(
                "overweight must be in [0, 0.5), got {overweight}"
            )));
        }
        let dim = integ.integrator.dim();
        let len = product(n, dim, "n * dim")?;
        as_nis(integ.integrator.as_mut())?;
        if x.is_null() || weights.is_null() {
            return Err(Failure::null(if x.is_null() { "x" } else { "weights" }));
        }
        let u = with_callback(integ, f, user, None, |m, f| match m.as_nis() {
            Some(nis) => nis.unweighted(f, n, overweight),
            None => Err(nis::Error::Config("only a NIS integrator unweights".into())),
        })?;
        unsafe { buffer(x, len, "x") }?.copy_from_slice(&u.points);
        unsafe { buffer(weights, n, "weights") }?.copy_from_slice(&u.weights);
        Ok(())
    })
}

/// Saves a trained NIS integrator (its flow and settings) to `path`, atomically; other methods:
/// `NIS_ERR_UNSUPPORTED`.
///
/// # Safety
/// `integ` must be a live integrator; `path` a NUL-terminated string.
#[no_mangle]
pub unsafe extern "C" fn nis_save(integ: *mut nis_integrator, path: *const c_char) -> c_int {
    guard(|| {
        let integ = unsafe { handle(integ) }?;
        let path = PathBuf::from(unsafe { text(path, "the path") }?);
        as_nis(integ.integrator.as_mut())?.save(&path)?;
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn version_constants_match_the_crate_version() {
        let v = format!("{NIS_VERSION_MAJOR}.{NIS_VERSION_MINOR}.{NIS_VERSION_PATCH}");
        assert_eq!(v, env!("CARGO_PKG_VERSION"));
        assert_eq!(NIS_VERSION_STRING, env!("CARGO_PKG_VERSION"));
        let s = unsafe { CStr::from_ptr(nis_version()) };
        assert_eq!(s.to_str().unwrap(), NIS_VERSION_STRING);
    }
}
