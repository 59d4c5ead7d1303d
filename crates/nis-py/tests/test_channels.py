"""Multi-channel integration and sign splitting from Python: nis.Channel, nis.Integrator's
`channels` and `signs`, the per-channel parts of a result, the built-in examples' channels, and
the errors of bad channels (which name the channel)."""

import os
import signal
import threading

import numpy as np
import pytest

import nis

# Two Cauchy (Breit–Wigner) peaks on [0, 1]^2, each a product of L(t) = γ/((t − m)² + γ²)
# in both coordinates: f = c₁ L₁(x₀) L₁(x₁) + c₂ L₂(x₀) L₂(x₁). With
# I(m) = ∫₀¹ L = atan((1 − m)/γ) + atan(m/γ), the exact value is c₁ I₁² + c₂ I₂².
GAMMA = 0.02
PEAKS = [(0.3, 1.0), (0.75, 2.0)]  # (m, c)


def lorentz(t, m):
    return GAMMA / ((t - m) ** 2 + GAMMA**2)


def mass(m):
    return np.arctan((1 - m) / GAMMA) + np.arctan(m / GAMMA)


EXACT = sum(c * mass(m) ** 2 for m, c in PEAKS)


def two_peaks(x):
    return sum(c * lorentz(x[:, 0], m) * lorentz(x[:, 1], m) for m, c in PEAKS)


def tan_channel(m, dim=None, prior=1.0):
    """The tan mapping that flattens L around m in every coordinate: t = m + γ tan θ with θ
    uniform between atan(−m/γ) and atan((1 − m)/γ), so g(t) = L(t)/I(m), exactly normalised on
    [0, 1]."""
    lo, hi = -np.arctan(m / GAMMA), np.arctan((1 - m) / GAMMA)

    def sample(u):
        return np.clip(m + GAMMA * np.tan(lo + u * (hi - lo)), 0.0, 1.0)

    def density(x):
        return np.prod(lorentz(x, m) / (hi - lo), axis=1)

    return nis.Channel(sample, density, prior, dim=dim)


def channels():
    return [tan_channel(m) for m, _ in PEAKS]


def within(r, exact, sigmas=4.0, exact_err=0.0):
    return abs(r.mean - exact) < sigmas * r.sdev + exact_err


@pytest.mark.parametrize(
    "method, evals", [("nis", 100_000), ("vegas", 200_000), ("uniform", 200_000)]
)
def test_two_cauchy_peaks_are_unbiased_with_every_method(method, evals):
    integ = nis.Integrator(2, method, channels=channels(), seed=1)
    assert integ.channels == 2 and integ.method == method
    r = integ(two_peaks, evals=evals)
    assert within(r, EXACT), (r.mean, r.sdev, EXACT)
    assert r.channel_weights.dtype == np.float64 and r.channel_weights.shape == (2,)
    assert abs(r.channel_weights.sum() - 1) < 1e-12
    assert r.channel_means.shape == r.channel_sdevs.shape == (2,)
    assert abs(r.channel_means.sum() - r.mean) < 1e-9 * abs(r.mean)
    assert np.isclose(np.sqrt((r.channel_sdevs**2).sum()), r.sdev, rtol=1e-9)
    assert r.channel_evals.dtype in (np.uint64, np.int64) and (r.channel_evals > 0).all()
    assert r.signs is None  # f > 0: no split
    # Each channel carries (nearly all of) its own peak.
    for k, (m, c) in enumerate(PEAKS):
        assert abs(r.channel_means[k] - c * mass(m) ** 2) < 0.02 * EXACT


@pytest.mark.parametrize("method", ["nis", "uniform"])
def test_enhancements_keep_the_integral_and_a_bad_one_is_named(method):
    # Each channel's enhancement is its peak's propagator: α_k ∝ a_k L_k(x₀)L_k(x₁).
    def enhanced(m):
        c = tan_channel(m)
        return nis.Channel(
            c.sample, c.density, enhancement=lambda x: lorentz(x[:, 0], m) * lorentz(x[:, 1], m)
        )

    r = nis.Integrator(2, method, channels=[enhanced(m) for m, _ in PEAKS], seed=3)(
        two_peaks, evals=100_000
    )
    assert within(r, EXACT), (r.mean, r.sdev, EXACT)
    bad = nis.Channel(
        lambda u: u, lambda x: np.ones(len(x)), enhancement=lambda x: -np.ones(len(x))
    )
    with pytest.raises(ValueError, match="channel 1.*enhancement"):
        nis.Integrator(2, method, channels=[tan_channel(0.3), bad])(two_peaks, evals=10_000)
    with pytest.raises(ValueError, match="enhancement must be callable"):
        nis.Channel(lambda u: u, lambda x: np.ones(len(x)), enhancement=1.0)


