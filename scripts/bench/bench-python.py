#!/usr/bin/env python3
"""The Python module against the Rust library and the Python packages a physicist would reach
for: the 8-d camel (two Gaussians, α = 0.2) at 10^6 evaluations.

- nis from Python with a numpy integrand (the module's callback path: whole batches, GIL taken
  only to call f), and with the built-in camel (no Python per batch);
- the same NIS run through the Rust closure: `nis integrate camel --dim 8 --method nis --json`;
- the `vegas` package (VEGAS+, numpy batch integrand) on the same numpy integrand;
- MadNIS (PyTorch), if it installs and runs here, on the same numpy integrand.

Run by scripts/bench/bench-python.sh, which makes one venv per package; this file is both the driver
(`--driver`) and, inside each venv, the runner of one method (`--run METHOD`). Each line of a
runner's output is one JSON result. The driver writes the table into docs/results/integration.md between
the `<!-- python:start -->` and `<!-- python:end -->` markers.
"""

import argparse
import json
import math
import os
import platform
import statistics
import subprocess
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "lib"))  # scripts/lib
from docs_section import machine, write_section  # noqa: E402

DIM, EVALS, SEED, ALPHA = 8, 1_000_000, 1, 0.2
EXACT = (0.5 * (math.erf(1 / (3 * ALPHA)) + math.erf(2 / (3 * ALPHA)))) ** DIM


def camel_np(x):
    """The suite's camel in numpy, written as a numpy user would (vectorised over the batch)."""
    import numpy as np

    pre = 0.5 * (ALPHA * math.sqrt(math.pi)) ** (-x.shape[1])
    a = ((x - 1 / 3) ** 2).sum(axis=1)
    b = ((x - 2 / 3) ** 2).sum(axis=1)
    return pre * (np.exp(-a / ALPHA**2) + np.exp(-b / ALPHA**2))


def emit(**row):
    print(json.dumps(row), flush=True)


def run_nis(reps):
    import nis

    for rep in range(reps):
        for label, f in [("numpy", camel_np), ("built-in", nis.integrands.camel(dim=DIM))]:
            integ = nis.Integrator(DIM, "nis", seed=SEED)
            t = time.perf_counter()
            r = integ(f, evals=EVALS)
            wall = time.perf_counter() - t
            emit(method=f"nis (Python, {label} integrand)", rep=rep, value=r.mean,
                 std_err=r.sdev, n_eval=r.n_eval, seconds=wall)


def run_vegas(reps):
    import numpy as np
    import vegas

    @vegas.batchintegrand
    def f(x):
        return camel_np(np.asarray(x))

    for rep in range(reps):
        np.random.seed(SEED + rep)
        integ = vegas.Integrator(DIM * [[0, 1]])
        t = time.perf_counter()
        # 10^6 evaluations: 5 warm-up iterations (discarded, as the package's docs advise)
        # and 15 that make the result, 5·10^4 each.
        integ(f, nitn=5, neval=50_000)
        r = integ(f, nitn=15, neval=50_000)
        wall = time.perf_counter() - t
        n = getattr(r, "sum_neval", None)
        emit(method="vegas package (VEGAS+, numpy)", rep=rep, value=float(r.mean),
             std_err=float(r.sdev), n_eval=int(n) + 5 * 50_000 if n else 20 * 50_000,
             seconds=wall)


def run_madnis(reps):
    import torch
    from madnis.integrator import Integrator

    torch.set_num_threads(os.cpu_count() or 1)

    def f(x):
        return torch.from_numpy(camel_np(x.detach().double().numpy())).to(x.dtype)

    batch = 1024
    train_steps = int(0.4 * EVALS) // batch  # the same 40 % / 60 % split as nis
    for rep in range(reps):
        torch.manual_seed(SEED + rep)
        integ = Integrator(f, dims=DIM, batch_size=batch, learning_rate=1e-3)
        t = time.perf_counter()
        integ.train(train_steps)
        n_final = EVALS - train_steps * batch
        value, err = integ.integrate(n_final)
        wall = time.perf_counter() - t
        emit(method="MadNIS (PyTorch, numpy)", rep=rep, value=value, std_err=err,
             n_eval=EVALS, seconds=wall)


def run_rust(cli, reps):
    for rep in range(reps):
        t = time.perf_counter()
        out = subprocess.run(
            [cli, "integrate", "camel", "--dim", str(DIM), "--method", "nis", "--evals",
             str(EVALS), "--seed", str(SEED), "--json"],
            check=True, capture_output=True, text=True).stdout
        wall = time.perf_counter() - t
        r = json.loads(out)
        emit(method="nis (Rust closure, CLI)", rep=rep, value=r["value"], std_err=r["std_err"],
             n_eval=r["n_eval"], seconds=r["seconds"], process_seconds=wall)


