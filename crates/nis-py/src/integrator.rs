//! `nis.Integrator` and `nis.IntegrationResult`: the library's [`Integrator`] trait, shaped like
//! the `vegas` package's `Integrator` (every setting a keyword, `integ(f, evals=…)` adapts
//! further on each call) and its result (`mean`, `sdev`, a printable summary).

use std::sync::{Arc, Mutex};

use nis::flow::Density;
use nis::integrate::nis::NisIntegrator;
use nis::integrate::{
    integrator, Integrand, IntegrationResult, Integrator, Method, Settings, TrainOn,
};
use nis::loss::Loss;
use nis::TransformKind;
use numpy::{PyArray1, PyArray2, PyArrayMethods};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use crate::builtin::PyBuiltin;
use crate::call::{run, Call, Guarded, PyIntegrand};
use crate::flow::PyFlow;
use crate::{check_parent, count, path_of, to_py_err, PointsAndValues};

/// The adapted state: NIS concretely (for its own calls), the others through the trait.
enum Engine {
    Nis(Box<NisIntegrator>),
    Other(Box<dyn Integrator>),
}

impl Engine {
    fn integrator(&mut self) -> &mut dyn Integrator {
        match self {
            Engine::Nis(n) => n.as_mut(),
            Engine::Other(o) => o.as_mut(),
        }
    }

    fn nis(&mut self, what: &str) -> PyResult<&mut NisIntegrator> {
        match self {
            Engine::Nis(n) => Ok(n),
            Engine::Other(o) => Err(PyValueError::new_err(format!(
                "{what} needs a trained flow: method=\"nis\", not {:?}",
                o.method().name()
            ))),
        }
    }
}

/// A Monte Carlo integrator over [0, 1]^dim that owns its adapted state, like
/// `vegas.Integrator`.
///
/// `method` is "nis" (neural importance sampling), "vegas" (VEGAS+) or "uniform" (plain MC).
/// Every setting is a keyword; those of another method than the chosen one are an error.
///
///     integ = nis.Integrator(dim=4, method="nis", coupling="pq", loss="kl", seed=1)
///     r = integ(f, evals=1_000_000)   # f: (n, 4) float64 array -> (n,) or (n, k)
///     print(r)                        # mean ± sdev, χ²/dof, ...
///
/// A second call adapts further from where the first stopped, then estimates anew.
#[pyclass(module = "nis", name = "Integrator")]
pub(crate) struct PyIntegrator {
    // A Mutex only to make the class Sync; methods take `&mut self`, so it is never contended.
    engine: Mutex<Engine>,
    threads: Option<usize>,
    pool: Option<Arc<rayon::ThreadPool>>,
}

/// Keywords that only some methods take.
struct Given<'a> {
    nis: Vec<&'a str>,
    vegas: Vec<&'a str>,
    iterations: bool,
    train_on: bool,
}

