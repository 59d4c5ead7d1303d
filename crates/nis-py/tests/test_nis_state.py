"""Trained NIS state: save/load, weighted and unweighted samples, the flow inside."""

import numpy as np
import pytest

import nis
from conftest import gauss_np


@pytest.fixture(scope="module")
def trained():
    integ = nis.Integrator(2, seed=3)
    integ(gauss_np, evals=100_000)
    return integ


def test_save_and_load_round_trip(trained, tmp_path):
    path = tmp_path / "g2.safetensors"
    trained.save(path)
    loaded = nis.Integrator.load(str(path))
    assert (loaded.method, loaded.dim) == ("nis", 2)
    assert loaded.trained_evals == trained.trained_evals
    x = np.random.default_rng(0).random((100, 2))
    assert np.array_equal(loaded.flow.log_prob(x), trained.flow.log_prob(x))
    r = loaded.estimate(gauss_np, evals=50_000)
    assert abs(r.mean - nis.integrands.gauss(dim=2).exact) < 5 * r.sdev
    assert r.n_eval == 50_000
    # The integrator's file is a flow file too (the CLI's `nis::io` format).
    flow = nis.Flow.load(path)
    assert np.array_equal(flow.log_prob(x), trained.flow.log_prob(x))


def test_file_errors_are_python_exceptions(tmp_path):
    with pytest.raises(FileNotFoundError):
        nis.Integrator.load(tmp_path / "missing.safetensors")
    with pytest.raises(FileNotFoundError):
        nis.Flow.load(tmp_path / "missing.safetensors")
    bad = tmp_path / "bad.safetensors"
    bad.write_bytes(b"not a model at all")
    with pytest.raises(nis.ModelError):
        nis.Integrator.load(bad)
    with pytest.raises(nis.ModelError):
        nis.Flow.load(bad)
    # A flow file without integrator settings is not an integrator.
    plain = tmp_path / "flow.safetensors"
    nis.Flow(2).save(plain)
    with pytest.raises(nis.ModelError, match="integrator"):
        nis.Integrator.load(plain)
    with pytest.raises(FileNotFoundError):
        nis.Flow(2).save(tmp_path / "no" / "such" / "dir.safetensors")


def test_other_methods_refuse_nis_calls(tmp_path):
    v = nis.Integrator(2, "vegas")
    with pytest.raises(ValueError, match="vegas"):
        v.save(tmp_path / "v.safetensors")
    for call in (lambda: v.sample(gauss_np, 10), lambda: v.unweighted(gauss_np, 10),
                 lambda: v.flow, lambda: v.estimate(gauss_np, 100)):
        with pytest.raises(ValueError, match="nis"):
            call()


def test_weighted_samples_estimate_the_integral(trained):
    n = 50_000
    x, w = trained.sample(gauss_np, n)
    assert x.shape == (n, 2) and w.shape == (n,)
    assert np.all((x >= 0) & (x <= 1))
    exact = nis.integrands.gauss(dim=2).exact
    assert abs(w.mean() - exact) < 5 * w.std() / np.sqrt(n)
    # The weights are f/q_mix: f over the defensive mixture of uniform (share λ = 0.002, the
    # default `uniform_fraction`) and the flow, the density the points were drawn from.
    q_mix = 0.002 + 0.998 * np.exp(trained.flow.log_prob(x))
    assert np.allclose(w, gauss_np(x) / q_mix, rtol=1e-4)


def test_unweighted_points_follow_the_integrand(trained):
    n = 20_000
    x, w = trained.unweighted(gauss_np, n)
    assert x.shape == (n, 2) and w.shape == (n,)
    assert np.all(np.abs(w) >= 1)
    # The robust maximum leaves overweight = 1e-3 (the default) of the calibration batch's weight
    # mass above it; in this sample the excess mass Σ(|w| − 1)/Σ|w| estimates the same share from
    # the ~1% of points that are overweight (~200: a relative error of about a quarter), so 3×
    # the share is far outside its noise. How many points are overweight is not bounded by it.
    excess = (np.abs(w) - 1).sum() / np.abs(w).sum()
    assert 0 <= excess < 3e-3
    # Points of exp(−|x − ½|²/α²), α = 0.2: per coordinate mean ½ and variance α²/2 (the cube
    # cuts the tails at 3.5σ, which changes neither at this precision).
    var = 0.2**2 / 2
    assert np.all(np.abs(x.mean(axis=0) - 0.5) < 5 * np.sqrt(var / n))
    assert np.all(np.abs(x.var(axis=0) - var) < 5 * var * np.sqrt(2 / n))


def test_the_trained_flow_is_not_uniform(trained):
    flow = trained.flow
    assert flow.dim == 2
    centre = flow.log_prob(np.array([[0.5, 0.5]]))[0]
    corner = flow.log_prob(np.array([[0.02, 0.02]]))[0]
    assert centre > 1 and corner < centre - 3
