"""nis.Integrator: settings, results, errors from f, vector integrands, agreement with Rust."""

import math
import os
import signal
import threading

import numpy as np
import pytest

import nis
from conftest import gauss_np


def within(r, exact, sigmas=5.0):
    return abs(r.mean - exact) < sigmas * r.sdev


# The Rust test `results_are_bit_identical_to_the_recorded_ones` (crates/nis/tests/integration.rs):
# gauss in 2-d, seed 5, 10^5 evaluations, default settings.
RECORDED = {
    "nis": ("0.9990956460590507", "0.00015733138761886862"),
    "vegas": ("0.9991289316819392", "0.00017338791639042743"),
    "uniform": ("0.9975623516355743", "0.005446123321194651"),
}


@pytest.mark.parametrize("method", sorted(RECORDED))
def test_results_are_bit_identical_to_the_rust_ones(method):
    g = nis.integrands.gauss(dim=2)
    # A built-in evaluates in Rust; wrapped in a lambda it goes through the Python callback
    # path with numpy batches. Both must give the Rust test's bits.
    for f in (g, lambda x: g(x)):
        r = nis.Integrator(2, method, seed=5)(f, evals=100_000)
        assert (repr(r.mean), repr(r.sdev)) == RECORDED[method]
        assert r.n_eval == 100_000


def test_stratify_false_gives_the_i_i_d_final_phase():
    # Without stratification and without training in the estimate (reuse_training=0) the final
    # phase draws i.i.d. latents: the bits `nis integrate gauss --dim 2 --evals 100000 --seed 5
    # --method nis --nis-config '{"stratify": null, "reuse_training": 0}'` gives. Stratified, the
    # same flow has less than half the error bar on this 2-d Gaussian.
    g = nis.integrands.gauss(dim=2)
    iid = nis.Integrator(2, "nis", seed=5, stratify=False, reuse_training=0)(g, evals=100_000)
    assert (repr(iid.mean), repr(iid.sdev)) == ("0.9989264161900435", "0.0003675489275197983")
    # Stratified with the final phase alone.
    alone = nis.Integrator(2, "nis", seed=5, stratify=True, reuse_training=0)(g, evals=100_000)
    assert (repr(alone.mean), repr(alone.sdev)) == ("0.9990974168222485", "0.00015856168951298977")
    strat = nis.Integrator(2, "nis", seed=5, stratify=True)(g, evals=100_000)
    assert (repr(strat.mean), repr(strat.sdev)) == RECORDED["nis"]
    assert strat.sdev < 0.6 * iid.sdev
    with pytest.raises(ValueError, match="stratify"):
        nis.Integrator(2, "vegas", stratify=False)


def test_a_numpy_integrand_agrees_with_the_rust_result_for_the_same_seed(gauss):
    # The same function in numpy: where numpy's exp gives libm's bits (checked here on many
    # points), the whole run must give the Rust bits; otherwise the runs part after the first
    # differing value and agree only statistically.
    g = nis.integrands.gauss(dim=2)
    x = np.random.default_rng(0).random((100_000, 2))
    r = nis.Integrator(2, "nis", seed=5)(gauss, evals=100_000)
    if np.array_equal(g(x), gauss(x)):
        assert (repr(r.mean), repr(r.sdev)) == RECORDED["nis"]
    else:
        assert abs(r.mean - float(RECORDED["nis"][0])) < 5 * math.sqrt(2) * r.sdev


def test_chi2_loss_on_camel_matches_the_recorded_bits():
    camel = nis.integrands.camel(dim=4)
    r = nis.Integrator(4, "nis", loss="chi2", seed=3)(lambda x: camel(x), evals=200_000)
    assert (r.mean, r.sdev) == (0.9636228957670196, 0.00042528498456387314)