#[pymethods]
impl PyIntegrator {
    #[new]
    #[pyo3(signature = (
        dim, method = "nis", *, seed = 0, coupling = None, bins = None, layers = None, masks = None,
        hidden_layers = None, hidden_width = None, blob_bins = None, loss = None, batch = None,
        steps_per_batch = None, train_fraction = None, learning_rate = None,
        learning_rate_end = None, average_span = None, uniform_fraction = None, anneal_from = None,
        final_iterations = None, stratify = None, reuse_training = None, replay_batches = None,
        replay_steps = None, increments = None, alpha = None, beta = None,
        iterations = None, warmup = None, min_per_cube = None, train_on = None, threads = None
    ))]
    // Each parameter is a named keyword of the Python constructor (the `vegas`-like interface the
    // module promises); PyO3 maps keywords to parameters, so a struct cannot stand in for them.
    #[allow(clippy::too_many_arguments)]
    fn new(
        dim: i64,
        method: &str,
        seed: i64,
        coupling: Option<&str>,
        bins: Option<i64>,
        layers: Option<i64>,
        masks: Option<&str>,
        hidden_layers: Option<i64>,
        hidden_width: Option<i64>,
        blob_bins: Option<i64>,
        loss: Option<&str>,
        batch: Option<i64>,
        steps_per_batch: Option<i64>,
        train_fraction: Option<f64>,
        learning_rate: Option<f32>,
        learning_rate_end: Option<f32>,
        average_span: Option<f64>,
        uniform_fraction: Option<f64>,
        anneal_from: Option<f64>,
        final_iterations: Option<i64>,
        stratify: Option<bool>,
        reuse_training: Option<f64>,
        replay_batches: Option<i64>,
        replay_steps: Option<i64>,
        increments: Option<i64>,
        alpha: Option<f64>,
        beta: Option<f64>,
        iterations: Option<i64>,
        warmup: Option<i64>,
        min_per_cube: Option<i64>,
        train_on: Option<&Bound<'_, PyAny>>,
        threads: Option<i64>,
    ) -> PyResult<PyIntegrator> {
        let method: Method = method.parse().map_err(to_py_err)?;
        let dim = count("dim", dim)?;
        let mut given = Given {
            nis: Vec::new(),
            vegas: Vec::new(),
            iterations: iterations.is_some(),
            train_on: train_on.is_some(),
        };
        let mut s = Settings::default().seed(count("seed", seed)? as u64);
        let n = &mut s.nis;
        macro_rules! set {
            ($list:ident, $name:ident, $field:expr, $conv:expr) => {
                if let Some(v) = $name {
                    given.$list.push(stringify!($name));
                    $field = $conv(v)?;
                }
            };
        }
        let c = |name: &'static str| move |v: i64| count(name, v);
        fn same<T>(v: T) -> PyResult<T> {
            Ok(v)
        }
        if coupling.is_some() || bins.is_some() {
            given.nis.push(if coupling.is_some() {
                "coupling"
            } else {
                "bins"
            });
            n.flow.transform = transform(coupling.unwrap_or("pq"), bins, &n.flow.transform)?;
        }
        set!(nis, layers, n.flow.couplings, c("layers"));
        set!(nis, masks, n.flow.masks, |m: &str| m
            .parse()
            .map_err(to_py_err));
        set!(nis, hidden_layers, n.flow.hidden_layers, c("hidden_layers"));
        set!(nis, hidden_width, n.flow.hidden_width, c("hidden_width"));
        set!(nis, blob_bins, n.flow.blob_bins, c("blob_bins"));
        set!(nis, loss, n.loss, parse_loss);
        set!(nis, batch, n.batch, c("batch"));
        set!(
            nis,
            steps_per_batch,
            n.steps_per_batch,
            c("steps_per_batch")
        );
        set!(nis, train_fraction, n.train_fraction, same);
        set!(nis, learning_rate, n.adam.learning_rate, same);
        set!(nis, learning_rate_end, n.learning_rate_end, same);
        set!(nis, average_span, n.average_span, same);
        set!(nis, uniform_fraction, n.uniform_fraction, same);
        set!(nis, anneal_from, n.anneal_from, same);
        set!(
            nis,
            final_iterations,
            n.final_iterations,
            c("final_iterations")
        );
        if let Some(on) = stratify {
            given.nis.push("stratify");
            n.stratify = on.then(|| n.stratify.unwrap_or_default());
        }
        set!(nis, reuse_training, n.reuse_training, same);
        set!(nis, replay_batches, n.replay_batches, c("replay_batches"));
        set!(nis, replay_steps, n.replay_steps, c("replay_steps"));
        let v = &mut s.vegas;
        set!(vegas, increments, v.increments, c("increments"));
        set!(vegas, alpha, v.alpha, same);
        set!(vegas, beta, v.beta, same);
        set!(vegas, warmup, v.warmup, c("warmup"));
        set!(vegas, min_per_cube, v.min_per_cube, c("min_per_cube"));
        if let Some(i) = iterations {
            let i = count("iterations", i)?;
            s.vegas.iterations = i;
            s.uniform.iterations = i;
        }
        if let Some(t) = train_on {
            s = s.train_on(parse_train_on(t)?);
        }
        given.check(method)?;
        let threads = threads.map(|t| count("threads", t)).transpose()?;
        let pool = match threads {
            Some(0) => return Err(PyValueError::new_err("threads must be at least 1")),
            Some(t) => Some(Arc::new(
                rayon::ThreadPoolBuilder::new()
                    .num_threads(t)
                    .build()
                    .map_err(|e| PyValueError::new_err(format!("threads={t}: {e}")))?,
            )),
            None => None,
        };
        let engine = match method {
            Method::Nis => {
                Engine::Nis(Box::new(NisIntegrator::new(dim, s.nis).map_err(to_py_err)?))
            }
            m => Engine::Other(integrator(m, dim, &s).map_err(to_py_err)?),
        };
        Ok(PyIntegrator {
            engine: Mutex::new(engine),
            threads,
            pool,
        })
    }

    /// Spends `evals` evaluations of `f`: adapts on a share of them (continuing from earlier
    /// calls), then estimates ∫ f with the rest, the sampler frozen.
    ///
    /// `f` takes an (n, dim) float64 array and returns n values (shape (n,)) or n vectors
    /// (shape (n, k): every component is estimated from the same points, with covariance). It
    /// is called on whole batches, with the GIL held only then. An exception raised by `f`
    /// propagates unchanged; NaN or inf raise `nis.IntegrandError`; Ctrl-C raises
    /// KeyboardInterrupt at the next batch.
    #[pyo3(signature = (f, evals = 1_000_000))]
    fn __call__(
        &mut self,
        py: Python<'_>,
        f: &Bound<'_, PyAny>,
        evals: i64,
    ) -> PyResult<PyIntegrationResult> {
        let evals = count("evals", evals)? as u64;
        let engine = self.engine.get_mut().unwrap_or_else(|p| p.into_inner());
        with_integrand(py, f, engine.integrator().dim(), |g, vector| {
            let r = run(py, self.pool.as_deref(), g.call, || {
                engine.integrator().integrate(g.f, evals)
            })?;
            Ok(PyIntegrationResult { r, vector })
        })
    }

    /// NIS only: trains the flow on `evals` more evaluations of `f`, without estimating.
    #[pyo3(signature = (f, evals))]
    fn train(&mut self, py: Python<'_>, f: &Bound<'_, PyAny>, evals: i64) -> PyResult<()> {
        let evals = count("evals", evals)? as u64;
        let nis = self.engine.get_mut().unwrap_or_else(|p| p.into_inner());
        let nis = nis.nis("train")?;
        let dim = nis.flow().dim();
        with_integrand(py, f, dim, |g, _| {
            run(py, self.pool.as_deref(), g.call, || nis.train(g.f, evals))
        })
    }

    /// NIS only: estimates ∫ f with the flow frozen (e.g. after `load`), all `evals`
    /// evaluations in the final phase.
    #[pyo3(signature = (f, evals = 1_000_000))]
    fn estimate(
        &mut self,
        py: Python<'_>,
        f: &Bound<'_, PyAny>,
        evals: i64,
    ) -> PyResult<PyIntegrationResult> {
        let evals = count("evals", evals)? as u64;
        let nis = self.engine.get_mut().unwrap_or_else(|p| p.into_inner());
        let nis = nis.nis("estimate")?;
        let dim = nis.flow().dim();
        with_integrand(py, f, dim, |g, vector| {
            let r = run(py, self.pool.as_deref(), g.call, || {
                nis.estimate(g.f, evals)
            })?;
            Ok(PyIntegrationResult { r, vector })
        })
    }

    /// NIS only: `n` weighted points of the trained sampler, `(x, w)`: x of shape (n, dim), w
    /// the weights f(x)/q(x) of shape (n,) (or (n, k)), whose mean estimates ∫ f.
    #[pyo3(signature = (f, n))]
    fn sample<'py>(
        &mut self,
        py: Python<'py>,
        f: &Bound<'py, PyAny>,
        n: i64,
    ) -> PyResult<(Bound<'py, PyArray2<f64>>, Bound<'py, PyAny>)> {
        let n = count("n", n)?;
        let nis = self.engine.get_mut().unwrap_or_else(|p| p.into_inner());
        let nis = nis.nis("sample")?;
        let dim = nis.flow().dim();
        with_integrand(py, f, dim, |g, vector| {
            let k = g.f.components();
            let (x, w) = run(py, self.pool.as_deref(), g.call, || {
                // In pieces, so that f sees batches of bounded size.
                let (mut x, mut w) = (Vec::with_capacity(n * dim), Vec::with_capacity(n * k));
                while w.len() < n * k {
                    let m = (n - w.len() / k).min(1 << 16);
                    let (xm, wm) = nis.weighted(g.f, m)?;
                    x.extend(xm);
                    w.extend(wm);
                }
                Ok((x, w))
            })?;
            let x = PyArray1::from_vec(py, x).reshape([n, dim])?;
            let w = PyArray1::from_vec(py, w);
            let w = if vector {
                w.reshape([n, k])?.into_any()
            } else {
                w.into_any()
            };
            Ok((x, w))
        })
    }

    /// NIS only: `n` unweighted points of the trained sampler's target |f|/∫|f| (rejection
    /// against a robust maximum weight; `overweight` is the tolerated share of weight mass above
    /// it), `(x, w)`: x of shape (n, dim) and w of shape (n,), sign(f)·max(1, |w|/w_max) (±1
    /// except for the rare overweight points). For a vector integrand, the points follow the
    /// component the flow learned (`train_on`).
    #[pyo3(signature = (f, n, overweight = 1e-3))]
    fn unweighted<'py>(
        &mut self,
        py: Python<'py>,
        f: &Bound<'py, PyAny>,
        n: i64,
        overweight: f64,
    ) -> PyResult<PointsAndValues<'py>> {
        let n = count("n", n)?;
        let nis = self.engine.get_mut().unwrap_or_else(|p| p.into_inner());
        let nis = nis.nis("unweighted")?;
        let dim = nis.flow().dim();
        with_integrand(py, f, dim, |g, _| {
            let u = run(py, self.pool.as_deref(), g.call, || {
                nis.unweighted(g.f, n, overweight)
            })?;
            let x = PyArray1::from_vec(py, u.points).reshape([n, dim])?;
            Ok((x, PyArray1::from_vec(py, u.weights)))
        })
    }

    /// NIS only: saves the trained integrator (its flow and settings) as a safetensors file, the
    /// format `nis integrate --save` writes.
    fn save(&mut self, path: &Bound<'_, PyAny>) -> PyResult<()> {
        let path = path_of(path)?;
        check_parent(&path)?;
        let engine = self.engine.get_mut().unwrap_or_else(|p| p.into_inner());
        engine.integrator().save(&path).map_err(to_py_err)
    }

    /// Loads an integrator saved by `save` (or `nis integrate --save`).
    #[staticmethod]
    #[pyo3(signature = (path, *, threads = None))]
    fn load(path: &Bound<'_, PyAny>, threads: Option<i64>) -> PyResult<PyIntegrator> {
        let path = path_of(path)?;
        let nis = NisIntegrator::load(&path).map_err(to_py_err)?;
        let threads = threads.map(|t| count("threads", t)).transpose()?;
        let pool = match threads {
            Some(0) => return Err(PyValueError::new_err("threads must be at least 1")),
            Some(t) => Some(Arc::new(
                rayon::ThreadPoolBuilder::new()
                    .num_threads(t)
                    .build()
                    .map_err(|e| PyValueError::new_err(format!("threads={t}: {e}")))?,
            )),
            None => None,
        };
        Ok(PyIntegrator {
            engine: Mutex::new(Engine::Nis(Box::new(nis))),
            threads,
            pool,
        })
    }

    /// The method: "nis", "vegas" or "uniform".
    #[getter]
    fn method(&mut self) -> &'static str {
        let engine = self.engine.get_mut().unwrap_or_else(|p| p.into_inner());
        engine.integrator().method().name()
    }

    /// The dimension.
    #[getter]
    fn dim(&mut self) -> usize {
        let engine = self.engine.get_mut().unwrap_or_else(|p| p.into_inner());
        engine.integrator().dim()
    }

    /// Threads of its own rayon pool (None: the global pool).
    #[getter]
    fn threads(&self) -> Option<usize> {
        self.threads
    }

    /// NIS only: a copy of the trained flow, as a `nis.Flow`.
    #[getter]
    fn flow(&mut self) -> PyResult<PyFlow> {
        let engine = self.engine.get_mut().unwrap_or_else(|p| p.into_inner());
        let nis = engine.nis("flow")?;
        Ok(PyFlow::from_flow(nis.flow().clone(), nis.config().seed))
    }

    /// NIS only: evaluations spent training so far (over all calls, and before saving).
    #[getter]
    fn trained_evals(&mut self) -> PyResult<u64> {
        let engine = self.engine.get_mut().unwrap_or_else(|p| p.into_inner());
        Ok(engine.nis("trained_evals")?.trained_evals())
    }

    fn __repr__(&mut self) -> String {
        let engine = self.engine.get_mut().unwrap_or_else(|p| p.into_inner());
        match engine {
            Engine::Nis(n) => format!(
                "nis.Integrator(dim={}, method=\"nis\", coupling={:?}, loss={:?}, seed={})",
                n.flow().dim(),
                n.config().flow.transform.label(),
                match n.config().loss {
                    Loss::Kl => "kl",
                    Loss::ChiSquare => "chi2",
                    Loss::Nll => "nll",
                },
                n.config().seed
            ),
            Engine::Other(o) => format!(
                "nis.Integrator(dim={}, method={:?})",
                o.dim(),
                o.method().name()
            ),
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

impl Given<'_> {
    /// Rejects keywords of another method than `method`.
    fn check(&self, method: Method) -> PyResult<()> {
        let mut wrong: Vec<&str> = Vec::new();
        if method != Method::Nis {
            wrong.extend(&self.nis);
        }
        if method != Method::Vegas {
            wrong.extend(&self.vegas);
        }
        if method == Method::Nis && self.iterations {
            wrong.push("iterations (NIS has final_iterations)");
        }
        if method == Method::Uniform && self.train_on {
            wrong.push("train_on");
        }
        if wrong.is_empty() {
            Ok(())
        } else {
            Err(PyValueError::new_err(format!(
                "method={:?} does not take {}",
                method.name(),
                wrong.join(", ")
            )))
        }
    }
}

/// A coupling transform by name ("pq", "pl", "rq", "affine"), with `bins` or the current ones.
pub(crate) fn transform(
    name: &str,
    bins: Option<i64>,
    current: &TransformKind,
) -> PyResult<TransformKind> {
    let bins = match bins {
        Some(b) => count("bins", b)?,
        None => match *current {
            TransformKind::Linear { bins }
            | TransformKind::Quadratic { bins }
            | TransformKind::RationalQuadratic { bins } => bins,
            TransformKind::Affine => 16,
        },
    };
    let t = match name {
        "pq" | "quadratic" => TransformKind::Quadratic { bins },
        "pl" | "linear" => TransformKind::Linear { bins },
        "rq" | "rational_quadratic" => TransformKind::RationalQuadratic { bins },
        "affine" => TransformKind::Affine,
        _ => {
            return Err(PyValueError::new_err(format!(
                "unknown coupling {name:?}: expected \"pq\", \"pl\", \"rq\" or \"affine\""
            )))
        }
    };
    t.validate().map_err(to_py_err)?;
    Ok(t)
}

/// A training loss by name ("kl", "chi2").
pub(crate) fn parse_loss(name: &str) -> PyResult<Loss> {
    match name.parse::<Loss>().map_err(to_py_err)? {
        Loss::Nll => Err(PyValueError::new_err(
            "loss \"nll\" is for data (Flow.fit); an integrand trains with \"kl\" or \"chi2\"",
        )),
        l => Ok(l),
    }
}

/// `train_on`: a component index or "sum_abs".
fn parse_train_on(v: &Bound<'_, PyAny>) -> PyResult<TrainOn> {
    if let Ok(i) = v.extract::<i64>() {
        return Ok(TrainOn::Component(count("train_on", i)?));
    }
    match v.extract::<String>().as_deref() {
        Ok("sum_abs") => Ok(TrainOn::SumAbs),
        _ => Err(PyValueError::new_err(format!(
            "train_on must be a component index or \"sum_abs\", got {v}"
        ))),
    }
}

/// The outcome of an integration, like a `vegas` result: `mean`, `sdev` (floats for a scalar
/// integrand, arrays for a vector one, with `cov`), `chi2_dof`, `n_eval`, `rel_var_per_eval`,
/// `unweighting_efficiency`, the reliability figures `pareto_k`, `ess`, `var_rel_err`, `seconds`;
/// `str(r)` is a readable summary.
#[pyclass(module = "nis", name = "IntegrationResult", frozen)]
pub(crate) struct PyIntegrationResult {
    r: IntegrationResult,
    vector: bool,
}

#[pymethods]
impl PyIntegrationResult {
    /// The estimate of ∫ f (an array of k for a vector integrand).
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

    /// Var(f/q)/F² per evaluation of the final phase (1/n_eff per point; smaller is better).
    #[getter]
    fn rel_var_per_eval(&self) -> f64 {
        self.r.rel_var_per_eval
    }

    /// mean(|w|)/max(|w|) of the final phase's weights.
    #[getter]
    fn unweighting_efficiency(&self) -> f64 {
        self.r.unweighting_efficiency
    }

    /// PSIS's Pareto k̂ of the final phase's weights: above 0.5 the error bar cannot be trusted
    /// (NaN when it cannot be fitted).
    #[getter]
    fn pareto_k(&self) -> f64 {
        self.r.pareto_k
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
