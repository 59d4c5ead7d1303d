//! A Python function as an integrand, and the runner every long call goes through.
//!
//! The library runs with the GIL released on a worker thread (inside the rayon pool of the
//! integrator's `threads`, if set); the GIL is taken again only to hand f one whole batch as an
//! (n, d) float64 array. Meanwhile the calling thread polls for signals, so Ctrl-C raises
//! KeyboardInterrupt: the poll marks the call cancelled and the run stops before its next batch.
//! An exception raised by f is kept and re-raised unchanged once the library has returned.

use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Mutex};
use std::time::Duration;

use nis::integrate::Integrand;
use numpy::{PyArray1, PyArrayDyn, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::exceptions::{PyRuntimeError, PyValueError};
use pyo3::prelude::*;

use crate::builtin::PyBuiltin;
use crate::shape_str;

/// How often the calling thread looks for pending signals while the library works.
const SIGNAL_POLL: Duration = Duration::from_millis(50);

/// The state one call shares between the library's thread and the Python caller's.
#[derive(Default)]
pub(crate) struct Call {
    cancelled: AtomicBool,
    /// The first Python exception: raised by f, by a check of f's output, or KeyboardInterrupt.
    error: Mutex<Option<PyErr>>,
}

impl Call {
    /// Records `err` (the first one wins) and cancels the call.
    fn fail(&self, err: PyErr) {
        let mut slot = self.error.lock().unwrap_or_else(|p| p.into_inner());
        slot.get_or_insert(err);
        self.cancelled.store(true, Ordering::SeqCst);
    }

    /// Whether the call was cancelled (an exception or Ctrl-C): loops stop at their next step.
    pub(crate) fn cancelled(&self) -> bool {
        self.cancelled.load(Ordering::SeqCst)
    }

    /// The library error that stops a cancelled run (replaced by the recorded exception).
    pub(crate) fn stop() -> nis::Error {
        nis::Error::IntegrandFailed {
            message: "interrupted".into(),
        }
    }

    fn take_error(&self) -> Option<PyErr> {
        self.error.lock().unwrap_or_else(|p| p.into_inner()).take()
    }
}

/// A Python callable f((n, d) float64 array) → (n,) or (n, k) array, as a library integrand.
pub(crate) struct PyIntegrand<'a> {
    f: Py<PyAny>,
    /// k, and whether f returns a 2-D (n, k) array (a vector integrand, also for k = 1).
    components: usize,
    vector: bool,
    call: &'a Call,
}

impl<'a> PyIntegrand<'a> {
    /// Wraps `f` for a `dim`-dimensional run, calling it once on the centre of the cube to learn
    /// the shape of its values (as the `vegas` package does); an exception there propagates.
    pub(crate) fn probe(
        f: &Bound<'_, PyAny>,
        dim: usize,
        call: &'a Call,
    ) -> PyResult<PyIntegrand<'a>> {
        if !f.is_callable() {
            return Err(PyValueError::new_err(format!(
                "the integrand must be callable, got {}",
                f.get_type().name()?
            )));
        }
        let py = f.py();
        let x = PyArray1::from_vec(py, vec![0.5; dim]).reshape([1, dim])?;
        let y = as_f64_array(&f.call1((x,))?)?;
        let (components, vector) = match y.shape() {
            [1] => (1, false),
            [1, k] if *k > 0 => (*k, true),
            s => {
                return Err(PyValueError::new_err(format!(
                    "the integrand must return one value per point, shape (n,), or k values per \
                     point, shape (n, k), for a batch of n points; called on a batch of one \
                     point it returned shape {}",
                    shape_str(s)
                )))
            }
        };
        Ok(PyIntegrand {
            f: f.clone().unbind(),
            components,
            vector,
            call,
        })
    }

    /// Whether f returns (n, k) arrays.
    pub(crate) fn vector(&self) -> bool {
        self.vector
    }

    fn eval_py(&self, py: Python<'_>, x: &[f64], dim: usize, out: &mut [f64]) -> PyResult<()> {
        let n = x.len() / dim;
        let points = PyArray1::from_slice(py, x).reshape([n, dim])?;
        let y = as_f64_array(&self.f.bind(py).call1((points,))?)?;
        let want: Vec<usize> = if self.vector {
            vec![n, self.components]
        } else {
            vec![n]
        };
        if y.shape() != want.as_slice() {
            return Err(PyValueError::new_err(format!(
                "the integrand returned shape {} for {n} points, expected {}",
                shape_str(y.shape()),
                shape_str(&want)
            )));
        }
        let y = y.readonly();
        for (o, v) in out.iter_mut().zip(y.as_array().iter()) {
            *o = *v;
        }
        Ok(())
    }
}