def test_multi_channel_beats_uniform_sampling_by_far():
    evals = 200_000
    multi = nis.Integrator(2, "uniform", channels=channels(), seed=2)(two_peaks, evals=evals)
    plain = nis.Integrator(2, "uniform", seed=2)(two_peaks, evals=evals)
    assert within(multi, EXACT)
    assert multi.sdev < 0.05 * plain.sdev, (multi.sdev, plain.sdev)
    assert plain.channel_weights is None and plain.channel_means is None
    assert plain.channel_sdevs is None and plain.channel_evals is None and plain.signs is None


def test_priors_set_the_starting_weights():
    a, b = PEAKS[0][0], PEAKS[1][0]
    integ = nis.Integrator(2, "vegas", channels=[tan_channel(a, prior=1), tan_channel(b, prior=3)])
    assert np.allclose(integ.channel_weights, [0.25, 0.75])
    assert "Channel" in repr(tan_channel(a))


def test_channel_settings_tune_the_multi_channel_integrator():
    a, b = PEAKS[0][0], PEAKS[1][0]
    fixed = [tan_channel(a, prior=1), tan_channel(b, prior=3)]
    r = nis.Integrator(2, "uniform", channels=fixed, channel_settings={"adapt_weights": False})(
        two_peaks, evals=100_000
    )
    assert list(r.channel_weights) == [0.25, 0.75] and within(r, EXACT)
    moved = nis.Integrator(2, "uniform", channels=channels())(two_peaks, evals=100_000)
    assert moved.channel_weights[0] != 0.5
    # One flow shared by the channels (the default) and a flow per channel.
    for shared_flow in (True, False):
        integ = nis.Integrator(2, "nis", channels=channels(),
                               channel_settings={"shared_flow": shared_flow})
        r = integ(two_peaks, evals=100_000)
        assert within(r, EXACT) and len(r.channel_means) == 2 and all(r.channel_evals > 0)
        x, w, channel = integ.events(two_peaks, 200)
        assert x.shape == (200, 2) and set(channel) == {0, 1}
    # Channel weights refined by a network (kept only where it lowers the variance).
    integ = nis.Integrator(2, "nis", channels=channels(), channel_settings={"weight_network": True})
    r = integ(two_peaks, evals=100_000)
    assert within(r, EXACT) and len(r.channel_means) == 2
    with pytest.raises(ValueError, match="channel_settings needs channels or signs"):
        nis.Integrator(2, channel_settings={"pilot": 10})
    with pytest.raises(ValueError, match="colour"):
        nis.Integrator(2, channels=channels(), channel_settings={"colour": 1})
    with pytest.raises(ValueError, match="adapt_fraction"):
        nis.Integrator(2, channels=channels(), channel_settings={"adapt_fraction": 2.0})


def test_a_channel_is_callable_from_python_with_the_checks():
    c = tan_channel(0.3)
    u = np.random.default_rng(0).random((1000, 2))
    x = c.sample(u)
    assert x.shape == (1000, 2) and ((x >= 0) & (x <= 1)).all()
    g = c.density(x)
    assert g.shape == (1000,) and (g > 0).all()
    # The density integrates to 1 over the cube (a grid in each coordinate, product form).
    t = (np.arange(200_000) + 0.5) / 200_000
    one = nis.Channel(lambda u: u, lambda x: lorentz(x[:, 0], 0.3) / mass(0.3))
    assert abs(one.density(t[:, None]).mean() - 1) < 1e-6


