"""Type stubs of the compiled module ``nis._nis`` (re-exported by ``nis``)."""

import os
from typing import Any, Callable, Dict, List, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

__version__: str

PathLike = Union[str, "os.PathLike[str]"]
Points = npt.ArrayLike
"""An (n, dim) array-like of float64 points in [0, 1]^dim."""
IntegrandFn = Callable[[npt.NDArray[np.float64]], npt.ArrayLike]
"""f((n, dim) float64 array) -> (n,) values, or (n, k) for a vector integrand."""

class IntegrandError(ValueError):
    """The integrand returned NaN or ±inf; ``point`` holds the point, ``value`` the value."""

    point: npt.NDArray[np.float64]
    value: float

class ModelError(ValueError):
    """A model file that cannot be read back as what it claims to be."""

class IntegrationResult:
    """The outcome of an integration, like a ``vegas`` result; ``str(r)`` is a summary."""

    @property
    def mean(self) -> Union[float, npt.NDArray[np.float64]]:
        """The estimate of ∫ f (an array of k for a vector integrand, one whose f returns shape
        (n, k), k = 1 included)."""
    @property
    def sdev(self) -> Union[float, npt.NDArray[np.float64]]:
        """Its standard error (an array of k for a vector integrand)."""
    @property
    def cov(self) -> Union[float, npt.NDArray[np.float64]]:
        """Covariance of the estimates: k × k for a vector integrand, sdev² for a scalar."""
    @property
    def chi2_dof(self) -> float:
        """χ² per degree of freedom of the final phase's iterations."""
    @property
    def n_eval(self) -> int:
        """All evaluations of the integrand in the call, training included."""
    @property
    def rel_var_per_eval(self) -> float:
        """Var(f/q)/F² per evaluation of the estimate: n·sdev²/mean², n the evaluations that make
        the estimate (``iterations``' or ``channel_evals``' sum; not those that only trained or
        adapted the sampler); smaller is better."""
    @property
    def unweighting_efficiency(self) -> float:
        """mean(|w|)/max(|w|) of the final phase's weights."""
    @property
    def pareto_k(self) -> float:
        """PSIS's Pareto k̂ of the final phase's weights: above ``pareto_k_limit`` the error bar
        cannot be trusted (NaN when it cannot be fitted)."""
    @property
    def pareto_k_limit(self) -> float:
        """The k̂ above which the result warns: 0.5 plus 1.645 standard errors of a k̂ fitted to
        this tail (a one-sided test at 5 % that k > 0.5; inf when k̂ cannot be fitted)."""
    @property
    def tail_end_p(self) -> float:
        """How probable a largest weight as small as the one seen is under the tail k̂ was
        fitted to: below 0.001 the weights end within the sample, and k̂ does not warn if
        ``var_rel_err`` is at most 0.1 too (NaN without a fit)."""
    @property
    def ess(self) -> float:
        """Effective sample size (Σ|w|)²/Σw² of the final phase's weights."""
    @property
    def var_rel_err(self) -> float:
        """Relative error of the variance estimate behind ``sdev``."""
    @property
    def seconds(self) -> float:
        """Wall time of the call."""
    @property
    def stop(self) -> Optional[str]:
        """Why a run to a precision target stopped: "target", "max_evals" or "max_seconds"
        (None for a run on a budget)."""
    @property
    def answered_by(self) -> Optional[str]:
        """The method whose sampler made the estimate when it is not the integrator's own:
        "vegas" when NIS, integrating to a target, left it to VEGAS+, which met it first with
        no warning (None otherwise)."""
    @property
    def warnings(self) -> List[str]:
        """What the user should know (e.g. a large χ²/dof)."""
    @property
    def iterations(self) -> List[Tuple[float, float, int]]:
        """The final phase's iterations: (estimate, variance, evaluations)."""
    @property
    def channel_weights(self) -> Optional[npt.NDArray[np.float64]]:
        """Multi-channel results: each channel's a-priori weight in the estimate (summing to 1);
        None for a single-channel result."""
    @property
    def channel_means(self) -> Optional[npt.NDArray[np.float64]]:
        """Multi-channel results: each channel's weighted share ∫ α_k f of the integral (α_k the
        channel weights, which sum to one at every point; the shares sum to ``mean``). Not the
        integral of the peak the channel maps: a share depends on the weights."""
    @property
    def channel_sdevs(self) -> Optional[npt.NDArray[np.float64]]:
        """Multi-channel results: the standard errors of ``channel_means``."""
    @property
    def channel_evals(self) -> Optional[npt.NDArray[np.uint64]]:
        """Multi-channel results: the estimate's evaluations in each channel."""
    @property
    def signs(self) -> Optional[Dict[str, float]]:
        """When the integrand was split by sign: ``positive`` (∫ max(f, 0)), ``positive_sdev``,
        ``negative`` (∫ max(−f, 0)), ``negative_sdev``, ``negative_fraction``
        (negative/(positive + negative)), and the estimate's evaluations of each sign's parts,
        ``positive_evals`` and ``negative_evals``; None otherwise."""
    def summary(self) -> str:
        """The readable summary, ``str(r)``."""

