"""The built-in test suite, one function per member of the library's suite (``nis list``):
``camel(dim=8)`` returns a ``nis.Builtin``, callable on (n, dim) arrays, with ``.exact``,
``.dim`` and ``.name``. Names use ``_`` where the command line uses ``-``
(``camel_sharp`` is ``camel-sharp``).

The functions are made at import from the compiled suite, so they always match it.

The multi-channel examples (``examples()``: "gauss-pm", "dalitz", "resonances-4d",
"phase-space-8d", "resonances-100") are not suite members: ``example(name)`` returns the integrand (a
``nis.Builtin`` with ``.exact``), ``channels(name)`` the channels written for it (a list of
``nis.Channel``), to give to ``nis.Integrator(dim, channels=...)``.
"""

from typing import Callable, List, Optional

from ._nis import Builtin, Channel, suite as _suite
from ._nis import example_channels as _example_channels, example_names as _example_names

__all__: List[str] = []


def _member(name: str, dims: List[int], description: str) -> Callable[..., Builtin]:
    def make(dim: Optional[int] = None) -> Builtin:
        return Builtin(name, dim)

    make.__name__ = make.__qualname__ = name.replace("-", "_")
    make.__doc__ = (
        f"{description}.\n\nSuite dimensions {dims}; ``dim`` defaults to {dims[0]}. "
        f"Returns a ``nis.Builtin`` (callable on (n, dim) arrays, with ``.exact``)."
    )
    return make


for _name, _dims, _description in _suite():
    _f = _member(_name, list(_dims), _description)
    globals()[_f.__name__] = _f
    __all__.append(_f.__name__)

del _name, _dims, _description, _f


def names() -> List[str]:
    """The suite's names as the command line spells them (e.g. "camel-sharp")."""
    return [name for name, _, _ in _suite()]


def examples() -> List[str]:
    """The multi-channel examples' names (e.g. "resonances-4d")."""
    return list(_example_names())


def example(name: str) -> Builtin:
    """The integrand of the multi-channel example ``name`` (one of ``examples()``), a
    ``nis.Builtin`` with its exact value ``.exact`` (and ``.exact_err``)."""
    if name not in _example_names():
        raise ValueError(
            f"unknown multi-channel example {name!r}; examples: {', '.join(_example_names())}"
        )
    return Builtin(name)


def channels(name: str) -> List[Channel]:
    """The channels of the multi-channel example ``name`` (one of ``examples()``), one per peak
    (resonance, Gaussian), equal priors: ``nis.Channel``s evaluated in Rust, for
    ``nis.Integrator(dim, channels=nis.integrands.channels(name))``."""
    return list(_example_channels(name))
