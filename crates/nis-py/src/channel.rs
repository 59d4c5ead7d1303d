//! `nis.Channel`: a channel of multi-channel integration from two Python batch callbacks (the
//! map `sample(u) -> x` and its density `density(x) -> g`), or one of the library's built-in
//! channels (`nis.integrands.channels(name)`).
//!
//! A Python channel becomes a library [`Channel`] only inside an integrator, where it learns its
//! dimension and its index in the set (for messages). Its callbacks are called with the GIL on
//! whole batches, like an integrand; an exception they raise is kept in the integrator's
//! [`Raised`] slot and re-raised unchanged once the library has returned. Wrong shapes are the
//! library's [`nis::Error::Channel`] naming the channel and the point; points outside the cube
//! and densities that are NaN, negative or zero where the channel sampled are caught by the
//! library's own checks ([`nis::channels::check_sampled`]).

use std::sync::{Arc, Mutex};

use nis::channels::{examples, Channel};
use numpy::{PyArray1, PyArrayDyn, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use crate::{dimension, rows, shape_str, to_py_err};

/// The first exception a Python channel raised during a call.
#[derive(Default)]
pub(crate) struct Raised(Mutex<Option<PyErr>>);

impl Raised {
    fn record(&self, e: PyErr) {
        let mut slot = self.0.lock().unwrap_or_else(|p| p.into_inner());
        slot.get_or_insert(e);
    }

    /// The recorded exception, if any (and clears it).
    pub(crate) fn take(&self) -> Option<PyErr> {
        self.0.lock().unwrap_or_else(|p| p.into_inner()).take()
    }
}

/// Where a channel's map and density come from.
enum Source {
    /// Two Python callables on batches.
    Python {
        sample: Py<PyAny>,
        density: Py<PyAny>,
        enhancement: Option<Py<PyAny>>,
    },
    /// A channel of the library (a built-in example's).
    Builtin(Arc<dyn Channel>),
}

/// A channel of multi-channel integration: a map from the unit cube onto the integration domain
/// [0, 1]^d and the density of the points it produces, with an a-priori weight `prior`.
///
/// `sample` takes an (n, d) float64 array u of uniform points and returns x = φ(u), shape
/// (n, d), inside [0, 1]^d; `density` takes an (n, d) array x (any points of the cube, not only
/// the channel's own) and returns g(x), shape (n,), the density of `sample`'s points (finite,
/// ≥ 0, and > 0 where the channel can put a point). Both are called on whole batches, with the
/// GIL held only then; an exception they raise propagates unchanged, and wrong shapes, points
/// outside the cube and NaN or negative densities raise ValueError naming the channel's index
/// and the point. `dim`, if given, is checked against the integrator's. `enhancement`, if
/// given, takes an (n, d) array x and returns w(x) ≥ 0, shape (n,), large where the channel's
/// peak is (its diagram's |M|², its propagator): the channel weights then become
/// α_k = a_k w_k/Σ_j a_j w_j (single-diagram enhancement) instead of a_k g_k/Σ_j a_j g_j.
///
///     ramp = nis.Channel(lambda u: np.sqrt(u), lambda x: 2.0 * x[:, 0], prior=2.0)
///     flat = nis.Channel(lambda u: u, lambda x: np.ones(len(x)))
///     integ = nis.Integrator(1, channels=[ramp, flat], method="vegas")
///
/// Built-in examples' channels: `nis.integrands.channels("resonances-4d")`.
#[pyclass(module = "nis", name = "Channel", frozen)]
pub(crate) struct PyChannel {
    source: Source,
    prior: f64,
    dim: Option<usize>,
    name: Option<String>,
}

impl PyChannel {
    /// The library channel for index `index` of a set of dimension `dim`, its exceptions
    /// recorded in `raised`.
    pub(crate) fn channel(
        &self,
        py: Python<'_>,
        index: usize,
        dim: usize,
        raised: &Arc<Raised>,
    ) -> PyResult<Box<dyn Channel>> {
        if let Some(d) = self.dim {
            if d != dim {
                return Err(PyValueError::new_err(format!(
                    "channel {index}{} has dimension {d}, the integrator {dim}",
                    self.label()
                )));
            }
        }
        Ok(match &self.source {
            Source::Python {
                sample,
                density,
                enhancement,
            } => Box::new(CallbackChannel {
                index,
                dim,
                sample: sample.clone_ref(py),
                density: density.clone_ref(py),
                enhancement: enhancement.as_ref().map(|e| e.clone_ref(py)),
                raised: raised.clone(),
            }),
            Source::Builtin(c) => Box::new(Shared(c.clone())),
        })
    }

    /// The prior.
    pub(crate) fn prior(&self) -> f64 {
        self.prior
    }

    fn label(&self) -> String {
        self.name
            .as_ref()
            .map(|n| format!(" ({n})"))
            .unwrap_or_default()
    }

    /// The built-in example `name`'s channels, with equal priors.
    pub(crate) fn builtins(name: &str) -> nis::Result<Vec<PyChannel>> {
        let ex = examples::by_name(name)?;
        Ok(ex
            .channels
            .into_iter()
            .enumerate()
            .map(|(k, c)| PyChannel {
                dim: Some(c.dim()),
                source: Source::Builtin(Arc::from(c)),
                prior: 1.0,
                name: Some(format!("{name}[{k}]")),
            })
            .collect())
    }

    /// The dimension for calls from Python: the declared one, or the points' own.
    fn dim_for(&self, obj: &Bound<'_, PyAny>) -> PyResult<usize> {
        if let Some(d) = self.dim {
            return Ok(d);
        }
        let np = obj.py().import("numpy")?;
        let shape: Vec<usize> = np.call_method1("shape", (obj,))?.extract()?;
        match shape.as_slice() {
            [_, d] if *d > 0 => Ok(*d),
            s => Err(PyValueError::new_err(format!(
                "points must have shape (n, d), got {}",
                shape_str(s)
            ))),
        }
    }
}

#[pymethods]
impl PyChannel {
    #[new]
    #[pyo3(signature = (sample, density, prior = 1.0, *, dim = None, enhancement = None))]
    fn new(
        sample: &Bound<'_, PyAny>,
        density: &Bound<'_, PyAny>,
        prior: f64,
        dim: Option<i64>,
        enhancement: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<PyChannel> {
        let callbacks = [("sample", sample), ("density", density)]
            .into_iter()
            .chain(enhancement.map(|e| ("enhancement", e)));
        for (what, f) in callbacks {
            if !f.is_callable() {
                return Err(PyValueError::new_err(format!(
                    "a channel's {what} must be callable, got {}",
                    f.get_type().name()?
                )));
            }
        }
        if !(prior.is_finite() && prior > 0.0) {
            return Err(PyValueError::new_err(format!(
                "a channel's prior must be finite and > 0, got {prior}"
            )));
        }
        let dim = dim.map(|d| dimension("dim", d)).transpose()?;
        Ok(PyChannel {
            source: Source::Python {
                sample: sample.clone().unbind(),
                density: density.clone().unbind(),
                enhancement: enhancement.map(|e| e.clone().unbind()),
            },
            prior,
            dim,
            name: None,
        })
    }

    /// Maps uniform points `u`, an (n, d) array, to x, shape (n, d), checked as an integrator
    /// checks them (inside the cube, density finite and > 0 there).
    #[pyo3(name = "sample")]
    fn sample_py<'py>(&self, u: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyAny>> {
        let py = u.py();
        let dim = self.dim_for(u)?;
        let (u, n) = rows(u, dim, "u")?;
        let raised = Arc::new(Raised::default());
        let c = self.channel(py, 0, dim, &raised)?;
        let mut x = vec![0.0; u.len()];
        let mut g = vec![0.0; n];
        let r = c
            .sample(&u, &mut x)
            .and_then(|_| c.density(&x, &mut g))
            .and_then(|_| nis::channels::check_sampled(0, dim, &u, &x, &g));
        if let Some(e) = raised.take() {
            return Err(e);
        }
        r.map_err(to_py_err)?;
        Ok(PyArray1::from_vec(py, x).reshape([n, dim])?.into_any())
    }

    /// The density g at the points `x`, an (n, d) array: shape (n,).
    #[pyo3(name = "density")]
    fn density_py<'py>(&self, x: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let py = x.py();
        let dim = self.dim_for(x)?;
        let (x, n) = rows(x, dim, "x")?;
        let raised = Arc::new(Raised::default());
        let c = self.channel(py, 0, dim, &raised)?;
        let mut g = vec![0.0; n];
        let r = c.density(&x, &mut g);
        if let Some(e) = raised.take() {
            return Err(e);
        }
        r.map_err(to_py_err)?;
        Ok(PyArray1::from_vec(py, g))
    }

    /// The a-priori weight (the integrator normalises the priors to sum 1).
    #[getter(prior)]
    fn prior_py(&self) -> f64 {
        self.prior
    }

    /// The dimension, if declared (built-in channels always know theirs).
    #[getter(dim)]
    fn dim_py(&self) -> Option<usize> {
        self.dim
    }

    /// The built-in channel's name ("resonances-4d[0]"), None for a Python one.
    #[getter(name)]
    fn name_py(&self) -> Option<String> {
        self.name.clone()
    }

    fn __repr__(&self) -> String {
        match (&self.name, &self.source) {
            (Some(n), _) => format!(
                "nis.Channel({n:?}, dim={}, prior={:?})",
                self.dim.map_or("None".into(), |d| d.to_string()),
                self.prior
            ),
            (
                None,
                Source::Python {
                    sample, density, ..
                },
            ) => Python::attach(|py| {
                let name = |f: &Py<PyAny>| {
                    f.bind(py)
                        .getattr("__name__")
                        .and_then(|n| n.extract::<String>())
                        .unwrap_or_else(|_| "?".into())
                };
                format!(
                    "nis.Channel({}, {}, prior={:?})",
                    name(sample),
                    name(density),
                    self.prior
                )
            }),
            (None, Source::Builtin(_)) => format!("nis.Channel(prior={:?})", self.prior),
        }
    }
}

