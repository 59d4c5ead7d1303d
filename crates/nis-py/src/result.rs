//! `nis.IntegrationResult`: what an integration returns to Python, read-only.

use nis::integrate::IntegrationResult;
use numpy::{PyArray1, PyArrayMethods};
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// The outcome of an integration, like a `vegas` result: `mean`, `sdev` (floats for a scalar
/// integrand, arrays for a vector one, with `cov`), `chi2_dof`, `n_eval`, `rel_var_per_eval`,
/// `unweighting_efficiency`, the reliability figures `pareto_k`, `ess`, `var_rel_err`, `seconds`;
/// for a multi-channel integrator also `channel_weights`, `channel_means`, `channel_sdevs`,
/// `channel_evals` and `signs` (None otherwise); `str(r)` is a readable summary.
#[pyclass(module = "nis", name = "IntegrationResult", frozen)]
pub(crate) struct PyIntegrationResult {
    r: IntegrationResult,
    vector: bool,
}

impl PyIntegrationResult {
    /// The result of an integrand that returned (n, k) arrays (`vector`) or (n,) ones; an
    /// (n, 1) array makes a vector integrand of one component, which its warnings say.
    pub(crate) fn new(mut r: IntegrationResult, vector: bool) -> PyIntegrationResult {
        if vector && r.estimates().mean.len() == 1 {
            r.warnings.push(
                "f returned shape (n, 1): a vector integrand of one component, so mean, sdev \
                 and cov are arrays; return shape (n,) for floats"
                    .into(),
            );
        }
        PyIntegrationResult { r, vector }
    }
}

