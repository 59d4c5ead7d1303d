//! Status codes, the thread-local last error, and the guard every entry point runs in: a Rust
//! panic never unwinds into C (that would be undefined behaviour); it becomes `NIS_ERR_PANIC`.

use std::cell::{Cell, RefCell};
use std::ffi::{c_char, c_int, CString};
use std::panic::{catch_unwind, AssertUnwindSafe};

/// Success.
pub const NIS_OK: c_int = 0;
/// A required pointer argument was NULL.
pub const NIS_ERR_NULL_POINTER: c_int = 1;
/// An argument has a bad value: a size of zero, a size that overflows, a component count that
/// does not match, a string that is not UTF-8.
pub const NIS_ERR_INVALID_ARGUMENT: c_int = 2;
/// The JSON config cannot be parsed (syntax, unknown field, wrong type) or describes invalid
/// settings.
pub const NIS_ERR_CONFIG: c_int = 3;
/// The integrand callback returned non-zero; `nis_last_callback_status()` gives its value.
pub const NIS_ERR_CALLBACK: c_int = 4;
/// The integrand callback wrote NaN or ±infinity; the message names the point.
pub const NIS_ERR_NON_FINITE: c_int = 5;
/// A file could not be read or written, or is not a saved integrator.
pub const NIS_ERR_FILE: c_int = 6;
/// The integrator's method cannot do this (only NIS samples and saves).
pub const NIS_ERR_UNSUPPORTED: c_int = 7;
/// There is no result to read yet: no integration has succeeded on this integrator.
pub const NIS_ERR_NO_RESULT: c_int = 8;
/// An internal error (a Rust panic, caught at the boundary). The integrator may be left in an
/// inconsistent state: free it.
pub const NIS_ERR_PANIC: c_int = 9;

thread_local! {
    static LAST_ERROR: RefCell<CString> = RefCell::new(CString::default());
    static LAST_CALLBACK_STATUS: Cell<c_int> = const { Cell::new(0) };
}

/// A failed call: its status code and message.
#[derive(Debug)]
pub(crate) struct Failure {
    pub code: c_int,
    pub message: String,
}

impl Failure {
    pub(crate) fn new(code: c_int, message: impl Into<String>) -> Failure {
        Failure {
            code,
            message: message.into(),
        }
    }

    pub(crate) fn null(what: &str) -> Failure {
        Failure::new(NIS_ERR_NULL_POINTER, format!("{what} is NULL"))
    }

    pub(crate) fn invalid(message: impl Into<String>) -> Failure {
        Failure::new(NIS_ERR_INVALID_ARGUMENT, message)
    }
}

impl From<nis::Error> for Failure {
    fn from(e: nis::Error) -> Failure {
        use nis::Error as E;
        let code = match &e {
            E::Config(_) | E::Dimension { .. } => NIS_ERR_CONFIG,
            E::Integrand { .. } | E::NonFinite { .. } | E::OutOfDomain { .. } => NIS_ERR_NON_FINITE,
            // Another MPI rank's failure; the C ABI runs on one process, where it cannot occur.
            E::IntegrandFailed { .. } | E::Rank { .. } => NIS_ERR_CALLBACK,
            E::Model { .. } | E::Io { .. } => NIS_ERR_FILE,
            // A channel's map or density broke its contract at a point it names.
            E::Channel { .. } => NIS_ERR_INVALID_ARGUMENT,
        };
        Failure::new(code, e.to_string())
    }
}

pub(crate) type Outcome<T = ()> = Result<T, Failure>;

/// Runs an entry point's body: its failure or panic becomes a status code and the thread's last
/// error message.
pub(crate) fn guard(body: impl FnOnce() -> Outcome) -> c_int {
    match catch_unwind(AssertUnwindSafe(body)) {
        Ok(Ok(())) => NIS_OK,
        Ok(Err(f)) => {
            set_last_error(&f.message);
            f.code
        }
        Err(panic) => {
            let what = panic
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "unknown cause".into());
            set_last_error(&format!("internal error (a panic in nis): {what}"));
            NIS_ERR_PANIC
        }
    }
}

fn set_last_error(message: &str) {
    // Interior NULs cannot be represented in a C string; they cannot come from nis's messages
    // but may from a path the caller gave.
    let c = CString::new(message.replace('\0', "\\0")).unwrap_or_default();
    LAST_ERROR.with(|e| *e.borrow_mut() = c);
}

pub(crate) fn set_last_callback_status(status: c_int) {
    LAST_CALLBACK_STATUS.with(|s| s.set(status));
}

/// The message of the last failed call on this thread ("" before any failure), NUL-terminated.
/// The pointer stays valid until the next failing call on this thread; copy it to keep it.
#[no_mangle]
pub extern "C" fn nis_last_error_message() -> *const c_char {
    LAST_ERROR.with(|e| e.borrow().as_ptr())
}

/// Copies the last error message of this thread into `buffer` (at most `capacity` bytes with the
/// terminating NUL; truncated to fit) and returns the message's full length in bytes without the
/// NUL, so a caller can size its buffer (for Fortran, where a C string pointer is awkward).
/// `buffer` may be NULL when `capacity` is 0.
///
/// # Safety
/// `buffer` must point to `capacity` writable bytes (or be NULL with `capacity` 0).
#[no_mangle]
pub unsafe extern "C" fn nis_last_error_copy(buffer: *mut c_char, capacity: usize) -> usize {
    // SAFETY: forwarded under the same contract.
    LAST_ERROR.with(|e| unsafe { copy_text(e.borrow().as_bytes(), buffer, capacity) })
}

/// Copies `text` into `buffer` (at most `capacity` bytes with the terminating NUL, truncated to
/// fit; nothing when `buffer` is NULL or `capacity` 0) and returns its full length without the
/// NUL.
///
/// # Safety
/// `buffer` must point to `capacity` writable bytes (or be NULL).
pub(crate) unsafe fn copy_text(text: &[u8], buffer: *mut c_char, capacity: usize) -> usize {
    if !buffer.is_null() && capacity > 0 {
        let n = text.len().min(capacity - 1);
        // SAFETY: the caller provides `capacity` writable bytes; n + 1 <= capacity.
        unsafe {
            std::ptr::copy_nonoverlapping(text.as_ptr().cast::<c_char>(), buffer, n);
            *buffer.add(n) = 0;
        }
    }
    text.len()
}

/// The value the integrand callback returned when the last call on this thread failed with
/// `NIS_ERR_CALLBACK` (0 before any such failure).
#[no_mangle]
pub extern "C" fn nis_last_callback_status() -> c_int {
    LAST_CALLBACK_STATUS.with(|s| s.get())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_panic_becomes_a_status_and_a_message() {
        let code = guard(|| panic!("boom"));
        assert_eq!(code, NIS_ERR_PANIC);
        let message = unsafe { std::ffi::CStr::from_ptr(nis_last_error_message()) };
        assert!(message.to_str().unwrap().contains("boom"));
        assert_eq!(guard(|| Ok(())), NIS_OK);
        assert_eq!(guard(|| Err(Failure::null("x"))), NIS_ERR_NULL_POINTER);
    }
}
