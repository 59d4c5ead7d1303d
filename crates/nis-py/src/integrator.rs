//! `nis.Integrator`: the library's [`Integrator`] trait, shaped like the `vegas` package's
//! `Integrator` (every setting a keyword, `integ(f, evals=…)` adapts further on each call); its
//! result is `crate::result`.

use std::sync::{Arc, Mutex};

use nis::channels::ChannelSet;
use nis::flow::Density;
use nis::integrate::multichannel::{by_default, MultiChannel, MultiChannelConfig, Signs};
use nis::integrate::nis::NisIntegrator;
use nis::integrate::{Integrator, Method, Settings, Target};
use nis::loss::Loss;
use numpy::{PyArray1, PyArray2, PyArrayMethods};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use crate::call::{run, with_integrand};
use crate::channel::{PyChannel, Raised};
use crate::flow::PyFlow;
use crate::result::PyIntegrationResult;
use crate::settings::{json_of, keywords};
use crate::{check_parent, count, dimension, path_of, to_py_err, PointsAndValues};

/// A Monte Carlo integrator over [0, 1]^dim that owns its adapted state, like
/// `vegas.Integrator`.
///
/// `method` is "nis" (neural importance sampling), "vegas" (VEGAS+) or "uniform" (plain MC).
/// Every setting is a keyword: a field of the method's settings (`batch=2048`,
/// `increments=500`, `flow={"hidden_width": 64}`) or a shorthand (`coupling="pq"`, `bins=16`,
/// `layers`, `masks`, `hidden_layers`, `hidden_width`, `blob_bins`, `learning_rate`, `loss="kl"`,
/// `stratify=False`, `train_on=1`); those of another method than the chosen one, unknown ones
/// and ill-typed values raise ValueError naming the keyword. None leaves a setting at its
/// default.
///
///     integ = nis.Integrator(dim=4, method="nis", coupling="pq", loss="kl", seed=1)
///     r = integ(f, evals=1_000_000)   # f: (n, 4) float64 array -> (n,) or (n, k)
///     print(r)                        # mean ± sdev, χ²/dof, ...
///
/// A second call adapts further from where the first stopped, then estimates anew.
///
/// Multi-channel: `channels=[nis.Channel(...), ...]` integrates with a sampler of `method` per
/// channel (and per sign of f when it changes sign: `signs="auto"`, the default, or "split",
/// "whole"); `signs=` alone splits a single-channel integral by sign. Without either, NIS splits
/// a scalar integrand whose first points show both signs (`signs="auto"` is the default), while
/// VEGAS+ and plain MC keep the whole; vector integrands always do. Results then carry
/// `channel_weights`, `channel_means`, `channel_sdevs`, `channel_evals` and `signs`; precision
/// targets work as for one channel; `events(f, n)` draws unweighted events that carry their
/// channel (NIS), and the other NIS-only methods raise ValueError. `channel_settings` (a dict:
/// `adapt_fraction`, `adapt_weights`, `weight_floor`, `pilot`, `target_adapt`, `shared_flow`,
/// `weight_network`)
/// tunes the multi-channel integrator.
///
///     integ = nis.Integrator(4, "vegas", channels=nis.integrands.channels("resonances-4d"))
///     r = integ(nis.integrands.example("resonances-4d"), evals=300_000)
#[pyclass(module = "nis", name = "Integrator")]
pub(crate) struct PyIntegrator {
    // A Mutex only to make the class Sync; methods take `&mut self`, so it is never contended.
    // One integrator whatever it integrates: a method, or channels and/or a sign split.
    integrator: Mutex<Box<dyn Integrator>>,
    /// What a multi-channel integrator was made with (None for a single channel).
    channels: Option<Channels>,
    threads: Option<usize>,
    pool: Option<Arc<rayon::ThreadPool>>,
}

/// Events as Python gets them: points (n, dim), weights (n,), channels (n,).
type Events<'py> = (
    Bound<'py, PyArray2<f64>>,
    Bound<'py, PyArray1<f64>>,
    Bound<'py, PyArray1<u64>>,
);

/// What a multi-channel integrator (channels and/or sign splitting) was made with.
struct Channels {
    /// Channels given (0: `signs` alone, the identity channel).
    count: usize,
    signs: Signs,
    /// The first exception a Python channel raised in the current call.
    raised: Arc<Raised>,
}

impl PyIntegrator {
    /// What integrates.
    fn engine(&mut self) -> &mut dyn Integrator {
        self.integrator
            .get_mut()
            .unwrap_or_else(|p| p.into_inner())
            .as_mut()
    }

