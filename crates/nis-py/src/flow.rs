//! `nis.Flow`: the library's coupling flow on [0, 1]^dim as a distribution, with the
//! conventions of zuko / `torch.distributions` — `sample` returns points with their
//! log-density, `log_prob` evaluates it, `fit` learns from data by maximum likelihood — and
//! `fit_integrand`, which learns |f|/∫|f| from an integrand's values (KL or χ²).

use nis::flow::{Density, Flow, FlowConfig};
use nis::integrate::{evaluate, Method, Settings, TrainOn};
use nis::loss::Loss;
use nis::nn::AdamConfig;
use nis::train::Trainer;
use nis::TransformKind;
use numpy::{PyArray1, PyArrayMethods};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use rand::seq::SliceRandom;
use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;

use crate::call::{run, with_integrand, Call};
use crate::{check_parent, count, dimension, path_of, rows, to_py_err, PointsAndValues};

/// A normalizing flow on [0, 1]^dim with a uniform latent: a stack of coupling layers
/// (`coupling` "pq" piecewise-quadratic, "pl" piecewise-linear, "rq" rational-quadratic,
/// "affine") whose conditioners are MLPs on one-blob encoded inputs, optionally conditioned on
/// `context_dim` features per point. A new flow is the uniform density.
///
///     flow = nis.Flow(2, coupling="pq", bins=16, seed=0)
///     flow.fit(data, epochs=20)            # data: (n, 2) points in [0, 1]^2
///     x, log_q = flow.sample(1000)         # points and their log-density
///     assert np.allclose(flow.log_prob(x), log_q, atol=1e-4)
///
/// The defaults are those of the NIS integrator's flow. `layers` is the number of coupling
/// layers (None: one pass of the masks that separate every pair of dimensions).
#[pyclass(module = "nis", name = "Flow")]
pub(crate) struct PyFlow {
    flow: Flow,
    rng: Pcg64Mcg,
}

impl PyFlow {
    /// Wraps a library flow; its random stream starts from `seed`.
    pub(crate) fn from_flow(flow: Flow, seed: u64) -> PyFlow {
        PyFlow {
            flow,
            rng: Pcg64Mcg::seed_from_u64(seed ^ 0x666c_6f77),
        }
    }
}

/// A coupling transform by name ("pq", "pl", "rq", "affine"), read as `Integrator`'s
/// `coupling` and `bins` keywords are.
fn transform(coupling: &str, bins: i64) -> PyResult<TransformKind> {
    let keywords = [
        ("coupling", serde_json::json!(coupling)),
        ("bins", serde_json::json!(bins)),
    ];
    let s = Settings::default()
        .with_keywords(Method::Nis, keywords)
        .map_err(to_py_err)?;
    Ok(s.nis.flow.transform)
}

/// A training loss by name ("kl", "chi2").
fn parse_loss(name: &str) -> PyResult<Loss> {
    match name.parse::<Loss>().map_err(to_py_err)? {
        Loss::Nll => Err(PyValueError::new_err(
            "loss \"nll\" is for data (Flow.fit); an integrand trains with \"kl\" or \"chi2\"",
        )),
        l => Ok(l),
    }
}

/// Context features for n points: an (n, context_dim) array as f32, or none.
fn context(ctx: Option<&Bound<'_, PyAny>>, cdim: usize, n: usize) -> PyResult<Option<Vec<f32>>> {
    match ctx {
        None => Ok(None),
        Some(c) => {
            let (v, m) = rows(c, cdim, "context")?;
            if m != n {
                return Err(PyValueError::new_err(format!(
                    "context has {m} rows for {n} points"
                )));
            }
            Ok(Some(v.into_iter().map(|v| v as f32).collect()))
        }
    }
}

