"""Lets `import nis` find this package before the standard library's `nis` (the NIS/YP client,
deprecated by PEP 594 and removed in Python 3.13), whose lib-dynload folder comes earlier on
sys.path in Python 3.9 to 3.12. Installed with `nis-precedence.pth`, which runs it at start-up,
as setuptools' `distutils-precedence.pth` does for distutils. Set NIS_STDLIB_NIS=1 to keep
the standard library's module instead.
"""

import importlib.machinery
import os
import sys
import sysconfig


def _stdlib(entry):
    """Whether a sys.path entry is the standard library's (where the old `nis` lives)."""
    real = os.path.realpath(entry or os.curdir)
    paths = sysconfig.get_paths()
    std = {os.path.realpath(paths[k]) for k in ("stdlib", "platstdlib") if k in paths}
    return real in std or os.path.basename(real) == "lib-dynload"


class NisPrecedence:
    """A meta-path finder for the top-level name `nis` only: sys.path in its order, less the
    standard library's folders."""

    @classmethod
    def find_spec(cls, fullname, path=None, target=None):
        if fullname != "nis" or path is not None:
            return None
        entries = [p for p in sys.path if not _stdlib(p)]
        return importlib.machinery.PathFinder.find_spec(fullname, entries)


def install():
    if sys.version_info < (3, 13) and os.environ.get("NIS_STDLIB_NIS") != "1":
        if not any(f is NisPrecedence for f in sys.meta_path):
            sys.meta_path.insert(0, NisPrecedence)
