//! Integrating to a precision target from C: [`nis_integrate_to`], why the run stopped
//! ([`nis_result_stop`]) and the result's warnings ([`nis_result_warnings`]).

use std::ffi::{c_char, c_int, c_void};

use nis::integrate::{Stop, Target};

use super::{handle, nis_integrand_fn, nis_integrator, nis_result, with_callback, write_result};
use crate::status::{copy_text, guard, Failure};

/// The last result was not a run to a target (`nis_integrate`).
pub const NIS_STOP_NONE: c_int = 0;
/// The error bar met the target.
pub const NIS_STOP_TARGET: c_int = 1;
/// `max_evals` ended the run first (a result warning says how far from the target it was).
pub const NIS_STOP_MAX_EVALS: c_int = 2;
/// `max_seconds` ended the run first (a result warning says how far from the target it was).
pub const NIS_STOP_MAX_SECONDS: c_int = 3;

/// The last result's estimate is the integrator's own.
pub const NIS_ANSWERED_BY_OWN: c_int = 0;
/// NIS, integrating to a target, left the estimate to VEGAS+, which met the target first with no
/// warning (the NIS setting `race_vegas`).
pub const NIS_ANSWERED_BY_VEGAS: c_int = 1;

/// Integrates `f` until the standard error is at most max(`abs_err`, `rel_err`·|value|) or a
/// limit is reached, as Cuba's `epsrel`/`epsabs`/`maxeval`: 0 leaves `rel_err` or `abs_err` out
/// (one of them must be given), `max_evals` 0 means 10⁸, `max_seconds` 0 no time limit.
/// [`nis_result_stop`] then says which ended the run; a limit is not an error. Negative or NaN
/// values are `NIS_ERR_INVALID_ARGUMENT`, a `max_evals` below what one estimate of the method
/// needs `NIS_ERR_CONFIG`, both before `f` is called.
///
/// # Safety
/// As `nis_integrate`.
#[no_mangle]
pub unsafe extern "C" fn nis_integrate_to(
    integ: *mut nis_integrator,
    f: nis_integrand_fn,
    user: *mut c_void,
    rel_err: f64,
    abs_err: f64,
    max_evals: u64,
    max_seconds: f64,
    result: *mut nis_result,
) -> c_int {
    guard(|| {
        let integ = unsafe { handle(integ) }?;
        let target = target_of(rel_err, abs_err, max_evals, max_seconds)?;
        integ.integrator.check_target(&target)?;
        let r = with_callback(integ, f, user, None, |m, f| m.integrate_to(f, &target))?;
        // SAFETY: NULL or writable (caller's contract).
        unsafe { write_result(result, &r) };
        integ.last = Some(r);
        Ok(())
    })
}

/// The target C's arguments describe, 0 being "not given" (Cuba's convention); its values
/// checked (a method's own minimum is left to the integrator, a config matter).
pub(crate) fn target_of(
    rel_err: f64,
    abs_err: f64,
    max_evals: u64,
    max_seconds: f64,
) -> Result<Target, Failure> {
    let given = |v: f64| (v != 0.0).then_some(v);
    let target = Target::from_options(
        given(rel_err),
        given(abs_err),
        (max_evals != 0).then_some(max_evals),
        given(max_seconds),
    )
    .map_err(|e| Failure::invalid(e.to_string()))?
    .unwrap_or_default();
    target
        .check("an integrator", 0)
        .map_err(|e| Failure::invalid(e.to_string()))?;
    Ok(target)
}

/// The `NIS_STOP_*` code of a result (`NIS_STOP_NONE` for none or a run on a budget).
pub(crate) fn stop_code(r: Option<&nis::integrate::IntegrationResult>) -> c_int {
    match r.and_then(|r| r.stop) {
        None => NIS_STOP_NONE,
        Some(Stop::Target) => NIS_STOP_TARGET,
        Some(Stop::MaxEvals) => NIS_STOP_MAX_EVALS,
        Some(Stop::MaxSeconds) => NIS_STOP_MAX_SECONDS,
    }
}

/// Why the last result's run stopped: `NIS_STOP_TARGET`, `NIS_STOP_MAX_EVALS`,
/// `NIS_STOP_MAX_SECONDS`, or `NIS_STOP_NONE` for a run on a budget or no result yet.
///
/// # Safety
/// `integ` must be a live integrator or NULL (then `NIS_STOP_NONE`).
#[no_mangle]
pub unsafe extern "C" fn nis_result_stop(integ: *const nis_integrator) -> c_int {
    // SAFETY: NULL or live (caller's contract).
    stop_code(unsafe { integ.as_ref() }.and_then(|i| i.last.as_ref()))
}

/// Whose sampler made the last result's estimate: `NIS_ANSWERED_BY_VEGAS` when NIS, integrating
/// to a target, left it to VEGAS+; `NIS_ANSWERED_BY_OWN` otherwise (and for NULL or no result).
///
/// # Safety
/// `integ` must be a live integrator or NULL.
#[no_mangle]
pub unsafe extern "C" fn nis_result_answered_by(integ: *const nis_integrator) -> c_int {
    // SAFETY: NULL or live (caller's contract).
    let last = unsafe { integ.as_ref() }.and_then(|i| i.last.as_ref());
    match last.and_then(|r| r.answered_by) {
        Some(nis::integrate::Method::Vegas) => NIS_ANSWERED_BY_VEGAS,
        _ => NIS_ANSWERED_BY_OWN,
    }
}

/// Copies the last result's warnings (sentences that say what to do; none: an empty string),
/// one per line, into `buffer` as `nis_last_error_copy` copies a message: at most `capacity`
/// bytes with the terminating NUL, truncated to fit. Returns the text's full length in bytes
/// without the NUL (so a NULL `buffer` with `capacity` 0 asks for the size).
///
/// # Safety
/// `integ` must be a live integrator; `buffer` NULL or writable for `capacity` bytes.
#[no_mangle]
pub unsafe extern "C" fn nis_result_warnings(
    integ: *const nis_integrator,
    buffer: *mut c_char,
    capacity: usize,
) -> usize {
    // SAFETY: NULL or live (caller's contract); the buffer forwarded under the same contract.
    unsafe {
        copy_warnings(
            integ.as_ref().and_then(|i| i.last.as_ref()),
            buffer,
            capacity,
        )
    }
}

/// Copies the warnings of `r` (none: an empty string), one per line, as
/// [`nis_result_warnings`] documents.
///
/// # Safety
/// `buffer` NULL or writable for `capacity` bytes.
pub(crate) unsafe fn copy_warnings(
    r: Option<&nis::integrate::IntegrationResult>,
    buffer: *mut c_char,
    capacity: usize,
) -> usize {
    let text = r.map(|r| r.warnings.join("\n")).unwrap_or_default();
    // SAFETY: forwarded under the caller's contract.
    unsafe { copy_text(text.as_bytes(), buffer, capacity) }
}