#[pymethods]
impl PyFlow {
    #[new]
    #[pyo3(signature = (
        dim, coupling = "pq", bins = 16, layers = None, context_dim = 0, *, hidden_layers = 2,
        hidden_width = 32, blob_bins = 16, masks = "binary", seed = 0
    ))]
    // Each parameter is a named keyword of the Python constructor (the `vegas`-like interface the
    // module promises); PyO3 maps keywords to parameters, so a struct cannot stand in for them.
    #[allow(clippy::too_many_arguments)]
    fn new(
        dim: i64,
        coupling: &str,
        bins: i64,
        layers: Option<i64>,
        context_dim: i64,
        hidden_layers: i64,
        hidden_width: i64,
        blob_bins: i64,
        masks: &str,
        seed: i64,
    ) -> PyResult<PyFlow> {
        let seed = count("seed", seed)? as u64;
        let config = FlowConfig {
            dim: dimension("dim", dim)?,
            transform: transform(coupling, bins)?,
            couplings: layers.map(|l| count("layers", l)).transpose()?.unwrap_or(0),
            hidden_layers: count("hidden_layers", hidden_layers)?,
            hidden_width: count("hidden_width", hidden_width)?,
            blob_bins: count("blob_bins", blob_bins)?,
            context_dim: count("context_dim", context_dim)?,
            seed,
            masks: masks.parse().map_err(to_py_err)?,
        };
        if layers == Some(0) {
            return Err(PyValueError::new_err("layers must be at least 1 (or None)"));
        }
        Ok(PyFlow::from_flow(
            Flow::new(config).map_err(to_py_err)?,
            seed,
        ))
    }

    /// Draws `n` points with their log-density: `(x, log_q)`, x of shape (n, dim) in
    /// [0, 1]^dim, log_q of shape (n,). `context`: (n, context_dim) features of a conditional
    /// flow.
    #[pyo3(signature = (n, context = None))]
    fn sample<'py>(
        &mut self,
        py: Python<'py>,
        n: i64,
        context: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<PointsAndValues<'py>> {
        let n = count("n", n)?;
        let dim = self.flow.dim();
        let ctx = self::context(context, self.flow.context_dim(), n)?;
        let (flow, rng) = (&self.flow, &mut self.rng);
        let s = py
            .detach(|| flow.sample(n, ctx.as_deref(), rng))
            .map_err(to_py_err)?;
        let x: Vec<f64> = s.x.iter().map(|&v| v as f64).collect();
        Ok((
            PyArray1::from_vec(py, x).reshape([n, dim])?,
            PyArray1::from_vec(py, s.log_q),
        ))
    }

    /// ln q(x) of each row of `x`, an (n, dim) array of points in [0, 1]^dim: shape (n,).
    #[pyo3(signature = (x, context = None))]
    fn log_prob<'py>(
        &self,
        py: Python<'py>,
        x: &Bound<'py, PyAny>,
        context: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let (x, n) = rows(x, self.flow.dim(), "x")?;
        let ctx = self::context(context, self.flow.context_dim(), n)?;
        let x: Vec<f32> = x.into_iter().map(|v| v as f32).collect();
        let flow = &self.flow;
        let log_q = py
            .detach(|| flow.log_density(&x, ctx.as_deref()))
            .map_err(to_py_err)?;
        Ok(PyArray1::from_vec(py, log_q))
    }

    /// Maximum likelihood on `data`, an (n, dim) array of points in [0, 1]^dim (with
    /// `context`, (n, context_dim), for a conditional flow): `epochs` passes over the data in
    /// shuffled batches of `batch`, Adam with `learning_rate`. Returns the mean negative
    /// log-likelihood (nats per point) of each epoch. On an error or Ctrl-C the flow is left as
    /// it was before the call.
    #[pyo3(signature = (data, *, epochs = 10, batch = 256, learning_rate = 1e-3, context = None))]
    fn fit(
        &mut self,
        py: Python<'_>,
        data: &Bound<'_, PyAny>,
        epochs: i64,
        batch: i64,
        learning_rate: f32,
        context: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Vec<f64>> {
        let dim = self.flow.dim();
        let cdim = self.flow.context_dim();
        let (x, n) = rows(data, dim, "data")?;
        let ctx = self::context(context, cdim, n)?;
        let (epochs, batch) = (count("epochs", epochs)?, count("batch", batch)?);
        if n == 0 || batch == 0 {
            return Err(PyValueError::new_err(
                "fit needs at least one point and a batch of at least one",
            ));
        }
        let x: Vec<f32> = x.into_iter().map(|v| v as f32).collect();
        let adam = AdamConfig {
            learning_rate,
            ..AdamConfig::default()
        };
        let mut trainer = Trainer::new(self.flow.clone(), Loss::Nll, adam).map_err(to_py_err)?;
        let call = Call::default();
        let rng = &mut self.rng;
        let history = run(py, None, &call, || {
            let mut order: Vec<usize> = (0..n).collect();
            let mut history = Vec::with_capacity(epochs);
            let (mut xb, mut cb) = (Vec::new(), Vec::new());
            for _ in 0..epochs {
                order.shuffle(rng);
                let mut nll = 0.0;
                for idx in order.chunks(batch) {
                    if call.cancelled() {
                        return Err(Call::stop());
                    }
                    xb.clear();
                    cb.clear();
                    for &i in idx {
                        xb.extend_from_slice(&x[i * dim..(i + 1) * dim]);
                        if let Some(c) = &ctx {
                            cb.extend_from_slice(&c[i * cdim..(i + 1) * cdim]);
                        }
                    }
                    let c = ctx.as_ref().map(|_| cb.as_slice());
                    let zeros = vec![0.0; idx.len()];
                    let stats = trainer.step(&xb, c, &[], &zeros)?;
                    nll += stats.mean_nll * idx.len() as f64;
                }
                history.push(nll / n as f64);
            }
            Ok(history)
        })?;
        self.flow = trainer.into_flow();
        Ok(history)
    }

    /// Learns |f|/∫|f| from `evals` evaluations of the integrand `f` (an (n, dim) array → (n,)
    /// values; a vector integrand's first component), on-policy in batches of `batch`, with the
    /// `loss` "kl" or "chi2". Returns each batch's relative variance Var(f/q)/F² (it falls as
    /// the flow learns). On an error, an exception of f or Ctrl-C the flow is left as it was.
    #[pyo3(signature = (f, *, evals = 100_000, loss = "kl", batch = 1024, learning_rate = 5e-3))]
    fn fit_integrand(
        &mut self,
        py: Python<'_>,
        f: &Bound<'_, PyAny>,
        evals: i64,
        loss: &str,
        batch: i64,
        learning_rate: f32,
    ) -> PyResult<Vec<f64>> {
        let dim = self.flow.dim();
        if self.flow.context_dim() > 0 {
            return Err(PyValueError::new_err(
                "fit_integrand trains an unconditional flow (context_dim = 0)",
            ));
        }
        let loss = parse_loss(loss)?;
        let (evals, batch) = (count("evals", evals)?, count("batch", batch)?);
        if batch < 2 {
            return Err(PyValueError::new_err("batch must be at least 2"));
        }
        let adam = AdamConfig {
            learning_rate,
            clip_norm: Some(10.0),
            ..AdamConfig::default()
        };
        let mut trainer = Trainer::new(self.flow.clone(), loss, adam).map_err(to_py_err)?;
        let rng = &mut self.rng;
        let history = with_integrand(py, f, dim, |g, _| {
            run(py, None, g.call, || {
                let k = g.f.components();
                let mut history = Vec::with_capacity(evals / batch);
                for _ in 0..evals / batch {
                    let s = trainer.flow().sample_for_training(batch, None, rng)?;
                    let x64: Vec<f64> = s.x.iter().map(|&v| v as f64).collect();
                    let fx = evaluate(g.f, &x64, dim)?;
                    let target = TrainOn::Component(0).target(&fx, k);
                    if target.iter().any(|v| *v != 0.0) {
                        history.push(trainer.step_on_policy(&s, &target)?.rel_var);
                    }
                }
                Ok(history)
            })
        })?;
        self.flow = trainer.into_flow();
        Ok(history)
    }

    /// Saves the flow as a safetensors model file (the format of `nis::io`, which the CLI
    /// writes and reads).
    fn save(&self, path: &Bound<'_, PyAny>) -> PyResult<()> {
        let path = path_of(path)?;
        check_parent(&path)?;
        nis::io::save(&self.flow, &path).map_err(to_py_err)
    }

    /// Loads a flow saved by `save`, by `Integrator.save` or by the CLI.
    #[staticmethod]
    #[pyo3(signature = (path, *, seed = 0))]
    fn load(path: &Bound<'_, PyAny>, seed: i64) -> PyResult<PyFlow> {
        let path = path_of(path)?;
        let flow = nis::io::load(&path).map_err(to_py_err)?;
        Ok(PyFlow::from_flow(flow, count("seed", seed)? as u64))
    }

    /// The dimension.
    #[getter]
    fn dim(&self) -> usize {
        self.flow.dim()
    }

    /// Context features per point (0: unconditional).
    #[getter]
    fn context_dim(&self) -> usize {
        self.flow.context_dim()
    }

    /// Number of trainable parameters.
    #[getter]
    fn param_count(&self) -> usize {
        self.flow.param_count()
    }

    /// The flow's configuration as JSON (the library's `FlowConfig`).
    #[getter]
    fn config(&self) -> String {
        serde_json::to_string(self.flow.config()).expect("serialisable")
    }

    fn __repr__(&self) -> String {
        let c = self.flow.config();
        format!(
            "nis.Flow(dim={}, coupling={:?}, layers={}, context_dim={}, hidden_layers={}, \
             hidden_width={}, blob_bins={})",
            c.dim,
            c.transform.label(),
            c.coupling_count(),
            c.context_dim,
            c.hidden_layers,
            c.hidden_width,
            c.blob_bins
        )
    }
}