class Integrator:
    """A Monte Carlo integrator over [0, 1]^dim that owns its adapted state, like
    ``vegas.Integrator``. ``method``: "nis", "vegas" or "uniform". ``threads``: run in a rayon
    pool of that size. Every other keyword is a setting, read by the library's one reader of
    settings (the C ABI's JSON and the CLI's flags go through it too): a field of the chosen
    method's settings, or a shorthand for one. A keyword of another method, an unknown one or
    an ill-typed value raises ValueError naming it; None leaves the setting at its default.

    All methods: ``seed``. NIS: ``coupling`` ("pq", "pl", "rq", "affine"), ``bins``,
    ``layers`` (coupling layers), ``masks`` ("binary", the paper's, the default; "codes",
    fewer layers for a cheaper flow with a higher variance per evaluation, for cheap
    integrands; it misses modes more often, so check it against a second seed or method),
    ``hidden_layers``, ``hidden_width``, ``blob_bins``, ``flow`` (the flow's settings as a
    dict, e.g. ``{"hidden_width": 64}``), ``loss`` ("auto", the default: "kl" for one
    integrand, "chi2" for the parts of a multi-channel integral; "kl" or "chi2" forces one),
    ``batch``, ``steps_per_batch``, ``train_fraction``, ``learning_rate``, ``adam`` (the optimiser's
    settings as a dict, e.g. ``{"beta1": 0.95}``), ``learning_rate_end``, ``average_span``
    (the moving average of the flow's weights that the final phase samples spans this share of
    the first training's batches; default 0.1, 0 the last training step's weights),
    ``uniform_fraction``, ``anneal_from``, ``final_iterations``, ``stratify`` (the final
    phase's latent cut into adaptive hypercubes, as VEGAS+ does; default True, False draws it
    i.i.d., a dict sets ``beta``, ``min_per_cube``, ``max_cubes``), ``reuse_training`` (share
    of the training batches, the last ones, in the estimate; default 0.5, 0 the final phase
    alone; docs/ESTIMATE.md), ``replay_batches``, ``replay_steps`` (earlier batches replayed
    off-policy in training), ``auto_masks`` (to a precision target, an untrained flow of
    binary masks switches to the codes' fewer layers when its first batches show a smooth
    integrand; default True, and naming ``masks`` turns it off), ``race_vegas`` (to a precision
    target, an untrained flow races VEGAS+ after ten batches and leaves the answer to it when it
    meets the target first with no warning, ``r.answered_by``; default True). VEGAS+:
    ``increments``, ``alpha``, ``beta``, ``iterations``, ``warmup``, ``min_per_cube``. Plain MC: ``iterations``. NIS and VEGAS+: ``train_on``
    (component index or "sum_abs").

    Multi-channel integration: ``channels``, a non-empty list of ``Channel`` (mappings of the
    cube, one per peak, with their priors), makes an integrator that integrates
    ∫ f = Σ_k ∫ α_k f, α_k = a_k g_k/Σ_j a_j g_j, with a sampler of ``method`` per channel;
    the priors adapt between adapting and estimating. ``signs``: "auto" (the default with
    channels: split f into f⁺ and f⁻, a sampler each, when a pilot sees both signs), "split"
    (always) or "whole" (never). Without ``channels`` and ``signs``, NIS splits a scalar
    integrand whose first points show both signs (auto is the default); VEGAS+ and plain MC keep
    the whole; vector integrands always do. ``signs`` without ``channels`` splits a single-channel
    integral by sign. Such an integrator integrates scalar integrands on a budget
    (``integ(f, evals)``) or to a precision target (``integ(f, rel_err=…)``), its results carry
    ``channel_weights``, ``channel_means``, ``channel_sdevs``, ``channel_evals`` and
    ``signs``, ``events(f, n)`` draws unweighted events that carry their channel (NIS), and the
    other NIS-only methods (``train``, ``estimate``, ``sample``, ``unweighted``, ``save``,
    ``flow``, ``trained_evals``) raise ValueError. ``channel_settings``, a dict:
    ``adapt_fraction`` (share of a call's evaluations the samplers adapt on, default 0.25),
    ``adapt_weights`` (whether the priors adapt, default True), ``weight_floor`` (smallest
    weight a channel keeps, as a fraction of 1/K, default 0.01), ``pilot`` (uniform points per
    channel of the pilot that decides the sign split, default 1000), ``target_adapt``
    (evaluations each sampler adapts on in a run to a target, default 100000), ``shared_flow``
    (NIS: one flow for every channel and sign, conditioned on it, the default; False: a flow
    each), ``weight_network`` (NIS: refine the channel weights with a network fitted after the
    samplers adapt, kept when it lowers the variance on held-out points; default True).
    """

    def __init__(
        self,
        dim: int,
        method: str = "nis",
        *,
        channels: Optional[Sequence["Channel"]] = None,
        signs: Optional[str] = None,
        channel_settings: Optional[Dict[str, Any]] = None,
        threads: Optional[int] = None,
        seed: Optional[int] = None,
        coupling: Optional[str] = None,
        bins: Optional[int] = None,
        layers: Optional[int] = None,
        masks: Optional[str] = None,
        hidden_layers: Optional[int] = None,
        hidden_width: Optional[int] = None,
        blob_bins: Optional[int] = None,
        flow: Optional[Dict[str, Any]] = None,
        loss: Optional[str] = None,
        batch: Optional[int] = None,
        steps_per_batch: Optional[int] = None,
        train_fraction: Optional[float] = None,
        learning_rate: Optional[float] = None,
        adam: Optional[Dict[str, Any]] = None,
        learning_rate_end: Optional[float] = None,
        average_span: Optional[float] = None,
        uniform_fraction: Optional[float] = None,
        anneal_from: Optional[float] = None,
        final_iterations: Optional[int] = None,
        stratify: Optional[Union[bool, Dict[str, Any]]] = None,
        reuse_training: Optional[float] = None,
        replay_batches: Optional[int] = None,
        replay_steps: Optional[int] = None,
        auto_masks: Optional[bool] = None,
        race_vegas: Optional[bool] = None,
        increments: Optional[int] = None,
        alpha: Optional[float] = None,
        beta: Optional[float] = None,
        iterations: Optional[int] = None,
        warmup: Optional[int] = None,
        min_per_cube: Optional[int] = None,
        train_on: Optional[Union[int, str, Dict[str, int]]] = None,
    ) -> None: ...
    def __call__(
        self,
        f: IntegrandFn,
        evals: Optional[int] = None,
        *,
        rel_err: Optional[float] = None,
        abs_err: Optional[float] = None,
        max_evals: Optional[int] = None,
        max_seconds: Optional[float] = None,
    ) -> IntegrationResult:
        """Spends ``evals`` evaluations of ``f`` (10⁶ when neither ``evals`` nor a target is
        given): adapts on a share of them (continuing from earlier calls), then estimates ∫ f with
        the rest, the sampler frozen; returns an ``IntegrationResult``.

        With ``rel_err`` and/or ``abs_err`` instead of ``evals`` it integrates until
        ``sdev <= max(abs_err, rel_err * |mean|)`` or a limit is reached: ``max_evals``
        (default 10⁸, training included) or ``max_seconds``. ``r.stop`` then says which
        ("target", "max_evals", "max_seconds"); a limit is a warning, not an error. NIS decides
        how long to train from the costs it measures. A target that cannot be met raises
        ``ValueError`` before ``f`` is called.

        ``f`` takes an (n, dim) float64 array and returns n values, shape (n,), or n vectors,
        shape (n, k): every component is then estimated from the same points, with covariance,
        and ``mean``, ``sdev`` and ``cov`` are arrays. An f returning shape (n, 1) is such a
        vector integrand of one component (its result's warnings say so); return shape (n,) for
        floats. f is called on whole batches, with the GIL held only then. An exception raised by
        f propagates unchanged; NaN or inf raise ``nis.IntegrandError``; Ctrl-C raises
        KeyboardInterrupt at the next batch. Each of the result's ``warnings`` (an error bar that
        cannot be trusted, a sampler that had not converged) is also raised as a ``UserWarning``.

        A multi-channel integrator (made with ``channels`` or ``signs``) takes scalar integrands,
        on a budget or to a precision target.
        """
    def train(self, f: IntegrandFn, evals: int) -> None:
        """NIS only: trains on ``evals`` more evaluations without estimating."""
    def estimate(self, f: IntegrandFn, evals: int = 1_000_000) -> IntegrationResult:
        """NIS only: estimates with the flow frozen (e.g. after ``load``)."""
    def sample(
        self, f: IntegrandFn, n: int
    ) -> Tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """NIS only: ``(x, w)``, n weighted points and their weights f/q."""
    def unweighted(
        self, f: IntegrandFn, n: int, overweight: float = 1e-3
    ) -> Tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """NIS only: ``(x, w)``, n unweighted points of |f| and their residual weights
        sign(f)·max(1, |w|/w_max)."""
    def events(
        self, f: IntegrandFn, n: int, overweight: float = 1e-3
    ) -> Tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.uint64]]:
        """Multi-channel NIS only: ``(x, w, channel)``, n unweighted events of |f| through the
        channels, their residual weights (negative where f < 0) and the channel of each."""
    def save(self, path: PathLike) -> None:
        """NIS only: saves the trained integrator (safetensors, as ``nis integrate --save``)."""
    @staticmethod
    def load(path: PathLike, *, threads: Optional[int] = None) -> "Integrator":
        """Loads an integrator saved by ``save`` or the CLI."""
    @property
    def method(self) -> str: ...
    @property
    def dim(self) -> int: ...
    @property
    def threads(self) -> Optional[int]: ...
    @property
    def channels(self) -> Optional[int]:
        """The number of channels (None for a single-channel integrator, 1 for ``signs``
        alone)."""
    @property
    def channel_weights(self) -> Optional[npt.NDArray[np.float64]]:
        """The a-priori channel weights the next call starts from (they adapt)."""
    @property
    def flow(self) -> "Flow":
        """NIS only: a copy of the trained flow."""
    @property
    def trained_evals(self) -> int:
        """NIS only: evaluations spent training so far."""

