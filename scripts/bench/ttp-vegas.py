"""The `vegas` package's side of `nis bench time-to-precision`, driven line by line from Rust.

The Rust driver owns the measurement rule (budgets, stopping, cap, medians); this process only
runs what it is asked, on the integrand `nis eval` serves (the same code, and the same synthetic
cost per point, as our integrators get). Requests on stdin, one JSON answer per line on stdout:

  calibrate N        -> {"us_per_point": wall µs per point of a batch of N through the pipe,
                         "vegas": version, "python": version}
  run SEED EVALS     -> {"evals", "seconds", "value", "std_err"}: a fresh vegas.Integrator run as
                        its documentation shows (5 adapting iterations discarded, then 15 for the
                        result, EVALS/20 points each), timed around the two calls
Run in the venv scripts/setup/vegas-venv.sh makes.
"""

import argparse
import json
import os
import platform
import sys
import time

import gvar
import numpy as np
import vegas

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "lib"))  # scripts/lib
from nis_served import Served  # noqa: E402


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--cli", required=True)
    p.add_argument("--name", required=True)
    p.add_argument("--dim", type=int, required=True)
    p.add_argument("--spins", type=int, default=0)
    args = p.parse_args()
    served = Served(args.cli, args.name, args.dim, args.spins)
    f = vegas.batchintegrand(served)
    try:
        for line in sys.stdin:
            words = line.split()
            if not words:
                continue
            if words[0] == "calibrate":
                n = int(words[1])
                x = np.random.default_rng(0).random((n, args.dim))
                served(x)
                times = []
                for _ in range(3):
                    t = time.perf_counter()
                    served(x)
                    times.append(time.perf_counter() - t)
                answer = dict(us_per_point=sorted(times)[1] * 1e6 / n, vegas=vegas.__version__,
                              python=platform.python_version())
            elif words[0] == "run":
                seed, evals = int(words[1]), int(words[2])
                gvar.ranseed(seed)
                integ = vegas.Integrator(args.dim * [[0, 1]])
                calls = served.calls
                t = time.perf_counter()
                integ(f, nitn=5, neval=evals // 20)
                r = integ(f, nitn=15, neval=evals // 20)
                seconds = time.perf_counter() - t
                answer = dict(evals=served.calls - calls, seconds=seconds, value=float(r.mean),
                              std_err=float(r.sdev))
            else:
                raise SystemExit(f"unknown request {line!r}")
            print(json.dumps(answer), flush=True)
    finally:
        served.close()


if __name__ == "__main__":
    main()