def test_resonances_4d_through_the_builtin_channels():
    chans = nis.integrands.channels("resonances-4d")
    assert len(chans) == 3 and all(isinstance(c, nis.Channel) for c in chans)
    assert chans[0].dim == 4 and chans[0].name == "resonances-4d[0]"
    f = nis.integrands.example("resonances-4d")
    assert f.dim == 4 and f.exact > 0
    examples = {"dalitz", "resonances-4d", "phase-space-8d", "gauss-pm"}
    assert set(nis.integrands.examples()) >= examples
    r = nis.Integrator(4, "vegas", channels=chans, seed=3)(f, evals=300_000)
    assert within(r, f.exact, exact_err=4 * f.exact_err), (r.mean, r.sdev, f.exact)
    assert r.channel_means.shape == (3,)
    # The same built-in channels called from Python.
    x = chans[1].sample(np.full((5, 4), 0.5))
    assert x.shape == (5, 4) and (chans[1].density(x) > 0).all()
    with pytest.raises(ValueError, match="unknown"):
        nis.integrands.channels("camel")
    with pytest.raises(ValueError, match="unknown"):
        nis.integrands.example("camel")


def test_every_builtin_example_has_channels_of_its_dimension():
    for name in nis.integrands.examples():
        f = nis.integrands.example(name)
        chans = nis.integrands.channels(name)
        assert chans and all(c.dim == f.dim for c in chans)


def test_a_plus_minus_pair_is_split_by_sign():
    # f = x₀ − 0.3 on [0, 1]²: F = 0.2, F⁺ = 0.7²/2 = 0.245, F⁻ = 0.3²/2 = 0.045.
    def f(x):
        return x[:, 0] - 0.3

    integ = nis.Integrator(2, "vegas", signs="auto", seed=4)
    assert integ.channels == 1
    r = integ(f, evals=200_000)
    s = r.signs
    assert s is not None and set(s) == {
        "positive", "positive_sdev", "negative", "negative_sdev", "negative_fraction",
        "positive_evals", "negative_evals",
    }
    assert s["positive_evals"] > 0 and s["negative_evals"] > 0
    assert s["positive_evals"] + s["negative_evals"] == r.channel_evals.sum()
    assert within(r, 0.2)
    assert abs(s["positive"] - 0.245) < 4 * s["positive_sdev"]
    assert abs(s["negative"] - 0.045) < 4 * s["negative_sdev"]
    assert abs(s["negative_fraction"] - 0.045 / 0.29) < 0.01
    assert abs(s["positive"] - s["negative"] - r.mean) < 1e-12
    # "whole" never splits.
    whole = nis.Integrator(2, "vegas", signs="whole", seed=4)(f, evals=100_000)
    assert whole.signs is None and within(whole, 0.2)


def test_nis_splits_a_sign_changing_integrand_by_default():
    # f = x₀ − 0.3 again, no signs given: NIS's first points see both signs and the integral is
    # split; VEGAS+ and a positive integrand keep the whole, the latter bit for bit.
    def f(x):
        return x[:, 0] - 0.3

    integ = nis.Integrator(2, seed=4)
    assert integ.channels is None
    r = integ(f, evals=100_000)
    assert r.signs is not None and within(r, 0.2)
    assert r.n_eval == 100_000  # every evaluation asked for, split or not
    with pytest.raises(ValueError, match="changed sign"):
        integ.train(f, 1000)
    assert nis.Integrator(2, "vegas", seed=4)(f, evals=100_000).signs is None
    g = nis.integrands.gauss(dim=2)
    r = nis.Integrator(2, seed=5)(g, evals=100_000)
    assert r.signs is None and r.n_eval == 100_000


def test_two_peaks_of_opposite_sign_with_channels():
    def f(x):
        (m1, _), (m2, _) = PEAKS
        peak1 = lorentz(x[:, 0], m1) * lorentz(x[:, 1], m1)
        peak2 = lorentz(x[:, 0], m2) * lorentz(x[:, 1], m2)
        return peak1 - 0.5 * peak2

    exact = mass(PEAKS[0][0]) ** 2 - 0.5 * mass(PEAKS[1][0]) ** 2
    r = nis.Integrator(2, "uniform", channels=channels(), signs="split", seed=5)(f, evals=200_000)
    assert within(r, exact)
    assert r.signs["negative"] > 0 and 0 < r.signs["negative_fraction"] < 1
    g = nis.integrands.example("gauss-pm")
    chans = nis.integrands.channels("gauss-pm")
    r = nis.Integrator(2, "vegas", channels=chans, seed=6)(g, evals=200_000)
    assert r.signs is not None and within(r, g.exact)


