"""A built-in integrand of `nis` served by `nis eval` behind a pipe, as a `vegas` batch integrand.

Shared by scripts/bench/bench-vegas.py and scripts/bench/ttp-vegas.py: the Python baselines integrate the very
same integrand code as our integrators, optionally with the same synthetic cost per point
(`spins`, see `nis eval --spins`).
"""

import struct
import subprocess


class Served:
    """`nis eval NAME --dim DIM [--spins SPINS]` as a callable on (n, dim) arrays."""

    def __init__(self, cli, name, dim, spins=0):
        import numpy as np
        self.np, self.dim = np, dim
        args = [cli, "eval", name, "--dim", str(dim)]
        if spins:
            args += ["--spins", str(spins)]
        self.proc = subprocess.Popen(args, stdin=subprocess.PIPE, stdout=subprocess.PIPE)
        self.calls = 0

    def __call__(self, x):
        np = self.np
        x = np.ascontiguousarray(x, dtype="<f8")
        n = x.shape[0]
        self.proc.stdin.write(struct.pack("<Q", n) + x.tobytes())
        self.proc.stdin.flush()
        buf = self.proc.stdout.read(8 * n)
        if len(buf) != 8 * n:
            raise RuntimeError(f"nis eval stopped answering (exit {self.proc.poll()})")
        self.calls += n
        return np.frombuffer(buf, dtype="<f8").copy()

    def close(self):
        self.proc.stdin.write(struct.pack("<Q", 0))
        self.proc.stdin.close()
        self.proc.wait()