def test_a_numpy_integrand_agrees_with_the_exact_value_and_the_result_reads_well(gauss):
    g = nis.integrands.gauss(dim=3)
    integ = nis.Integrator(dim=3, method="nis", coupling="pq", loss="kl", seed=1)
    r = integ(gauss, evals=100_000)
    assert within(r, g.exact)
    assert 0 < r.rel_var_per_eval < 1 and 0 < r.unweighting_efficiency <= 1
    assert r.chi2_dof > 0 and r.seconds > 0 and r.n_eval == 100_000
    assert isinstance(r.mean, float) and isinstance(r.cov, float)
    assert math.isclose(r.cov, r.sdev**2)
    # k̂ warns above 0.5 + 1.645·1.5/√M, M = 3√n tail weights: 0.58–0.61 for 2·10⁴–10⁵ weights.
    assert 0.55 < r.pareto_k_limit < 0.65 and r.pareto_k < r.pareto_k_limit
    # The probability of a largest weight as small as the one seen under the fitted tail.
    assert 0 <= r.tail_end_p <= 1
    text = str(r)
    # The 10 groups of the training batches that join the estimate (reuse_training 0.5 by
    # default), then the final phase's 10 iterations: the pieces the χ²/dof compares.
    assert "result" in text and "χ²/dof" in text and len(r.iterations) == 20
    assert text == r.summary() and "IntegrationResult(" in repr(r)


def test_the_flow_of_fewer_layers_integrates_honestly(gauss):
    # masks="codes": 5 coupling layers at d = 8 instead of the paper's 6.
    exact = nis.integrands.gauss(dim=8).exact
    r = nis.Integrator(8, masks="codes", seed=2)(gauss, evals=100_000)
    assert within(r, exact)
    default = nis.Integrator(8, seed=2)(gauss, evals=100_000)
    assert within(default, exact) and r.mean != default.mean


def test_a_second_call_adapts_further(gauss):
    integ = nis.Integrator(2, seed=2)
    r1 = integ(gauss, evals=50_000)
    trained = integ.trained_evals
    r2 = integ(gauss, evals=50_000)
    assert integ.trained_evals > trained
    exact = nis.integrands.gauss(dim=2).exact
    assert within(r1, exact) and within(r2, exact)


@pytest.mark.parametrize("method", ["vegas", "uniform"])
def test_baselines_estimate_the_exact_value(method, gauss):
    r = nis.Integrator(2, method, seed=4)(gauss, evals=100_000)
    assert within(r, nis.integrands.gauss(dim=2).exact)


def test_a_thread_pool_of_one_gives_the_same_bits(gauss):
    a = nis.Integrator(2, seed=9)(gauss, evals=30_000)
    b = nis.Integrator(2, seed=9, threads=1)(gauss, evals=30_000)
    assert (a.mean, a.sdev) == (b.mean, b.sdev)


@pytest.mark.parametrize(
    "kwargs",
    [
        dict(method="bogus"),
        dict(coupling="spline"),
        dict(masks="gray"),
        dict(method="vegas", masks="codes"),
        dict(bins=-1),
        dict(bins=0),
        dict(train_fraction=1.5),
        dict(uniform_fraction=float("nan")),
        dict(average_span=1.5),
        dict(method="vegas", average_span=0.5),
        dict(loss="nll"),
        dict(batch=1),
        dict(train_on="everything"),
        dict(train_on=-1),
        dict(threads=0),
        dict(seed=-1),
        dict(method="vegas", coupling="pq"),
        dict(method="uniform", alpha=0.5),
        dict(method="nis", iterations=5),
        dict(method="uniform", train_on=0),
        dict(method="vegas", iterations=3, warmup=3),
    ],
)
def test_bad_settings_raise_value_error(kwargs):
    with pytest.raises(ValueError):
        nis.Integrator(2, **kwargs)


def test_bad_arguments_raise_value_error(gauss):
    # A dimension below 1 says what is allowed, in words, whether 0 or negative.
    for dim in (0, -1):
        with pytest.raises(ValueError, match=r"dim must be a positive integer \(1 or more\)"):
            nis.Integrator(dim)
        with pytest.raises(ValueError, match=r"dim must be a positive integer \(1 or more\)"):
            nis.integrands.gauss(dim=dim)
    integ = nis.Integrator(2, seed=0)
    with pytest.raises(ValueError):
        integ(gauss, evals=-5)
    with pytest.raises(ValueError, match="callable"):
        integ(42, evals=1000)
    with pytest.raises(ValueError, match="dimension"):
        integ(nis.integrands.gauss(dim=3), evals=10_000)