#[pymethods]
impl PyIntegrationResult {
    /// The estimate of ∫ f (an array of k for a vector integrand, one whose f returns shape
    /// (n, k), k = 1 included).
    #[getter]
    fn mean<'py>(&self, py: Python<'py>) -> Bound<'py, PyAny> {
        if self.vector {
            PyArray1::from_vec(py, self.r.estimates().mean).into_any()
        } else {
            self.r.value.into_pyobject(py).expect("a float").into_any()
        }
    }

    /// Its standard error (an array of k for a vector integrand).
    #[getter]
    fn sdev<'py>(&self, py: Python<'py>) -> Bound<'py, PyAny> {
        if self.vector {
            PyArray1::from_vec(py, self.r.estimates().std_err).into_any()
        } else {
            self.r
                .std_err
                .into_pyobject(py)
                .expect("a float")
                .into_any()
        }
    }

    /// The covariance of the estimates: k × k for a vector integrand, sdev² for a scalar one.
    #[getter]
    fn cov<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let e = self.r.estimates();
        if self.vector {
            let k = e.mean.len();
            Ok(PyArray1::from_vec(py, e.cov).reshape([k, k])?.into_any())
        } else {
            Ok(e.cov[0].into_pyobject(py).expect("a float").into_any())
        }
    }

    /// χ² per degree of freedom of the final phase's iterations (of component 0).
    #[getter]
    fn chi2_dof(&self) -> f64 {
        self.r.chi2_per_dof
    }

    /// All evaluations of the integrand in the call, training included.
    #[getter]
    fn n_eval(&self) -> u64 {
        self.r.n_eval
    }

    /// Var(f/q)/F² per evaluation of the estimate: n·sdev²/mean², n the evaluations that make the
    /// estimate (`iterations`' or `channel_evals`' sum; not those that only trained or adapted
    /// the sampler); smaller is better.
    #[getter]
    fn rel_var_per_eval(&self) -> f64 {
        self.r.rel_var_per_eval
    }

    /// mean(|w|)/max(|w|) of the final phase's weights.
    #[getter]
    fn unweighting_efficiency(&self) -> f64 {
        self.r.unweighting_efficiency
    }

    /// PSIS's Pareto k̂ of the final phase's weights: above `pareto_k_limit` the error bar cannot
    /// be trusted (NaN when it cannot be fitted).
    #[getter]
    fn pareto_k(&self) -> f64 {
        self.r.pareto_k
    }

    /// The k̂ above which the result warns: 0.5 plus 1.645 standard errors of a k̂ fitted to
    /// this tail (a one-sided test at 5 % that k > 0.5; inf when k̂ cannot be fitted).
    #[getter]
    fn pareto_k_limit(&self) -> f64 {
        self.r.pareto_k_limit
    }

    /// How probable a largest weight as small as the one seen is under the tail k̂ was fitted
    /// to: below 0.001 the weights end within the sample, and k̂ does not warn if `var_rel_err`
    /// is at most 0.1 too (NaN without a fit).
    #[getter]
    fn tail_end_p(&self) -> f64 {
        self.r.tail_end_p
    }

    /// Effective sample size (Σ|w|)²/Σw² of the final phase's weights.
    #[getter]
    fn ess(&self) -> f64 {
        self.r.ess
    }

    /// Relative error of the variance estimate behind `sdev`.
    #[getter]
    fn var_rel_err(&self) -> f64 {
        self.r.var_rel_err
    }

    /// Wall time of the call in seconds.
    #[getter]
    fn seconds(&self) -> f64 {
        self.r.seconds
    }

    /// Why a run to a precision target stopped: "target", "max_evals" or "max_seconds"
    /// (None for a run on a budget).
    #[getter]
    fn stop(&self) -> Option<&'static str> {
        self.r.stop.map(|s| s.name())
    }

    /// The method whose sampler made the estimate when it is not the integrator's own: "vegas"
    /// when NIS, integrating to a target, left it to VEGAS+, which met it first with no warning
    /// (None otherwise).
    #[getter]
    fn answered_by(&self) -> Option<&'static str> {
        self.r.answered_by.map(|m| m.name())
    }

    /// What the user should know (e.g. a large χ²/dof).
    #[getter]
    fn warnings(&self) -> Vec<String> {
        self.r.warnings.clone()
    }

    /// The final phase's iterations: (estimate, variance, evaluations) each.
    #[getter]
    fn iterations(&self) -> Vec<(f64, f64, u64)> {
        self.r
            .iterations
            .iter()
            .map(|i| (i.estimate, i.variance, i.evals))
            .collect()
    }

    /// Multi-channel results: each channel's a-priori weight a_k in the estimate (summing to 1),
    /// a float64 array of K (None for a single-channel result).
    #[getter]
    fn channel_weights<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray1<f64>>> {
        let c = self.r.channels.as_ref()?;
        Some(PyArray1::from_slice(py, &c.weights))
    }

    /// Multi-channel results: each channel's weighted share F_k = ∫ α_k f of the integral (α_k
    /// the channel weights, which sum to one at every point; they sum to `mean`). Not the
    /// integral of the peak the channel maps: a channel's share depends on the weights.
    #[getter]
    fn channel_means<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray1<f64>>> {
        let c = self.r.channels.as_ref()?;
        Some(PyArray1::from_slice(py, &c.means))
    }

    /// Multi-channel results: the standard errors of `channel_means`.
    #[getter]
    fn channel_sdevs<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray1<f64>>> {
        let c = self.r.channels.as_ref()?;
        Some(PyArray1::from_slice(py, &c.std_errs))
    }

    /// Multi-channel results: the estimate's evaluations in each channel (uint64).
    #[getter]
    fn channel_evals<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray1<u64>>> {
        let c = self.r.channels.as_ref()?;
        Some(PyArray1::from_slice(py, &c.evals))
    }

    /// When the integrand was split by sign: a dict with `positive` (F⁺ = ∫ max(f, 0)),
    /// `positive_sdev`, `negative` (F⁻ = ∫ max(−f, 0)), `negative_sdev`, `negative_fraction`
    /// (F⁻/(F⁺ + F⁻)) and the estimate's evaluations of each sign's parts, `positive_evals`
    /// and `negative_evals`; None otherwise.
    #[getter]
    fn signs<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        let Some(s) = self.r.channels.as_ref().and_then(|c| c.signs) else {
            return Ok(None);
        };
        let d = PyDict::new(py);
        d.set_item("positive", s.positive)?;
        d.set_item("positive_sdev", s.positive_err)?;
        d.set_item("negative", s.negative)?;
        d.set_item("negative_sdev", s.negative_err)?;
        d.set_item("negative_fraction", s.negative_fraction)?;
        d.set_item("positive_evals", s.positive_evals)?;
        d.set_item("negative_evals", s.negative_evals)?;
        Ok(Some(d))
    }

    /// The readable summary (`str(r)`), as `vegas`'s `result.summary()`.
    fn summary(&self) -> String {
        self.r.to_string()
    }

    fn __str__(&self) -> String {
        self.r.to_string()
    }

    fn __repr__(&self) -> String {
        if self.vector {
            let e = self.r.estimates();
            let parts: Vec<String> = e
                .mean
                .iter()
                .zip(&e.std_err)
                .map(|(m, s)| format!("{m:.6e} ± {s:.2e}"))
                .collect();
            format!("IntegrationResult([{}])", parts.join(", "))
        } else {
            format!(
                "IntegrationResult({:.8e} ± {:.3e}, chi2_dof={:.2}, n_eval={})",
                self.r.value, self.r.std_err, self.r.chi2_per_dof, self.r.n_eval
            )
        }
    }
}