class Flow:
    """A coupling flow on [0, 1]^dim with a uniform latent, as a distribution (zuko /
    torch.distributions conventions). A new flow is the uniform density. ``masks``: "binary"
    (the paper's layers) or "codes" (fewer layers, see ``Integrator``)."""

    def __init__(
        self,
        dim: int,
        coupling: str = "pq",
        bins: int = 16,
        layers: Optional[int] = None,
        context_dim: int = 0,
        *,
        hidden_layers: int = 2,
        hidden_width: int = 32,
        blob_bins: int = 16,
        masks: str = "binary",
        seed: int = 0,
    ) -> None: ...
    def sample(
        self, n: int, context: Optional[npt.ArrayLike] = None
    ) -> Tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """``(x, log_q)``: n points of shape (n, dim) and their log-density."""
    def log_prob(
        self, x: Points, context: Optional[npt.ArrayLike] = None
    ) -> npt.NDArray[np.float64]:
        """ln q(x) of each row of x."""
    def fit(
        self,
        data: Points,
        *,
        epochs: int = 10,
        batch: int = 256,
        learning_rate: float = 1e-3,
        context: Optional[npt.ArrayLike] = None,
    ) -> List[float]:
        """Maximum likelihood on data in [0, 1]^dim; returns each epoch's mean NLL (nats)."""
    def fit_integrand(
        self,
        f: IntegrandFn,
        *,
        evals: int = 100_000,
        loss: str = "kl",
        batch: int = 1024,
        learning_rate: float = 5e-3,
    ) -> List[float]:
        """Learns |f|/∫|f| on-policy (loss "kl" or "chi2"); returns each batch's Var(f/q)/F²."""
    def save(self, path: PathLike) -> None:
        """Saves as a safetensors model file (``nis::io``, as the CLI writes)."""
    @staticmethod
    def load(path: PathLike, *, seed: int = 0) -> "Flow":
        """Loads a flow saved by ``save``, ``Integrator.save`` or the CLI."""
    @property
    def dim(self) -> int: ...
    @property
    def context_dim(self) -> int: ...
    @property
    def param_count(self) -> int: ...
    @property
    def config(self) -> str:
        """The flow's configuration as JSON."""