@pytest.mark.parametrize(
    "f",
    [
        lambda x: np.zeros((x.shape[0], 2, 2)),
        lambda x: np.zeros(x.shape[0] + 1),
        lambda x: 1.0,
        lambda x: ["a"] * x.shape[0],
    ],
)
def test_integrands_of_the_wrong_shape_raise_value_error(f):
    with pytest.raises(ValueError):
        nis.Integrator(2, seed=0)(f, evals=10_000)


def test_a_length_change_after_the_first_batch_is_caught():
    calls = []

    def f(x):
        calls.append(len(x))
        return np.ones(len(x) if len(calls) < 3 else len(x) - 1)

    with pytest.raises(ValueError, match="shape"):
        nis.Integrator(2, seed=0)(f, evals=50_000)


class DetectorCrash(Exception):
    pass


@pytest.mark.parametrize("method", ["nis", "vegas", "uniform"])
def test_an_exception_in_f_propagates_as_itself(method, gauss):
    raised = DetectorCrash("simulation crashed")
    calls = [0]

    def f(x):
        calls[0] += 1
        if calls[0] == 4:
            raise raised
        return gauss(x)

    integ = nis.Integrator(2, method, seed=0)
    with pytest.raises(DetectorCrash) as info:
        integ(f, evals=200_000)
    assert info.value is raised
    assert calls[0] == 4  # the run stopped at the failing batch
    # The integrator is still usable.
    assert within(integ(gauss, evals=50_000), nis.integrands.gauss(dim=2).exact)


def test_keyboard_interrupt_raised_in_f_propagates(gauss):
    calls = [0]

    def f(x):
        calls[0] += 1
        if calls[0] == 3:
            raise KeyboardInterrupt
        return gauss(x)

    with pytest.raises(KeyboardInterrupt):
        nis.Integrator(2, seed=0)(f, evals=200_000)
    assert calls[0] == 3


@pytest.mark.skipif(threading.current_thread() is not threading.main_thread(), reason="signals")
@pytest.mark.parametrize("threads", [None, 1])
def test_ctrl_c_interrupts_a_run_between_batches(gauss, threads):
    # A real SIGINT, as Ctrl-C sends it, in the middle of a long run.
    calls = [0]
    after = [0]

    def f(x):
        calls[0] += 1
        if calls[0] == 5:
            os.kill(os.getpid(), signal.SIGINT)
        if calls[0] > 5:
            after[0] += 1
        return gauss(x)

    integ = nis.Integrator(2, seed=0, threads=threads)
    # Python's own handler, whatever the parent left: a process started in the background by a
    # non-interactive shell inherits SIGINT ignored, and then Ctrl-C reaches nobody.
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt):
            integ(f, evals=50_000_000)  # minutes if not interrupted
    finally:
        signal.signal(signal.SIGINT, previous)
    assert after[0] < 1000, "the run went on long after Ctrl-C"


def test_nan_raises_integrand_error_naming_the_point(gauss):
    def f(x):
        y = gauss(x)
        y[x[:, 0] > 0.95] = np.nan
        return y

    with pytest.raises(nis.IntegrandError) as info:
        nis.Integrator(2, seed=0)(f, evals=100_000)
    e = info.value
    assert isinstance(e, ValueError)
    assert "NaN" in str(e) and "point" in str(e)
    assert e.point.shape == (2,) and e.point[0] > 0.95 and math.isnan(e.value)


def test_inf_raises_integrand_error_for_vegas_too():
    def f(x):
        with np.errstate(divide="ignore"):
            return 1.0 / (x[:, 0] > 0.5)

    with pytest.raises(nis.IntegrandError, match="inf"):
        nis.Integrator(2, "vegas", seed=0)(f, evals=50_000)


