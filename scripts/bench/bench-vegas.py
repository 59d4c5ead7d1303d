"""Our VEGAS+ against the `vegas` package on every integrand of the suite, in the same run.

For each suite member (`nis list`), dimension and seed: our VEGAS+ through the CLI
(`nis integrate NAME --method vegas --json`, its defaults), and `vegas` as its documentation runs
it — `integ(f, nitn=5, neval=N/20)` to adapt (discarded), then `integ(f, nitn=15, neval=N/20)`
for the result — on the very same integrand, whose values `nis eval` serves over a pipe. Both
spend N evaluations in all; the variance per evaluation is N·σ²/I² over all N, and the pull is
(value − exact)/σ. Writes the section between `<!-- vegas:start -->` and `<!-- vegas:end -->`
of the docs file atomically. Run through scripts/bench/bench-vegas.sh (it makes the venv).
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
from nis_served import Served  # noqa: E402


def suite(cli, only):
    out = subprocess.run([cli, "list"], check=True, capture_output=True, text=True).stdout
    entries = []
    for line in out.splitlines()[1:]:
        name, dims = line.split()[:2]
        if only and name not in only:
            continue
        entries.append((name, [int(d) for d in dims.split(",")]))
    return entries


def ours(cli, name, dim, evals, seed):
    t = time.perf_counter()
    out = subprocess.run(
        [cli, "integrate", name, "--dim", str(dim), "--method", "vegas", "--evals", str(evals),
         "--seed", str(seed), "--json"], check=True, capture_output=True, text=True).stdout
    wall = time.perf_counter() - t
    r = json.loads(out)
    return dict(value=r["value"], sdev=r["std_err"], n=r["n_eval"], exact=r["exact"], wall=wall)


def package(cli, name, dim, evals, seed):
    import gvar
    import vegas
    served = Served(cli, name, dim)
    try:
        gvar.ranseed(seed)
        f = vegas.batchintegrand(served)
        integ = vegas.Integrator(dim * [[0, 1]])
        t = time.perf_counter()
        integ(f, nitn=5, neval=evals // 20)
        r = integ(f, nitn=15, neval=evals // 20)
        wall = time.perf_counter() - t
    finally:
        served.close()
    return dict(value=float(r.mean), sdev=float(r.sdev), n=served.calls, wall=wall)


def fmt_pulls(runs, exact):
    return " ".join(f"{(r['value'] - exact) / r['sdev']:+.1f}" if r["sdev"] > 0 else "—"
                    for r in runs)


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--cli", default="target/release/nis")
    p.add_argument("--evals", type=int, default=1_000_000)
    p.add_argument("--seeds", type=int, default=3)
    p.add_argument("--only", nargs="*", help="suite names to run (default: all)")
    p.add_argument("--out", default="docs/results/integration.md")
    args = p.parse_args()
    import numpy
    import vegas

    entries = suite(args.cli, args.only)
    total = sum(len(d) for _, d in entries) * args.seeds
    done, rows = 0, []
    load_start = os.getloadavg()[0]
    for name, dims in entries:
        for dim in dims:
            a, b = [], []
            for seed in range(1, args.seeds + 1):
                a.append(ours(args.cli, name, dim, args.evals, seed))
                b.append(package(args.cli, name, dim, args.evals, seed))
                done += 1
                exact = a[-1]["exact"]
                print(f"[{done}/{total}] {name} d={dim} seed={seed}: ours {a[-1]['value']:.6g} ± "
                      f"{a[-1]['sdev']:.2g} ({a[-1]['wall']:.1f} s), vegas {b[-1]['value']:.6g} ± "
                      f"{b[-1]['sdev']:.2g} ({b[-1]['wall']:.1f} s), exact {exact:.6g}",
                      file=sys.stderr, flush=True)
            rows.append((name, dim, exact, a, b))

    def rv(r, exact):
        return r["n"] * r["sdev"] ** 2 / exact ** 2

    def honest(runs, exact):
        return all(abs(r["value"] - exact) <= 4 * r["sdev"] for r in runs)

    lines = [
        "## VEGAS+: ours against the `vegas` package (`scripts/bench/bench-vegas.sh`)",
        "",
        f"Machine: {machine()}; Python {platform.python_version()}, vegas {vegas.__version__}, "
        f"numpy {numpy.__version__}"
        + ("; on a shared machine (other processes were running)." if load_start >= 0.5 else "."),
        "",
        f"Budget {args.evals:.0e} evaluations per run, seeds 1–{args.seeds}, the same integrand "
        "code on both sides (`vegas` gets its values from `nis eval` over a pipe). Ours: "
        "`nis integrate NAME --method vegas` with its defaults (20 iterations, 5 of them "
        "warm-up). `vegas`: 5 adapting iterations discarded, then 15 for the result, "
        "N/20 points each, its other settings default. Cells: the median over seeds of the "
        "relative variance per evaluation N·σ²/I² (all N evaluations counted; lower is better), "
        "then the pulls (value − exact)/σ of the seeds. Ratio: ours / `vegas` (medians); "
        "“wrong” marks a method with some |pull| > 4 (a confident wrong answer).",
        "",
        "| integrand | d | ours: rel. var. | ours: pulls | `vegas`: rel. var. | `vegas`: pulls "
        "| ours / `vegas` | s (ours, `vegas`) |",
        "|---|---:|---:|---|---:|---|---:|---|",
    ]
    for name, dim, exact, a, b in rows:
        ra = statistics.median(rv(r, exact) for r in a)
        rb = statistics.median(rv(r, exact) for r in b)
        ok_a, ok_b = honest(a, exact), honest(b, exact)
        ratio = f"{ra / rb:.2f}" if rb > 0 else "—"
        lines.append(
            f"| {name} | {dim} | {ra:.3g}{'' if ok_a else ' wrong'} | {fmt_pulls(a, exact)} | "
            f"{rb:.3g}{'' if ok_b else ' wrong'} | {fmt_pulls(b, exact)} | {ratio} | "
            f"{statistics.median(r['wall'] for r in a):.2f}, "
            f"{statistics.median(r['wall'] for r in b):.2f} |")
    section = "\n".join(lines)
    print(section)
    write_section(args.out, "vegas", section)


if __name__ == "__main__":
    main()