/// A library channel shared between Python objects and integrators.
struct Shared(Arc<dyn Channel>);

impl Channel for Shared {
    fn dim(&self) -> usize {
        self.0.dim()
    }
    fn sample(&self, u: &[f64], x: &mut [f64]) -> nis::Result<()> {
        self.0.sample(u, x)
    }
    fn density(&self, x: &[f64], g: &mut [f64]) -> nis::Result<()> {
        self.0.density(x, g)
    }
    fn has_enhancement(&self) -> bool {
        self.0.has_enhancement()
    }
    fn enhancement(&self, x: &[f64], w: &mut [f64]) -> nis::Result<()> {
        self.0.enhancement(x, w)
    }
}

/// A channel from Python callbacks, as a library channel (index `index` of its set).
struct CallbackChannel {
    index: usize,
    dim: usize,
    sample: Py<PyAny>,
    density: Py<PyAny>,
    enhancement: Option<Py<PyAny>>,
    raised: Arc<Raised>,
}

impl CallbackChannel {
    /// Calls `f` on the (n, d) batch `points` and copies its result, which must have the shape
    /// `want`, into `out`. `what` names the callback in errors.
    fn call(
        &self,
        f: &Py<PyAny>,
        what: &str,
        points: &[f64],
        want: &[usize],
        out: &mut [f64],
    ) -> nis::Result<()> {
        let d = self.dim;
        let n = points.len() / d;
        let first = || points.get(..d).unwrap_or_default().to_vec();
        let arg = if what == "sample" { "u" } else { "x" };
        let bad = |reason: String| nis::Error::Channel {
            channel: self.index,
            point: first(),
            reason: format!("{reason} (the point is the batch's first {arg})"),
        };
        if points.len() != n * d {
            return Err(bad(format!(
                "{what} got {} coordinates, not whole points of dimension {d}",
                points.len()
            )));
        }
        Python::attach(|py| {
            let y = PyArray1::from_slice(py, points)
                .reshape([n, d])
                .and_then(|a| f.bind(py).call1((a,)));
            let y = match y {
                Ok(y) => y,
                Err(e) => {
                    let message = format!("channel {}: {what} raised {e}", self.index);
                    self.raised.record(e);
                    return Err(nis::Error::IntegrandFailed { message });
                }
            };
            let np = py.import("numpy").map_err(|e| bad(e.to_string()))?;
            let y = np
                .call_method1("asarray", (y, "float64"))
                .map_err(|e| bad(format!("{what} must return an array of numbers ({e})")))?
                .cast_into::<PyArrayDyn<f64>>()
                .map_err(|_| bad(format!("{what} must return a float64 array")))?;
            if y.shape() != want {
                return Err(bad(format!(
                    "{what} returned shape {} for {n} points, expected {}",
                    shape_str(y.shape()),
                    shape_str(want)
                )));
            }
            let y = y.readonly();
            for (o, v) in out.iter_mut().zip(y.as_array().iter()) {
                *o = *v;
            }
            Ok(())
        })
    }
}

impl Channel for CallbackChannel {
    fn dim(&self) -> usize {
        self.dim
    }

    fn sample(&self, u: &[f64], x: &mut [f64]) -> nis::Result<()> {
        let n = u.len() / self.dim;
        self.call(&self.sample, "sample", u, &[n, self.dim], x)
    }

    fn density(&self, x: &[f64], g: &mut [f64]) -> nis::Result<()> {
        let n = x.len() / self.dim;
        self.call(&self.density, "density", x, &[n], g)
    }

    fn has_enhancement(&self) -> bool {
        self.enhancement.is_some()
    }

    fn enhancement(&self, x: &[f64], w: &mut [f64]) -> nis::Result<()> {
        match &self.enhancement {
            Some(e) => self.call(e, "enhancement", x, &[x.len() / self.dim], w),
            None => self.density(x, w),
        }
    }
}

/// The built-in multi-channel examples' names.
#[pyfunction]
pub(crate) fn example_names() -> Vec<&'static str> {
    examples::names()
}

/// The channels of the built-in multi-channel example `name`, as `nis.Channel`s.
#[pyfunction]
pub(crate) fn example_channels(name: &str) -> PyResult<Vec<PyChannel>> {
    PyChannel::builtins(name).map_err(to_py_err)
}
