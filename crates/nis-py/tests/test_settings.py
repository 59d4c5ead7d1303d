"""nis.Integrator's keywords: read by the library's one reader of settings, named in its errors,
and documented by the stub _nis.pyi, which is checked here against the library's schema."""

import ast
import inspect
import pathlib

import numpy as np
import pytest

import nis

STUB = pathlib.Path(__file__).resolve().parents[1] / "python" / "nis" / "_nis.pyi"
# Keywords of the constructor that are not settings.
NOT_SETTINGS = {"threads", "channels", "signs", "channel_settings"}


def stub_class(name):
    tree = ast.parse(STUB.read_text(encoding="utf-8"))
    return next(n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == name)


def stub_method(cls, name):
    return next(n for n in cls.body if isinstance(n, ast.FunctionDef) and n.name == name)


def test_the_stub_lists_every_setting_of_the_schema_and_nothing_else():
    cls = stub_class("Integrator")
    init = stub_method(cls, "__init__")
    keywords = {a.arg for a in init.args.kwonlyargs} - NOT_SETTINGS
    schema = set(nis._nis._keywords())
    assert keywords == schema, (
        f"in the stub, not the schema: {sorted(keywords - schema)}; "
        f"in the schema, not the stub: {sorted(schema - keywords)}"
    )
    doc = ast.get_docstring(cls)
    undocumented = [k for k in sorted(schema) if f"``{k}``" not in doc]
    assert not undocumented, f"the stub's Integrator docstring does not mention {undocumented}"


def test_call_has_the_stubs_docstring():
    stub = ast.get_docstring(stub_method(stub_class("Integrator"), "__call__"))
    assert inspect.getdoc(nis.Integrator.__call__) == stub
    assert "evals" in stub and "(n, 1)" in stub


def test_every_setting_keyword_is_taken_by_some_method():
    # A valid value of each must be accepted by some method.
    values = dict(
        seed=1, coupling="rq", bins=8, layers=2, masks="codes", hidden_layers=1, hidden_width=8,
        blob_bins=4, flow={"hidden_width": 8}, loss="chi2", batch=128, steps_per_batch=2,
        train_fraction=0.3, learning_rate=1e-3, adam={"beta1": 0.8}, learning_rate_end=0.5,
        average_span=0.2, uniform_fraction=0.01, anneal_from=0.5, final_iterations=4,
        stratify={"beta": 0.5}, reuse_training=0.25, replay_batches=2, replay_steps=1,
        increments=100, alpha=1.0, beta=0.5, iterations=6, warmup=2, min_per_cube=3,
        train_on="sum_abs", auto_masks=False, race_vegas=False,
    )
    # Settings valid only with another one.
    with_ = dict(warmup=dict(iterations=8), replay_steps=dict(replay_batches=2))
    assert set(values) == set(nis._nis._keywords())
    for k, v in values.items():
        for method in ["nis", "vegas", "uniform"]:
            try:
                nis.Integrator(2, method, **{k: v}, **with_.get(k, {}))
                break
            except ValueError:
                pass
        else:
            pytest.fail(f"no method takes {k}={v!r}")


@pytest.mark.parametrize(
    "kwargs, needle",
    [
        (dict(colour=1), "colour"),
        (dict(batch="many"), "batch"),
        (dict(layers=-1), "layers"),
        (dict(flow={"width": 3}), "width"),
        (dict(method="vegas", coupling="pq"), "coupling"),
        (dict(method="uniform", alpha=0.5), "alpha"),
        (dict(method="nis", iterations=5), "iterations"),
        (dict(uniform_fraction=float("nan")), "uniform_fraction"),
        (dict(loss="nll"), "nll"),
    ],
)
def test_a_refused_keyword_is_named(kwargs, needle):
    with pytest.raises(ValueError, match=needle):
        nis.Integrator(2, **kwargs)


def test_none_keeps_the_default_and_dicts_patch_sections():
    g = nis.integrands.gauss(dim=2)
    a = nis.Integrator(2, seed=5, batch=None, stratify=None)(g, evals=20_000)
    b = nis.Integrator(2, seed=5)(g, evals=20_000)
    assert (a.mean, a.sdev) == (b.mean, b.sdev)
    c = nis.Integrator(2, seed=5, hidden_width=16)(g, evals=20_000)
    d = nis.Integrator(2, seed=5, flow={"hidden_width": 16})(g, evals=20_000)
    assert (c.mean, c.sdev) == (d.mean, d.sdev) and c.mean != b.mean
    e = nis.Integrator(2, seed=np.int64(5))(g, evals=20_000)
    assert (e.mean, e.sdev) == (b.mean, b.sdev)


def test_an_n_by_1_integrand_is_a_vector_of_one_and_says_so(gauss):
    scalar = nis.Integrator(2, seed=3)(gauss, evals=20_000)
    column = nis.Integrator(2, seed=3)(lambda x: gauss(x)[:, None], evals=20_000)
    assert column.mean.shape == (1,) and column.mean[0] == scalar.mean
    assert any("(n, 1)" in w for w in column.warnings)
    assert not any("(n, 1)" in w for w in scalar.warnings)
