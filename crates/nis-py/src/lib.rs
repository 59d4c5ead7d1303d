//! The Python module `nis` (its compiled part, `nis._nis`): neural importance sampling from
//! Python, shaped like the `vegas` package (an integrator is an object that owns its adapted
//! state; a result prints itself) and, for flows, like zuko / `torch.distributions`
//! (`sample`, `log_prob`, `fit`).
//!
//! This crate is thin: it converts numpy arrays and keywords, runs the library with the GIL
//! released, and turns the library's typed errors into Python exceptions. Only whole batches
//! cross the language boundary (`call.rs`).
//!
//! - `call.rs`: a Python function as a fallible [`nis::integrate::Integrand`], and the runner that
//!   releases the GIL, polls for Ctrl-C and re-raises the integrand's own exception.
//! - `integrator.rs`: `nis.Integrator` (NIS, VEGAS+, plain MC by name; multi-channel with
//!   `channels`/`signs`) and `nis.IntegrationResult`.
//! - `flow.rs`: `nis.Flow`, a coupling flow as a distribution.
//! - `settings.rs`: keyword arguments as the library's settings keywords (one reader for Python,
//!   the C ABI and the CLI).
//! - `channel.rs`: `nis.Channel`, a channel of multi-channel integration (Python callbacks or a
//!   built-in example's).
//! - `builtin.rs`: the built-in suite, `nis.integrands.*`.

use std::path::Path;

use numpy::{PyArray1, PyArray2, PyArrayDyn, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::exceptions::{
    PyFileNotFoundError, PyOSError, PyPermissionError, PyRuntimeError, PyValueError,
};
use pyo3::prelude::*;

mod builtin;
mod call;
mod channel;
mod flow;
mod integrator;
mod result;
mod settings;

pyo3::create_exception!(
    nis,
    IntegrandError,
    PyValueError,
    "The integrand returned NaN or ±inf; `point` holds the point, `value` the value."
);
pyo3::create_exception!(
    nis,
    ModelError,
    PyValueError,
    "A model file that cannot be read back as what it claims to be."
);

/// The library's error as the Python exception a user expects: ValueError for bad settings and
/// shapes, `nis.IntegrandError` for non-finite values, FileNotFoundError and other OSErrors for
/// files, `nis.ModelError` for unreadable model files.
pub(crate) fn to_py_err(e: nis::Error) -> PyErr {
    use nis::Error;
    let message = e.to_string();
    match e {
        Error::Config(_)
        | Error::Dimension { .. }
        | Error::OutOfDomain { .. }
        | Error::NonFinite { .. }
        | Error::Channel { .. } => PyValueError::new_err(message),
        Error::Integrand { point, value } => Python::attach(|py| {
            let err = IntegrandError::new_err(message);
            let v = err.value(py);
            // The attributes are conveniences; the message already names the point.
            let _ = v.setattr("point", PyArray1::from_vec(py, point));
            let _ = v.setattr("value", value);
            err
        }),
        // Rank: another MPI rank's failure; the module runs on one process, where it cannot occur.
        Error::IntegrandFailed { .. } | Error::Rank { .. } => PyRuntimeError::new_err(message),
        Error::Model { .. } => ModelError::new_err(message),
        Error::Io { path, source } => {
            let args = (
                source.raw_os_error().unwrap_or(0),
                source.to_string(),
                path.display().to_string(),
            );
            match source.kind() {
                std::io::ErrorKind::NotFound => PyFileNotFoundError::new_err(args),
                std::io::ErrorKind::PermissionDenied => PyPermissionError::new_err(args),
                _ => PyOSError::new_err(args),
            }
        }
    }
}

/// Points, (n, dim), with one value per point, (n,): what sampling calls return.
pub(crate) type PointsAndValues<'py> = (Bound<'py, PyArray2<f64>>, Bound<'py, PyArray1<f64>>);

/// A non-negative integer setting (Python ints may be negative: a ValueError, not an overflow).
pub(crate) fn count(name: &str, v: i64) -> PyResult<usize> {
    usize::try_from(v)
        .map_err(|_| PyValueError::new_err(format!("{name} must be non-negative, got {v}")))
}

/// A dimension: at least 1 (a negative or zero `dim` is a ValueError that says so).
pub(crate) fn dimension(name: &str, v: i64) -> PyResult<usize> {
    match usize::try_from(v) {
        Ok(d) if d >= 1 => Ok(d),
        _ => Err(PyValueError::new_err(format!(
            "{name} must be a positive integer (1 or more), got {v}"
        ))),
    }
}

/// A path-like argument as a path.
pub(crate) fn path_of(obj: &Bound<'_, PyAny>) -> PyResult<std::path::PathBuf> {
    obj.extract::<std::path::PathBuf>()
        .map_err(|_| PyValueError::new_err("expected a path (str or os.PathLike)"))
}

/// Whether `path`'s parent folder exists (a clear FileNotFoundError instead of an I/O error
/// from the temporary file of an atomic write).
pub(crate) fn check_parent(path: &Path) -> PyResult<()> {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() && !p.is_dir() => Err(PyFileNotFoundError::new_err((
            2,
            "no such directory".to_string(),
            p.display().to_string(),
        ))),
        _ => Ok(()),
    }
}

/// An array-like of shape (n, `cols`) as row-major f64 values, and n. `what` names it in errors.
pub(crate) fn rows(obj: &Bound<'_, PyAny>, cols: usize, what: &str) -> PyResult<(Vec<f64>, usize)> {
    let py = obj.py();
    let np = py.import("numpy")?;
    let a = np
        .call_method1("ascontiguousarray", (obj, "float64"))
        .map_err(|e| PyValueError::new_err(format!("{what}: not an array of numbers ({e})")))?;
    let a = a
        .cast_into::<PyArrayDyn<f64>>()
        .map_err(|_| PyValueError::new_err(format!("{what}: not a float64 array")))?;
    let shape = a.shape().to_vec();
    if shape.len() != 2 || shape[1] != cols {
        return Err(PyValueError::new_err(format!(
            "{what} must have shape (n, {cols}), got {}",
            shape_str(&shape)
        )));
    }
    let v = a
        .to_vec()
        .map_err(|e| PyValueError::new_err(e.to_string()))?;
    Ok((v, shape[0]))
}

/// A shape as Python writes it: `(3,)`, `(2, 4)`.
pub(crate) fn shape_str(shape: &[usize]) -> String {
    match shape {
        [n] => format!("({n},)"),
        s => format!(
            "({})",
            s.iter()
                .map(|n| n.to_string())
                .collect::<Vec<_>>()
                .join(", ")
        ),
    }
}

/// Neural importance sampling: Monte Carlo integration over [0, 1]^d with a normalizing flow
/// learned from the integrand (the compiled part of the package `nis`).
#[pymodule]
fn _nis(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add("IntegrandError", py.get_type::<IntegrandError>())?;
    m.add("ModelError", py.get_type::<ModelError>())?;
    m.add_class::<integrator::PyIntegrator>()?;
    m.add_class::<result::PyIntegrationResult>()?;
    m.add_class::<flow::PyFlow>()?;
    m.add_class::<builtin::PyBuiltin>()?;
    m.add_class::<channel::PyChannel>()?;
    m.add_function(wrap_pyfunction!(channel::example_names, m)?)?;
    m.add_function(wrap_pyfunction!(channel::example_channels, m)?)?;
    m.add_function(wrap_pyfunction!(builtin::suite, m)?)?;
    m.add_function(wrap_pyfunction!(settings::_keywords, m)?)?;
    Ok(())
}