/// f's return value as a float64 numpy array (ints, float32, lists are converted).
fn as_f64_array<'py>(y: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
    let np = y.py().import("numpy")?;
    np.call_method1("asarray", (y, "float64"))
        .map_err(|e| {
            PyValueError::new_err(format!(
                "the integrand must return an array of numbers ({e})"
            ))
        })?
        .cast_into::<PyArrayDyn<f64>>()
        .map_err(|_| PyValueError::new_err("the integrand must return a float64 array"))
}

impl Integrand for PyIntegrand<'_> {
    fn eval_batch(&self, x: &[f64], dim: usize, out: &mut [f64]) -> nis::Result<()> {
        if self.call.cancelled() {
            return Err(Call::stop());
        }
        Python::attach(|py| self.eval_py(py, x, dim, out)).map_err(|e| {
            let message = e.to_string();
            self.call.fail(e);
            nis::Error::IntegrandFailed { message }
        })
    }

    fn components(&self) -> usize {
        self.components
    }
}

/// A library integrand (a built-in) that stops at the next batch once the call is cancelled.
pub(crate) struct Guarded<'a, F: Integrand + ?Sized> {
    pub(crate) f: &'a F,
    pub(crate) call: &'a Call,
}

impl<F: Integrand + ?Sized> Integrand for Guarded<'_, F> {
    fn eval_batch(&self, x: &[f64], dim: usize, out: &mut [f64]) -> nis::Result<()> {
        if self.call.cancelled() {
            return Err(Call::stop());
        }
        self.f.eval_batch(x, dim, out)
    }
    fn dim(&self) -> Option<usize> {
        self.f.dim()
    }
    fn components(&self) -> usize {
        self.f.components()
    }
}

/// Runs `work` with the GIL released, on a worker thread inside `pool` (if any), while this
/// thread polls for signals. The first Python exception recorded in `call` (f's own, or
/// KeyboardInterrupt) wins over the library's error; a panic becomes a RuntimeError.
pub(crate) fn run<T: Send>(
    py: Python<'_>,
    pool: Option<&rayon::ThreadPool>,
    call: &Call,
    work: impl FnOnce() -> nis::Result<T> + Send,
) -> PyResult<T> {
    let outcome = py.detach(|| {
        std::thread::scope(|s| {
            let (tx, rx) = mpsc::channel();
            s.spawn(move || {
                let r = catch_unwind(AssertUnwindSafe(|| match pool {
                    Some(p) => p.install(work),
                    None => work(),
                }));
                let _ = tx.send(r);
            });
            loop {
                match rx.recv_timeout(SIGNAL_POLL) {
                    Ok(r) => return r,
                    Err(mpsc::RecvTimeoutError::Timeout) => {
                        if !call.cancelled() {
                            if let Err(e) = Python::attach(|py| py.check_signals()) {
                                call.fail(e);
                            }
                        }
                    }
                    Err(mpsc::RecvTimeoutError::Disconnected) => {
                        return Err(Box::new("the worker thread ended without a result")
                            as Box<dyn std::any::Any + Send>)
                    }
                }
            }
        })
    });
    if let Some(e) = call.take_error() {
        return Err(e);
    }
    match outcome {
        Ok(Ok(v)) => Ok(v),
        Ok(Err(e)) => Err(crate::to_py_err(e)),
        Err(panic) => {
            let what = panic
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "unknown panic".into());
            Err(PyRuntimeError::new_err(format!(
                "internal error in nis (please report it): {what}"
            )))
        }
    }
}

/// An integrand for one call, with the call's shared state.
pub(crate) struct Target<'a> {
    pub(crate) f: &'a dyn Integrand,
    pub(crate) call: &'a Call,
}

/// Runs `body` with `f` as a library integrand: a built-in directly (no Python per batch), any
/// other callable through [`PyIntegrand`]; `body` also learns whether results are vectors.
pub(crate) fn with_integrand<T>(
    _py: Python<'_>,
    f: &Bound<'_, PyAny>,
    dim: usize,
    body: impl FnOnce(Target<'_>, bool) -> PyResult<T>,
) -> PyResult<T> {
    let call = Call::default();
    if let Ok(b) = f.cast::<PyBuiltin>() {
        let b = b.get();
        let g = Guarded {
            f: &b.inner,
            call: &call,
        };
        return body(Target { f: &g, call: &call }, false);
    }
    let g = PyIntegrand::probe(f, dim, &call)?;
    let vector = g.vector();
    body(Target { f: &g, call: &call }, vector)
}