def test_a_target_through_channels_stops_there():
    g = nis.integrands.example("dalitz")
    integ = nis.Integrator(2, "vegas", channels=nis.integrands.channels("dalitz"), seed=2)
    r = integ(g, rel_err=1e-2)
    assert r.stop == "target"
    assert r.sdev <= 1e-2 * abs(r.mean) and within(r, g.exact)
    assert len(r.channel_means) == 2


def test_a_bad_target_is_refused_before_f_is_called():
    calls = [0]

    def f(x):
        calls[0] += 1
        return two_peaks(x)

    integ = nis.Integrator(2, "vegas", channels=channels())
    for bad in [dict(rel_err=0.0), dict(rel_err=1e-3, max_evals=10)]:
        with pytest.raises(ValueError, match="precision target"):
            integ(f, **bad)
    assert calls[0] == 0


@pytest.mark.parametrize(
    "what", ["train", "estimate", "sample", "unweighted", "save", "flow", "trained_evals"]
)
def test_nis_only_methods_raise_for_a_multi_channel_integrator(what, tmp_path):
    integ = nis.Integrator(2, "nis", channels=channels())
    calls = {
        "train": lambda: integ.train(two_peaks, 10_000),
        "estimate": lambda: integ.estimate(two_peaks, 10_000),
        "sample": lambda: integ.sample(two_peaks, 10),
        "unweighted": lambda: integ.unweighted(two_peaks, 10),
        "save": lambda: integ.save(tmp_path / "m.safetensors"),
        "flow": lambda: integ.flow,
        "trained_evals": lambda: integ.trained_evals,
    }
    with pytest.raises(ValueError, match=f"{what} is not available for a multi-channel integrator"):
        calls[what]()


def good(u):
    return u


def flat(x):
    return np.ones(len(x))


def good_channel():
    return nis.Channel(good, flat)


@pytest.mark.parametrize(
    "sample, density, needle",
    [
        (lambda u: u + 1.0, flat, "unit cube"),
        (good, lambda x: -np.ones(len(x)), "density"),
        (lambda u: u[:, 0], flat, "shape"),
        (good, lambda x: np.ones((len(x), 2)), "shape"),
        (lambda u: np.full_like(u, np.nan), flat, "unit cube"),
        (good, lambda x: np.full(len(x), np.nan), "NaN"),
        (lambda u: "no", flat, "array of numbers"),
    ],
)
def test_a_bad_channel_raises_value_error_naming_it_at_the_first_batch(sample, density, needle):
    calls = [0]

    def f(x):
        calls[0] += 1
        return np.ones(len(x))

    bad = nis.Channel(sample, density)
    integ = nis.Integrator(2, "uniform", channels=[nis.Channel(good, flat), bad])
    with pytest.raises(ValueError, match=needle) as info:
        integ(f, evals=100_000)
    assert "channel 1" in str(info.value)
    assert calls[0] <= 2  # the probe and channel 0's pilot batch at most


@pytest.mark.parametrize(
    "make, needle",
    [
        (lambda: nis.Integrator(2, channels=[]), "non-empty"),
        (lambda: nis.Integrator(2, channels=[good]), "channel 0 is a function"),
        (lambda: nis.Channel(good, flat, prior=0.0), "prior"),
        (lambda: nis.Channel(good, flat, prior=-1.0), "prior"),
        (lambda: nis.Channel(good, flat, prior=float("nan")), "prior"),
        (lambda: nis.Channel(good, 3), "callable"),
        (lambda: nis.Channel(good, flat, dim=0), r"dim must be a positive integer \(1 or more\)"),
        (lambda: nis.Channel(good, flat, dim=-1), r"dim must be a positive integer \(1 or more\)"),
        (lambda: nis.Integrator(2, channels=[good_channel(), nis.Channel(good, flat, dim=3)]),
         "channel 1 has dimension 3"),
        (lambda: nis.Integrator(2, channels=nis.integrands.channels("resonances-4d")),
         r"channel 0 \(resonances-4d\[0\]\) has dimension 4"),
        (lambda: nis.Integrator(2, signs="sometimes"), "signs"),
        (lambda: nis.Integrator(2, channels=[good_channel()], coupling="nope"), "coupling"),
    ],
)
def test_bad_channel_arguments_raise_value_error_before_any_call(make, needle):
    with pytest.raises(ValueError, match=needle):
        make()