class Builtin:
    """A built-in integrand of the suite with its exact integral (see ``nis.integrands``)."""

    def __init__(self, name: str, dim: Optional[int] = None) -> None: ...
    def __call__(self, x: Points) -> npt.NDArray[np.float64]:
        """f at each row of the (n, dim) array x."""
    @property
    def name(self) -> str: ...
    @property
    def dim(self) -> int: ...
    @property
    def exact(self) -> float: ...
    @property
    def exact_err(self) -> float: ...
    @property
    def source(self) -> str: ...

class Channel:
    """A channel of multi-channel integration: a map of the unit cube onto [0, 1]^d and the
    density of its points, with an a-priori weight ``prior`` (finite, > 0).

    ``sample`` takes an (n, d) float64 array u of uniform points and returns x, shape (n, d),
    inside the cube; ``density`` takes an (n, d) array x (any points of the cube) and returns
    g(x), shape (n,): the density of ``sample``'s points, finite and ≥ 0 (> 0 where the channel
    puts points). Both are called on whole batches with the GIL held only then; an exception
    they raise propagates unchanged; wrong shapes, points outside the cube and NaN or negative
    densities raise ValueError naming the channel's index and the point. ``dim``, if given, is
    checked against the integrator's. ``enhancement``, if given, takes an (n, d) array x and
    returns w(x) ≥ 0, shape (n,), large where the channel's peak is (its diagram's |M|², its
    propagator): the channel weights become α_k = a_k w_k / Σ_j a_j w_j (single-diagram
    enhancement; w_j counts only where channel j's density is > 0) instead of a_k g_k / Σ_j a_j g_j.
    Built-in examples' channels (with their propagators as enhancements):
    ``nis.integrands.channels(name)``.
    """

    def __init__(
        self,
        sample: Callable[[npt.NDArray[np.float64]], npt.ArrayLike],
        density: Callable[[npt.NDArray[np.float64]], npt.ArrayLike],
        prior: float = 1.0,
        *,
        dim: Optional[int] = None,
        enhancement: Optional[Callable[[npt.NDArray[np.float64]], npt.ArrayLike]] = None,
    ) -> None: ...
    def sample(self, u: Points) -> npt.NDArray[np.float64]:
        """x for the uniform points u, checked as an integrator checks them."""
    def density(self, x: Points) -> npt.NDArray[np.float64]:
        """g at each row of x."""
    @property
    def prior(self) -> float: ...
    @property
    def dim(self) -> Optional[int]: ...
    @property
    def name(self) -> Optional[str]:
        """A built-in channel's name ("resonances-4d[0]"); None for a Python one."""

def example_names() -> List[str]:
    """The multi-channel examples' names (``nis.integrands.examples()``)."""

def example_channels(name: str) -> List[Channel]:
    """The channels of a multi-channel example (``nis.integrands.channels(name)``)."""

def suite() -> List[Tuple[str, List[int], str]]:
    """The suite: (name, benchmark dimensions, description) per member."""

def _keywords() -> List[str]:
    """The settings keywords ``Integrator`` takes, from the library's schema (for the tests)."""
