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
  estimates, like ``vegas.Integrator``.
- ``IntegrationResult``: ``mean``, ``sdev``, ``cov``, ``chi2_dof``, ... and ``str(r)``.
- ``Flow``: a coupling flow as a distribution (``sample``, ``log_prob``, ``fit``).
- ``integrands``: the built-in test suite with exact values.
"""

from ._nis import (
    Builtin,
    Flow,
    IntegrandError,
    IntegrationResult,
    Integrator,
    ModelError,
    __version__,
)
from . import integrands

__all__ = [
    "Builtin",
    "Flow",
    "IntegrandError",
    "IntegrationResult",
    "Integrator",
    "ModelError",
    "__version__",
    "integrands",
]
