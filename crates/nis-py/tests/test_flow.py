"""nis.Flow as a distribution: sample, log_prob, fit, fit_integrand, save/load, context."""

import numpy as np
import pytest

import nis
from conftest import gauss_np


def beta_data(n, seed):
    rng = np.random.default_rng(seed)
    return np.stack([rng.beta(2, 5, n), rng.beta(5, 2, n)], axis=1)


@pytest.fixture(scope="module")
def fitted():
    flow = nis.Flow(2, coupling="pq", bins=16, seed=0)
    history = flow.fit(beta_data(20_000, 1), epochs=8, batch=256, learning_rate=5e-3)
    return flow, history


def test_a_new_flow_is_uniform():
    flow = nis.Flow(3)
    x, log_q = flow.sample(1000)
    assert x.shape == (1000, 3) and log_q.shape == (1000,)
    assert np.all((x >= 0) & (x <= 1)) and np.allclose(log_q, 0, atol=1e-5)
    assert np.allclose(flow.log_prob(x), 0, atol=1e-5)
    assert "pq16" in repr(flow) and flow.param_count > 0 and '"dim":3' in flow.config


def test_fit_learns_the_data(fitted):
    flow, history = fitted
    assert len(history) == 8 and history[-1] < history[0] < 0.1
    # Held-out log-likelihood: the density of Beta(2,5) × Beta(5,2) has mean log p ≈ 0.97.
    held_out = flow.log_prob(beta_data(5000, 2)).mean()
    assert held_out > 0.6


def test_sampling_density_matches_log_prob(fitted):
    flow, _ = fitted
    n = 100_000
    x, log_q = flow.sample(n)
    # Same density both ways, point by point ...
    assert np.allclose(flow.log_prob(x), log_q, atol=1e-3)
    # ... and the points are drawn from it: E_q[1/q] = volume of the cube = 1, and
    # E_q[1{x0 < ½}/q] = ½, which hold only if x ~ exp(log_q).
    w = np.exp(-log_q)
    assert abs(w.mean() - 1) < 5 * w.std() / np.sqrt(n)
    h = w * (x[:, 0] < 0.5)
    assert abs(h.mean() - 0.5) < 5 * h.std() / np.sqrt(n)
    # The marginal of x0 matches the data's mean (Beta(2, 5): 2/7).
    assert abs(x[:, 0].mean() - 2 / 7) < 0.02


def test_fit_integrand_reduces_the_variance():
    flow = nis.Flow(2, seed=1)
    before = flow.log_prob(np.array([[0.5, 0.5]]))[0]
    history = flow.fit_integrand(gauss_np, evals=60_000, loss="kl")
    assert len(history) > 40
    assert np.mean(history[-10:]) < 0.3 * np.mean(history[:5])
    assert flow.log_prob(np.array([[0.5, 0.5]]))[0] > before + 1
    chi2 = nis.Flow(2, seed=1)
    h2 = chi2.fit_integrand(gauss_np, evals=60_000, loss="chi2")
    assert np.mean(h2[-10:]) < np.mean(h2[:5])


def test_an_exception_in_fit_integrand_leaves_the_flow_as_it_was():
    flow = nis.Flow(2, seed=1)
    x = np.random.default_rng(0).random((10, 2))
    before = flow.log_prob(x)
    calls = [0]

    def f(x):
        calls[0] += 1
        if calls[0] == 20:
            raise ZeroDivisionError("boom")
        return gauss_np(x)

    with pytest.raises(ZeroDivisionError):
        flow.fit_integrand(f, evals=100_000)
    assert np.array_equal(flow.log_prob(x), before)


def test_the_code_masks_build_a_smaller_flow_that_saves_and_loads(tmp_path):
    codes, binary = nis.Flow(8, masks="codes", seed=1), nis.Flow(8, seed=1)
    assert '"masks":"codes"' in codes.config and "masks" not in binary.config
    assert codes.param_count < binary.param_count
    codes.fit_integrand(gauss_np, evals=20_000)
    codes.save(tmp_path / "codes.safetensors")
    back = nis.Flow.load(str(tmp_path / "codes.safetensors"))
    x, log_q = codes.sample(200)
    assert back.config == codes.config
    assert np.array_equal(back.log_prob(x), codes.log_prob(x))
    assert np.allclose(log_q, codes.log_prob(x), atol=1e-3)


def test_save_and_load_keep_the_flow_bit_for_bit(fitted, tmp_path):
    flow, _ = fitted
    flow.save(tmp_path / "beta.safetensors")
    back = nis.Flow.load(str(tmp_path / "beta.safetensors"))
    x = beta_data(100, 3)
    assert np.array_equal(back.log_prob(x), flow.log_prob(x))
    assert back.config == flow.config


def test_a_conditional_flow_takes_context():
    flow = nis.Flow(2, context_dim=1, seed=0)
    n = 4000
    c = np.repeat([[0.0], [1.0]], n // 2, axis=0)
    # Data whose location depends on the context.
    rng = np.random.default_rng(0)
    x = np.clip(0.25 + 0.5 * c + 0.05 * rng.standard_normal((n, 2)), 0, 1)
    flow.fit(x, context=c, epochs=15, batch=200, learning_rate=5e-3)
    s0, _ = flow.sample(500, context=np.zeros((500, 1)))
    s1, _ = flow.sample(500, context=np.ones((500, 1)))
    assert s0.mean() < 0.4 < 0.6 < s1.mean()
    with pytest.raises(ValueError):
        flow.sample(10)  # context missing
    with pytest.raises(ValueError):
        flow.log_prob(x[:10], context=np.zeros((9, 1)))
    with pytest.raises(ValueError):
        flow.fit_integrand(gauss_np, evals=1000)


@pytest.mark.parametrize(
    "make",
    [
        lambda: nis.Flow(0),
        lambda: nis.Flow(2, coupling="nope"),
        lambda: nis.Flow(2, bins=0),
        lambda: nis.Flow(2, layers=0),
        lambda: nis.Flow(8, masks="gray"),
        lambda: nis.Flow(2, hidden_width=-3),
    ],
)
def test_bad_flow_settings_raise_value_error(make):
    with pytest.raises(ValueError):
        make()


def test_bad_points_raise_value_error():
    flow = nis.Flow(2)
    with pytest.raises(ValueError, match="outside"):
        flow.log_prob(np.array([[0.5, 1.5]]))
    with pytest.raises(ValueError, match="shape"):
        flow.log_prob(np.zeros((4, 3)))
    with pytest.raises(ValueError):
        flow.fit(np.zeros((0, 2)))
    with pytest.raises(ValueError):
        flow.fit_integrand(gauss_np, loss="nll")
