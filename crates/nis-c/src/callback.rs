//! The C integrand: a batch callback with a user pointer, seen by the integrators as a fallible
//! [`Integrand`].
//!
//! By default the callback gets each batch whole and is never entered by two threads at once
//! (a lock serialises it), so C code with static state and Fortran with SAVE variables are safe.
//! With `"concurrent_callback": true` a batch is cut into chunks of [`NIS_CONCURRENT_CHUNK`] points
//! evaluated in parallel on the thread pool: faster for a thread-safe callback.

use std::ffi::{c_int, c_void};
use std::sync::atomic::{AtomicI32, Ordering};
use std::sync::Mutex;

use nis::integrate::Integrand;
use rayon::prelude::*;

/// The integrand: writes f at `n` points `x` (row-major, `dim` coordinates each, in [0, 1]) into
/// `out` (row-major, `k` values per point for an integrand with `k` components) and returns 0, or
/// a non-zero status that stops the integration (the call then fails with `NIS_ERR_CALLBACK` and
/// `nis_last_callback_status()` returns the status). `user` is the pointer given with it.
pub type nis_integrand_fn = Option<
    unsafe extern "C" fn(
        x: *const f64,
        n: usize,
        dim: usize,
        out: *mut f64,
        user: *mut c_void,
    ) -> c_int,
>;

/// Points per callback call in concurrent mode.
pub const NIS_CONCURRENT_CHUNK: usize = 1024;

/// A callback with its user pointer, dimension and component count.
pub(crate) struct Callback {
    f: unsafe extern "C" fn(*const f64, usize, usize, *mut f64, *mut c_void) -> c_int,
    user: *mut c_void,
    dim: usize,
    components: usize,
    concurrent: bool,
    lock: Mutex<()>,
    /// The last non-zero status the callback returned (0: none).
    status: AtomicI32,
}

// SAFETY: the user pointer is only handed back to the callback; without `concurrent_callback`
// the lock makes every call exclusive, and with it the caller has declared the callback (and
// what `user` points to) safe to call from several threads at once.
unsafe impl Sync for Callback {}

impl Callback {
    pub(crate) fn new(
        f: unsafe extern "C" fn(*const f64, usize, usize, *mut f64, *mut c_void) -> c_int,
        user: *mut c_void,
        dim: usize,
        components: usize,
        concurrent: bool,
    ) -> Callback {
        Callback {
            f,
            user,
            dim,
            components,
            concurrent,
            lock: Mutex::new(()),
            status: AtomicI32::new(0),
        }
    }

    /// The failure `e` ended a call with: when it is the callback's own, its status is kept for
    /// `nis_last_callback_status`.
    pub(crate) fn failure(&self, e: nis::Error) -> crate::status::Failure {
        if let (nis::Error::IntegrandFailed { .. }, Some(s)) = (&e, self.failed_status()) {
            crate::status::set_last_callback_status(s);
        }
        crate::status::Failure::from(e)
    }

    /// The non-zero status the callback returned, if it did.
    pub(crate) fn failed_status(&self) -> Option<c_int> {
        Some(self.status.load(Ordering::SeqCst)).filter(|s| *s != 0)
    }

    fn call(&self, x: &[f64], dim: usize, out: &mut [f64]) -> nis::Result<()> {
        let n = x.len() / dim;
        // SAFETY: `x` holds n·dim values and `out` n·k, as the callback's contract says.
        let status = unsafe { (self.f)(x.as_ptr(), n, dim, out.as_mut_ptr(), self.user) };
        if status == 0 {
            return Ok(());
        }
        self.status.store(status, Ordering::SeqCst);
        Err(nis::Error::IntegrandFailed {
            message: format!("the callback returned {status}"),
        })
    }
}

impl Integrand for Callback {
    fn eval_batch(&self, x: &[f64], dim: usize, out: &mut [f64]) -> nis::Result<()> {
        if self.concurrent {
            let k = self.components;
            return out
                .par_chunks_mut(NIS_CONCURRENT_CHUNK * k)
                .zip(x.par_chunks(NIS_CONCURRENT_CHUNK * dim))
                .try_for_each(|(out, x)| self.call(x, dim, out));
        }
        // The lock holds no data, so a poisoned one (impossible: C does not panic) is still fine.
        let _exclusive = self.lock.lock().unwrap_or_else(|e| e.into_inner());
        self.call(x, dim, out)
    }

    fn dim(&self) -> Option<usize> {
        Some(self.dim)
    }

    fn components(&self) -> usize {
        self.components
    }
}
