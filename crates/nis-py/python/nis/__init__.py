"""Neural importance sampling: Monte Carlo integration over [0, 1]^d whose sampling density is
a normalizing flow learned from the integrand (Müller et al., "Neural Importance Sampling"),
with VEGAS+ and plain Monte Carlo as baselines.

>>> import numpy as np, nis
>>> f = nis.integrands.camel(dim=4)          # or any f((n, 4) array) -> (n,) array
>>> integ = nis.Integrator(dim=4, method="nis", seed=1)
>>> r = integ(f, evals=200_000)
>>> abs(r.mean - f.exact) < 5 * r.sdev
True

- ``Integrator``: NIS, VEGAS+ or plain MC by name; ``integ(f, evals=...)`` adapts and
  estimates, like ``vegas.Integrator``. With ``channels=[...]`` (``Channel``s) and/or
  ``signs=`` it is a multi-channel integrator (a sampler per channel and sign).
- ``Channel``: a mapping of the unit cube with its density, for multi-channel integration.
- ``IntegrationResult``: ``mean``, ``sdev``, ``cov``, ``chi2_dof``, ... and ``str(r)``.
- ``Flow``: a coupling flow as a distribution (``sample``, ``log_prob``, ``fit``).
- ``integrands``: the built-in test suite with exact values.
"""

import warnings as _warnings

from ._nis import (
    Builtin,
    Channel,
    Flow,
    IntegrandError,
    IntegrationResult,
    Integrator,
    ModelError,
    __version__,
)
from . import integrands

_integrate = Integrator.__call__


def _call(self, f, evals=None, *, rel_err=None, abs_err=None, max_evals=None, max_seconds=None):
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
    r = _integrate(
        self,
        f,
        evals,
        rel_err=rel_err,
        abs_err=abs_err,
        max_evals=max_evals,
        max_seconds=max_seconds,
    )
    for w in r.warnings:
        _warnings.warn(w, UserWarning, stacklevel=2)
    return r


# PyO3 makes ``__call__`` a type slot, which keeps no docstring: this one carries it.
_call.__name__ = "__call__"
_call.__qualname__ = "Integrator.__call__"
Integrator.__call__ = _call
del _call

__all__ = [
    "Builtin",
    "Channel",
    "Flow",
    "IntegrandError",
    "IntegrationResult",
    "Integrator",
    "ModelError",
    "__version__",
    "integrands",
]