def driver(args):
    rows, notes = [], []
    venvs = args.venvs
    load_start = os.getloadavg()[0]

    def collect(cmd, what):
        try:
            p = subprocess.run(cmd, capture_output=True, text=True, timeout=args.timeout)
        except subprocess.TimeoutExpired:
            notes.append(f"{what}: did not finish within {args.timeout} s")
            return
        if p.returncode != 0:
            tail = (p.stderr.strip().splitlines() or ["(no output)"])[-1]
            notes.append(f"{what}: failed ({tail})")
            return
        rows.extend(json.loads(line) for line in p.stdout.splitlines() if line.startswith("{"))

    me = os.path.abspath(__file__)
    py = lambda name: os.path.join(venvs, name, "bin", "python")  # noqa: E731
    # Interleaved, so that slow phases of the shared machine hit every method alike.
    for rep in range(args.reps):
        collect([sys.executable, me, "--run", "rust", "--cli", args.cli, "--reps", "1"], "rust")
        collect([py("nis"), me, "--run", "nis", "--reps", "1"], "nis")
        collect([py("vegas"), me, "--run", "vegas", "--reps", "1"], "vegas")
    if os.path.exists(py("madnis")):
        collect([py("madnis"), me, "--run", "madnis", "--reps", "1"], "MadNIS")
    else:
        notes.append(f"MadNIS: not installed ({args.madnis_note or 'no venv'})")

    by = {}
    for r in rows:
        by.setdefault(r["method"], []).append(r)
    rust = by.get("nis (Rust closure, CLI)")
    rust_t = statistics.median(r["seconds"] for r in rust) if rust else None
    versions = subprocess.run([py("nis"), "-c", "import nis, numpy; print(nis.__version__, numpy.__version__)"],
                              capture_output=True, text=True).stdout.split()
    vegas_v = subprocess.run([py("vegas"), "-c", "import vegas; print(vegas.__version__)"],
                             capture_output=True, text=True).stdout.strip()
    lines = [
        "## Python: the module `nis` against the Rust closure, `vegas` and MadNIS",
        "",
        f"`scripts/bench/bench-python.sh` — camel (two Gaussians on the diagonal, α = 0.2) in d = {DIM}, "
        f"{EVALS:,} evaluations per run, exact value {EXACT:.8f}; the numpy integrand is the "
        "same function for every package. Time is the median wall time of the integration call "
        f"over {args.reps} runs (one for MadNIS), interleaved; NIS settings are the defaults "
        f"(seed {SEED}), the same in the CLI and the module.",
        "",
        f"Machine: {machine()}, Python {platform.python_version()}; numpy {versions[1] if len(versions) > 1 else '?'}, "
        f"nis {versions[0] if versions else '?'}, vegas {vegas_v or '?'}"
        + ("; on a shared machine (other processes were running), so the times are noisy."
           if load_start >= 0.5 else "."),
        "",
        "pull = (value − exact)/std_err; σ²·N/F² = std_err² × all evaluations (training "
        "included) / exact²: the evaluations a method spends per unit of squared relative "
        "precision, smaller is better. vegas: 5 warm-up iterations (discarded) and 15 that make "
        "the result, 5·10⁴ evaluations each. MadNIS 1.0: its default flow and Adam at "
        "learning rate 10⁻³, 390 training steps of 1024 points (the 40 % NIS trains on), then "
        f"`integrate` with the remaining {EVALS - int(0.4 * EVALS) // 1024 * 1024:,}, "
        "torch on every core.",
        "",
        "| method | value ± std_err | pull | σ²·N/F² | seconds | vs Rust |",
        "| --- | --- | ---: | ---: | ---: | ---: |",
    ]
    order = ["nis (Rust closure, CLI)", "nis (Python, numpy integrand)",
             "nis (Python, built-in integrand)", "vegas package (VEGAS+, numpy)",
             "MadNIS (PyTorch, numpy)"]
    for name in order + sorted(set(by) - set(order)):
        rs = by.get(name)
        if not rs:
            continue
        t = statistics.median(r["seconds"] for r in rs)
        r = rs[0]
        pull = (r["value"] - EXACT) / r["std_err"] if r["std_err"] > 0 else float("nan")
        # Variance per evaluation of the whole budget (training included), relative to F²:
        # the cost in evaluations of a given precision.
        cost = r["std_err"] ** 2 * r["n_eval"] / EXACT**2
        ratio = f"{t / rust_t:.3f}×" if rust_t else "–"
        lines.append(f"| {name} | {r['value']:.6f} ± {r['std_err']:.2e} | {pull:+.2f} | "
                     f"{cost:.3g} | {t:.2f} | {ratio} |")
    lines.append("")
    nis_rows = [by[m][0] for m in order[:3] if m in by]
    spread = max(abs(r["value"] - nis_rows[0]["value"]) / abs(nis_rows[0]["value"])
                 for r in nis_rows) if nis_rows else float("nan")
    lines.append(
        "NIS gives the same numbers for the same seed run after run; vegas's change from run to run "
        "(`np.random.seed` does not fix its generator). The first run of each is shown. "
        + ("The three NIS rows are bit-identical: the module runs the same Rust code on the "
           "same points." if spread == 0 else
           f"The three NIS rows agree to a relative {spread:.1e}: numpy sums a point's "
           "coordinates in another order than the Rust closure, so f differs in the last "
           "place, and the flow's f32 training absorbs nearly all of it."))
    for n in notes:
        lines.append(f"- {n}")
    section = "\n".join(lines)
    print(section)
    if args.out:
        write_section(args.out, "python", section)


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--run", choices=["nis", "vegas", "madnis", "rust"])
    p.add_argument("--reps", type=int, default=3)
    p.add_argument("--cli", default="target/release/nis")
    p.add_argument("--venvs", default="target/bench-py")
    p.add_argument("--out")
    p.add_argument("--timeout", type=int, default=900)
    p.add_argument("--madnis-note", default="")
    args = p.parse_args()
    if args.run == "nis":
        run_nis(args.reps)
    elif args.run == "vegas":
        run_vegas(args.reps)
    elif args.run == "madnis":
        run_madnis(args.reps)
    elif args.run == "rust":
        run_rust(args.cli, args.reps)
    else:
        driver(args)


if __name__ == "__main__":
    main()