def test_vector_integrands_come_with_their_covariance(gauss):
    # f, x0·f and x1·f of the centred Gaussian: ∫ x_i f = ½ ∫ f by symmetry.
    def f(x):
        g = gauss(x)
        return np.stack([g, x[:, 0] * g, x[:, 1] * g], axis=1)

    for method in ["nis", "vegas", "uniform"]:
        r = nis.Integrator(2, method, seed=6)(f, evals=100_000)
        assert r.mean.shape == (3,) and r.sdev.shape == (3,) and r.cov.shape == (3, 3)
        assert np.allclose(r.cov, r.cov.T)
        assert np.all(np.linalg.eigvalsh(r.cov) > -1e-12 * np.abs(r.cov).max())
        assert np.allclose(np.sqrt(np.diag(r.cov)), r.sdev)
        exact = nis.integrands.gauss(dim=2).exact
        assert abs(r.mean[0] - exact) < 5 * r.sdev[0]
        # mean_1 − ½ mean_0 has variance c11 + ¼ c00 − c01; the points are shared, so the
        # covariance (not the two error bars) sets how well it cancels.
        d = r.mean[1] - 0.5 * r.mean[0]
        var = r.cov[1, 1] + 0.25 * r.cov[0, 0] - r.cov[0, 1]
        assert abs(d) < 5 * math.sqrt(var) + 1e-15
        # Positively correlated: far smaller than if the two estimates were independent.
        assert var < 0.5 * (r.cov[1, 1] + 0.25 * r.cov[0, 0])
        assert "component 2" in str(r)


def test_train_on_chooses_the_component(gauss):
    def f(x):
        g = gauss(x)
        return np.stack([x[:, 0], g], axis=1)

    exact = nis.integrands.gauss(dim=2).exact
    r0 = nis.Integrator(2, seed=1)(f, evals=60_000)
    r1 = nis.Integrator(2, seed=1, train_on=1)(f, evals=60_000)
    rs = nis.Integrator(2, seed=1, train_on="sum_abs")(f, evals=60_000)
    for r in (r0, r1, rs):
        assert abs(r.mean[1] - exact) < 5 * r.sdev[1] and abs(r.mean[0] - 0.5) < 5 * r.sdev[0]
    assert r1.sdev[1] < r0.sdev[1]  # the flow learned the peaked component
    with pytest.raises(ValueError, match="component"):
        nis.Integrator(2, seed=1, train_on=2)(f, evals=10_000)


def test_a_builtin_object_is_callable_and_knows_its_value():
    c = nis.integrands.camel(dim=8)
    assert (c.name, c.dim) == ("camel", 8)
    assert math.isclose(c.exact, (0.5 * (math.erf(1 / 0.6) + math.erf(2 / 0.6))) ** 8)
    y = c(np.full((3, 8), 1 / 3))
    assert y.shape == (3,) and np.all(y == y[0]) and y[0] > 1
    assert nis.integrands.camel_sharp(dim=2).name == "camel-sharp"
    assert nis.integrands.circles().dim == 2
    with pytest.raises(ValueError):
        c(np.zeros((3, 7)))
    with pytest.raises(ValueError):
        nis.integrands.circles(dim=3)
    assert "camel" in repr(c)


def test_the_suite_functions_match_the_rust_suite_and_the_stubs():
    names = nis.integrands.names()
    assert "camel-sharp" in names and len(names) >= 13
    assert sorted(nis.integrands.__all__) == sorted(n.replace("-", "_") for n in names)
    stub = os.path.join(os.path.dirname(nis.integrands.__file__), "integrands.pyi")
    with open(stub, encoding="utf-8") as fh:
        text = fh.read()
    for n in names:
        assert f"def {n.replace('-', '_')}(" in text
        assert getattr(nis.integrands, n.replace("-", "_"))().name == n


def test_the_package_is_typed_and_versioned():
    here = os.path.dirname(nis.__file__)
    assert os.path.exists(os.path.join(here, "py.typed"))
    assert os.path.exists(os.path.join(here, "_nis.pyi"))
    assert nis.__version__.count(".") == 2
    assert issubclass(nis.IntegrandError, ValueError)
    assert issubclass(nis.ModelError, ValueError)
    # Signatures an editor shows: from the compiled methods and from the stubs.
    assert "evals" in nis.Integrator.train.__text_signature__
    assert "epochs" in nis.Flow.fit.__text_signature__
    assert "evals=1000000" in nis.Integrator.estimate.__text_signature__
    with open(os.path.join(here, "_nis.pyi"), encoding="utf-8") as fh:
        stub = fh.read()
    assert "evals: Optional[int] = None," in stub and "rel_err: Optional[float] = None," in stub
    assert nis.Integrator.__doc__ and nis.Flow.fit.__doc__ and nis.IntegrationResult.__doc__
