//! The built-in suite as Python objects: `nis.integrands.camel(dim=8)` builds a [`PyBuiltin`],
//! callable on (n, dim) arrays and knowing its exact integral. The functions of
//! `nis.integrands` are generated at import from [`suite`], the library's `SUITE`.

use nis::integrands::{self, Builtin, SUITE};
use nis::integrate::Integrand;
use numpy::PyArray1;
use pyo3::prelude::*;

use crate::{dimension, rows, to_py_err};

/// A built-in integrand of the suite with its exact integral over the unit hypercube.
///
/// Built by the functions of `nis.integrands` (e.g. `nis.integrands.camel(dim=8)`). Calling it
/// on an (n, dim) array returns its n values. An integrator given a built-in evaluates it
/// without leaving Rust.
#[pyclass(module = "nis", name = "Builtin", frozen)]
pub(crate) struct PyBuiltin {
    pub(crate) inner: Builtin,
}

#[pymethods]
impl PyBuiltin {
    /// The suite member `name` (as `nis list` spells it, e.g. "camel-sharp") in `dim`
    /// dimensions (default: its smallest suite dimension).
    #[new]
    #[pyo3(signature = (name, dim = None))]
    fn new(name: &str, dim: Option<i64>) -> PyResult<PyBuiltin> {
        let dim = dim.map(|d| dimension("dim", d)).transpose()?;
        Ok(PyBuiltin {
            inner: integrands::by_name(name, dim).map_err(to_py_err)?,
        })
    }

    /// f at each row of `x`, an (n, dim) array: shape (n,).
    fn __call__<'py>(&self, x: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let py = x.py();
        let dim = self.inner.dim;
        let (points, n) = rows(x, dim, "x")?;
        let mut out = vec![0.0; n];
        py.detach(|| self.inner.eval_batch(&points, dim, &mut out))
            .map_err(to_py_err)?;
        Ok(PyArray1::from_vec(py, out))
    }

    /// The suite name.
    #[getter]
    fn name(&self) -> &str {
        &self.inner.name
    }

    /// The dimension.
    #[getter]
    fn dim(&self) -> usize {
        self.inner.dim
    }

    /// The exact integral over [0, 1]^dim.
    #[getter]
    fn exact(&self) -> f64 {
        self.inner.exact
    }

    /// Uncertainty of `exact` where it is known only numerically (0 if exact).
    #[getter]
    fn exact_err(&self) -> f64 {
        self.inner.exact_err
    }

    /// Where the integrand and its value come from.
    #[getter]
    fn source(&self) -> &str {
        self.inner.source
    }

    fn __repr__(&self) -> String {
        format!(
            "nis.integrands.{}(dim={})  # exact {}",
            self.inner.name.replace('-', "_"),
            self.inner.dim,
            self.inner.exact
        )
    }
}

/// The suite: (name, dimensions of the benchmark, description) per member.
#[pyfunction]
pub(crate) fn suite() -> Vec<(&'static str, Vec<usize>, &'static str)> {
    SUITE
        .iter()
        .map(|e| (e.name, e.dims.to_vec(), e.description))
        .collect()
}