def test_a_channel_of_another_dimension_fails_at_its_first_batch():
    # Without a declared dim, a 3-d channel in a 2-d integrator returns the wrong shape.
    wrong = nis.Channel(lambda u: np.hstack([u, u[:, :1]]), flat)
    with pytest.raises(ValueError, match="channel 0.*shape"):
        nis.Integrator(2, "vegas", channels=[wrong])(lambda x: np.ones(len(x)), evals=50_000)


class Crash(Exception):
    pass


@pytest.mark.parametrize("where", ["sample", "density"])
def test_an_exception_in_a_channel_propagates_as_itself(where):
    raised = Crash("mapping failed")
    calls = [0]

    def boom(x):
        calls[0] += 1
        if calls[0] == 3:
            raise raised
        return good(x) if where == "sample" else flat(x)

    c = nis.Channel(boom, flat) if where == "sample" else nis.Channel(good, boom)
    integ = nis.Integrator(2, "vegas", channels=[c, nis.Channel(good, flat)])
    with pytest.raises(Crash) as info:
        integ(lambda x: np.ones(len(x)), evals=100_000)
    assert info.value is raised
    # The integrator is still usable afterwards.
    r = integ(lambda x: np.ones(len(x)), evals=100_000)
    assert within(r, 1.0)


def test_keyboard_interrupt_in_a_channel_propagates():
    def density(x):
        raise KeyboardInterrupt

    integ = nis.Integrator(2, "uniform", channels=[nis.Channel(good, density)])
    with pytest.raises(KeyboardInterrupt):
        integ(lambda x: np.ones(len(x)), evals=100_000)


def test_a_vector_integrand_is_refused_with_channels():
    integ = nis.Integrator(2, "uniform", channels=channels())
    with pytest.raises(ValueError, match="scalar"):
        integ(lambda x: np.ones((len(x), 2)), evals=100_000)


@pytest.mark.parametrize("method", ["uniform", "vegas", "nis"])
def test_a_seed_gives_the_same_bits_with_or_without_a_thread_pool(method):
    a = nis.Integrator(2, method, channels=channels(), seed=1)(two_peaks, evals=100_000)
    b = nis.Integrator(2, method, channels=channels(), seed=1, threads=1)(two_peaks, evals=100_000)
    assert (a.mean, a.sdev) == (b.mean, b.sdev)
    assert list(a.channel_means) == list(b.channel_means)


@pytest.mark.skipif(threading.current_thread() is not threading.main_thread(), reason="signals")
def test_ctrl_c_interrupts_a_multi_channel_run():
    calls = [0]
    after = [0]

    def density(x):
        calls[0] += 1
        if calls[0] == 5:
            os.kill(os.getpid(), signal.SIGINT)
        if calls[0] > 5:
            after[0] += 1
        return flat(x)

    integ = nis.Integrator(2, "vegas", channels=[nis.Channel(good, density), good_channel()])
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(KeyboardInterrupt):
            integ(lambda x: np.ones(len(x)), evals=50_000_000)  # minutes if not interrupted
    finally:
        signal.signal(signal.SIGINT, previous)
    assert after[0] < 1000, "the run went on long after Ctrl-C"


def test_events_follow_f_and_carry_their_channel():
    g = nis.integrands.example("gauss-pm")
    integ = nis.Integrator(2, "nis", channels=nis.integrands.channels("gauss-pm"), seed=3)
    with pytest.raises(ValueError, match="integrated"):
        integ.events(g, 10)
    integ(g, evals=100_000)
    n = 10_000
    x, w, ch = integ.events(g, n)
    assert x.shape == (n, 2) and w.shape == (n,) and ch.shape == (n,)
    assert set(np.unique(ch)) == {0, 1}
    # ∫f = 0: half the events are negative, within 5 binomial σ.
    assert abs((w < 0).mean() - 0.5) < 5 * 0.5 / np.sqrt(n)
    x2, _, _ = integ.events(g, 10)
    assert not np.array_equal(x2, x[:10])
    with pytest.raises(ValueError, match="multi-channel"):
        nis.Integrator(2, "nis").events(g, 10)