    /// The single-channel integrator, for `what` that a multi-channel one does not do.
    fn integrator(&mut self, what: &str) -> PyResult<&mut dyn Integrator> {
        if self.channels.is_some() {
            return Err(PyValueError::new_err(format!(
                "{what} is not available for a multi-channel integrator (one made with channels \
                 or signs): it holds a sampler per channel and sign; use a single-channel \
                 Integrator for it"
            )));
        }
        Ok(self.engine())
    }

    /// The integrator as NIS, for `what` that only NIS does.
    fn nis(&mut self, what: &str) -> PyResult<&mut NisIntegrator> {
        let integ = self.integrator(what)?;
        let method = integ.method();
        if method == Method::Nis && integ.as_multichannel().is_some() {
            return Err(PyValueError::new_err(format!(
                "{what} is not available: the integrand changed sign, so it was integrated split \
                 by sign (signs=\"auto\", the default) with a sampler per sign; pass \
                 signs=\"whole\" to keep one flow"
            )));
        }
        integ.as_nis().ok_or_else(|| {
            PyValueError::new_err(format!(
                "{what} needs a trained flow: method=\"nis\", not {:?}",
                method.name()
            ))
        })
    }

    fn with(
        integrator: Box<dyn Integrator>,
        channels: Option<Channels>,
        threads: Option<i64>,
    ) -> PyResult<PyIntegrator> {
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
            integrator: Mutex::new(integrator),
            channels,
            threads,
            pool,
        })
    }
}

