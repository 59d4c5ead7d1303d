"""The built-in test suite, one function per member of the library's suite (``nis list``):
``camel(dim=8)`` returns a ``nis.Builtin``, callable on (n, dim) arrays, with ``.exact``,
``.dim`` and ``.name``. Names use ``_`` where the command line uses ``-``
(``camel_sharp`` is ``camel-sharp``).

The functions are made at import from the compiled suite, so they always match it.
"""

from typing import Callable, List, Optional

from ._nis import Builtin, suite as _suite

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