#[pymethods]
impl PyIntegrator {
    #[new]
    #[pyo3(signature = (
        dim, method = "nis", *, channels = None, signs = None, channel_settings = None,
        threads = None, **settings
    ))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        dim: i64,
        method: &str,
        channels: Option<&Bound<'_, PyAny>>,
        signs: Option<&str>,
        channel_settings: Option<&Bound<'_, PyDict>>,
        threads: Option<i64>,
        settings: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<PyIntegrator> {
        let method: Method = method.parse().map_err(to_py_err)?;
        let dim = dimension("dim", dim)?;
        let keywords = keywords(settings)?;
        let settings = Settings::default()
            .with_keywords(
                method,
                keywords.iter().map(|(k, v)| (k.as_str(), v.clone())),
            )
            .map_err(to_py_err)?;
        if channels.is_none() && signs.is_none() {
            if channel_settings.is_some() {
                return Err(PyValueError::new_err(
                    "channel_settings needs channels or signs (a multi-channel integrator)",
                ));
            }
            // By default NIS splits a scalar integrand that changes sign (signs="auto").
            let integ = by_default(method, dim, &settings).map_err(to_py_err)?;
            return PyIntegrator::with(integ, None, threads);
        }
        let mut config = match channel_settings {
            None => MultiChannelConfig::default(),
            Some(d) => {
                let value = json_of(d.as_any(), "channel_settings")?;
                serde_json::from_value::<MultiChannelConfig>(value)
                    .map_err(|e| PyValueError::new_err(format!("channel_settings: {e}")))?
            }
        };
        config.signs = match signs {
            None => config.signs,
            Some("auto") => Signs::Auto,
            Some("split") => Signs::Split,
            Some("whole") => Signs::Whole,
            Some(s) => {
                return Err(PyValueError::new_err(format!(
                    "signs must be \"auto\", \"split\" or \"whole\", got {s:?}"
                )))
            }
        };
        let raised = Arc::new(Raised::default());
        let signs = config.signs;
        let (mc, count) = match channels {
            None => (MultiChannel::single(dim, method, settings, config), 0),
            Some(list) => {
                let set = channel_set(py, list, dim, &raised)?;
                let n = set.len();
                (MultiChannel::new(set, method, settings, config), n)
            }
        };
        let channels = Channels {
            count,
            signs,
            raised,
        };
        PyIntegrator::with(Box::new(mc.map_err(to_py_err)?), Some(channels), threads)
    }

    /// Spends `evals` evaluations of `f`: adapts, then estimates ∫ f (the docstring Python
    /// shows is in python/nis/__init__.py: PyO3 makes `__call__` a type slot, which keeps none).
    #[pyo3(signature = (
        f, evals = None, *, rel_err = None, abs_err = None, max_evals = None, max_seconds = None
    ))]
    #[allow(clippy::too_many_arguments)]
    fn __call__(
        &mut self,
        py: Python<'_>,
        f: &Bound<'_, PyAny>,
        evals: Option<i64>,
        rel_err: Option<f64>,
        abs_err: Option<f64>,
        max_evals: Option<i64>,
        max_seconds: Option<f64>,
    ) -> PyResult<PyIntegrationResult> {
        let max_evals = max_evals.map(|m| count("max_evals", m)).transpose()?;
        let target =
            Target::from_options(rel_err, abs_err, max_evals.map(|m| m as u64), max_seconds)
                .map_err(to_py_err)?;
        let evals = match (target.is_some(), evals) {
            (true, Some(_)) => {
                return Err(PyValueError::new_err(
                    "give evals (a budget) or rel_err/abs_err (a precision target), not both",
                ))
            }
            (_, evals) => count("evals", evals.unwrap_or(1_000_000))? as u64,
        };
        let pool = self.pool.clone();
        let raised = self.channels.as_ref().map(|c| c.raised.clone());
        let integ = self.engine();
        if let Some(t) = &target {
            integ.check_target(t).map_err(to_py_err)?;
        }
        with_integrand(py, f, integ.dim(), |g, vector| {
            let raised = raised.as_deref();
            if let Some(r) = raised {
                r.take();
            }
            let r = run(py, pool.as_deref(), g.call, || match &target {
                Some(t) => integ.integrate_to(g.f, t),
                None => integ.integrate(g.f, evals),
            });
            // A channel's own exception wins over the library's error it caused.
            if let (Err(_), Some(e)) = (&r, raised.and_then(Raised::take)) {
                return Err(e);
            }
            Ok(PyIntegrationResult::new(r?, vector))
        })
    }

    /// NIS only: trains the flow on `evals` more evaluations of `f`, without estimating.
    #[pyo3(signature = (f, evals))]
    fn train(&mut self, py: Python<'_>, f: &Bound<'_, PyAny>, evals: i64) -> PyResult<()> {
        let evals = count("evals", evals)? as u64;
        let pool = self.pool.clone();
        let nis = self.nis("train")?;
        let dim = nis.flow().dim();
        with_integrand(py, f, dim, |g, _| {
            run(py, pool.as_deref(), g.call, || nis.train(g.f, evals))
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
        let pool = self.pool.clone();
        let nis = self.nis("estimate")?;
        let dim = nis.flow().dim();
        with_integrand(py, f, dim, |g, vector| {
            let r = run(py, pool.as_deref(), g.call, || nis.estimate(g.f, evals))?;
            Ok(PyIntegrationResult::new(r, vector))
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
        let pool = self.pool.clone();
        let nis = self.nis("sample")?;
        let dim = nis.flow().dim();
        with_integrand(py, f, dim, |g, vector| {
            let k = g.f.components();
            let (x, w) = run(py, pool.as_deref(), g.call, || {
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
        let pool = self.pool.clone();
        let nis = self.nis("unweighted")?;
        let dim = nis.flow().dim();
        with_integrand(py, f, dim, |g, _| {
            let u = run(py, pool.as_deref(), g.call, || {
                nis.unweighted(g.f, n, overweight)
            })?;
            let x = PyArray1::from_vec(py, u.points).reshape([n, dim])?;
            Ok((x, PyArray1::from_vec(py, u.weights)))
        })
    }

    /// Multi-channel NIS only, after a first integration: `(x, w, channel)`, n unweighted events
    /// of |f| through the channels (x of shape (n, dim), w of shape (n,) as for `unweighted`,
    /// negative for events of f < 0, and the channel of each event, shape (n,)), in random
    /// order; each call draws new events.
    #[pyo3(signature = (f, n, overweight = 1e-3))]
    fn events<'py>(
        &mut self,
        py: Python<'py>,
        f: &Bound<'py, PyAny>,
        n: i64,
        overweight: f64,
    ) -> PyResult<Events<'py>> {
        let n = count("n", n)?;
        let pool = self.pool.clone();
        let not_multi = || {
            PyValueError::new_err(
                "events come from a multi-channel integrator (one made with channels or signs); \
                 use unweighted for a single-channel one",
            )
        };
        let raised = self.channels.as_ref().ok_or_else(not_multi)?.raised.clone();
        let mc = self.engine().as_multichannel().ok_or_else(not_multi)?;
        let dim = mc.dim();
        with_integrand(py, f, dim, |g, _| {
            raised.take();
            let ev = run(py, pool.as_deref(), g.call, || {
                mc.unweighted(g.f, n, overweight)
            });
            if let (Err(_), Some(e)) = (&ev, raised.take()) {
                return Err(e);
            }
            let ev = ev?;
            let x = PyArray1::from_vec(py, ev.events.points).reshape([n, dim])?;
            let channels: Vec<u64> = ev.channels.iter().map(|&k| k as u64).collect();
            Ok((
                x,
                PyArray1::from_vec(py, ev.events.weights),
                PyArray1::from_vec(py, channels),
            ))
        })
    }

    /// NIS only: saves the trained integrator (its flow and settings) as a safetensors file, the
    /// format `nis integrate --save` writes.
    fn save(&mut self, path: &Bound<'_, PyAny>) -> PyResult<()> {
        let path = path_of(path)?;
        check_parent(&path)?;
        self.integrator("save")?.save(&path).map_err(to_py_err)
    }

    /// Loads an integrator saved by `save` (or `nis integrate --save`).
    #[staticmethod]
    #[pyo3(signature = (path, *, threads = None))]
    fn load(path: &Bound<'_, PyAny>, threads: Option<i64>) -> PyResult<PyIntegrator> {
        let path = path_of(path)?;
        let nis = NisIntegrator::load(&path).map_err(to_py_err)?;
        PyIntegrator::with(Box::new(nis), None, threads)
    }

    /// The method: "nis", "vegas" or "uniform".
    #[getter]
    fn method(&mut self) -> &'static str {
        self.engine().method().name()
    }

    /// The dimension.
    #[getter]
    fn dim(&mut self) -> usize {
        self.engine().dim()
    }

    /// The number of channels (None for a single-channel integrator; 1 for `signs` alone).
    #[getter]
    fn channels(&self) -> Option<usize> {
        self.channels.as_ref().map(|c| c.count.max(1))
    }

    /// The a-priori channel weights the next call starts from (they adapt between calls;
    /// None for a single-channel integrator).
    #[getter]
    fn channel_weights<'py>(&mut self, py: Python<'py>) -> Option<Bound<'py, PyArray1<f64>>> {
        let mc = self.engine().as_multichannel()?;
        Some(PyArray1::from_slice(py, mc.weights()))
    }

    /// Threads of its own rayon pool (None: the global pool).
    #[getter]
    fn threads(&self) -> Option<usize> {
        self.threads
    }

    /// NIS only: a copy of the trained flow, as a `nis.Flow`.
    #[getter]
    fn flow(&mut self) -> PyResult<PyFlow> {
        let nis = self.nis("flow")?;
        Ok(PyFlow::from_flow(nis.flow().clone(), nis.config().seed))
    }

    /// NIS only: evaluations spent training so far (over all calls, and before saving).
    #[getter]
    fn trained_evals(&mut self) -> PyResult<u64> {
        Ok(self.nis("trained_evals")?.trained_evals())
    }

    fn __repr__(&mut self) -> String {
        let (count, signs) = self
            .channels
            .as_ref()
            .map_or((0, None), |c| (c.count, Some(c.signs)));
        let integ = self.engine();
        let (dim, method) = (integ.dim(), integ.method().name());
        if let Some(signs) = signs {
            let signs = match signs {
                Signs::Auto => "auto",
                Signs::Split => "split",
                Signs::Whole => "whole",
            };
            let channels = match count {
                0 => String::new(),
                1 => ", channels=[1 channel]".into(),
                n => format!(", channels=[{n} channels]"),
            };
            return format!(
                "nis.Integrator(dim={dim}, method={method:?}{channels}, signs={signs:?})"
            );
        }
        match integ.as_nis() {
            Some(n) => format!(
                "nis.Integrator(dim={dim}, method=\"nis\", coupling={:?}, loss={:?}, seed={})",
                n.config().flow.transform.label(),
                match n.config().loss {
                    Loss::Kl => "kl",
                    Loss::ChiSquare => "chi2",
                    Loss::Nll => "nll",
                    Loss::Auto => "auto",
                },
                n.config().seed
            ),
            None => format!("nis.Integrator(dim={dim}, method={method:?})"),
        }
    }
}

/// The `channels` argument, a non-empty list of `nis.Channel`, as a channel set of dimension
/// `dim` whose Python channels record their exceptions in `raised`.
fn channel_set(
    py: Python<'_>,
    list: &Bound<'_, PyAny>,
    dim: usize,
    raised: &Arc<Raised>,
) -> PyResult<ChannelSet> {
    let not_list = || PyValueError::new_err("channels must be a non-empty list of nis.Channel");
    let items: Vec<Bound<'_, PyAny>> = list
        .try_iter()
        .map_err(|_| not_list())?
        .collect::<PyResult<_>>()?;
    if items.is_empty() {
        return Err(not_list());
    }
    let (mut channels, mut priors) = (Vec::new(), Vec::new());
    for (k, item) in items.iter().enumerate() {
        let c = item.cast::<PyChannel>().map_err(|_| {
            PyValueError::new_err(format!(
                "channel {k} is a {}, not a nis.Channel",
                item.get_type()
                    .name()
                    .map(|n| n.to_string())
                    .unwrap_or_default()
            ))
        })?;
        let c = c.get();
        channels.push(c.channel(py, k, dim, raised)?);
        priors.push(c.prior());
    }
    ChannelSet::with_priors(channels, priors).map_err(to_py_err)
}
