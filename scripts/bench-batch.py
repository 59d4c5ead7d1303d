#!/usr/bin/env python3
"""The NIS integrator's training batch: variance per evaluation and wall time of
`nis integrate NAME --dim D --method nis` at two budgets for several batch sizes (the same number
of training evaluations, so a smaller batch means more Adam steps), medians over seeds, written to
docs/BENCHMARKS.md (section "training-batch").

    scripts/bench-batch.py [--batches 256 1024] [--seeds 3] [--evals 320000 1000000]
                           [--nis target/release/nis] [--docs docs/BENCHMARKS.md]

Needs a release build of `nis` (cargo build --release -p nis-cli). About 10 minutes on 2 quiet
cores with the defaults.
"""

import argparse
import datetime
import json
import os
import statistics
import subprocess
import sys

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from docs_section import machine, write_section  # noqa: E402

# The final phase alone makes the estimate (as when the table in docs/BENCHMARKS.md was taken),
# so the variance measures the flow the batch size trained, not the training pieces' shares.
REUSE = 0.0

CELLS = ["camel-sharp:8", "camel:4", "gauss:8", "peaks:4", "gauss-diagonal:4", "annulus:2", "camel:2"]


def run(nis, name, dim, evals, batch, seed):
    out = subprocess.run(
        [nis, "integrate", name, "--dim", str(dim), "--method", "nis", "--evals", str(evals),
         "--seed", str(seed), "--json", "--nis-config",
         json.dumps({"batch": batch, "reuse_training": REUSE})],
        check=True, capture_output=True, text=True,
    ).stdout
    r = json.loads(out)
    return r["rel_var_per_eval"], r["seconds"], (r["value"] - r["exact"]) / r["std_err"]


def main():
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--batches", type=int, nargs="+", default=[256, 1024])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--evals", type=int, nargs="+", default=[320_000, 1_000_000])
    ap.add_argument("--cells", nargs="+", default=CELLS)
    ap.add_argument("--nis", default=os.path.join(root, "target", "release", "nis"))
    ap.add_argument("--docs", default=os.path.join(root, "docs", "BENCHMARKS.md"))
    args = ap.parse_args()
    base = max(args.batches)
    rows = []
    total = len(args.cells) * len(args.evals) * len(args.batches) * args.seeds
    done = 0
    for cell in args.cells:
        name, dim = cell.split(":")
        for evals in args.evals:
            med = {}
            for batch in args.batches:
                runs = []
                for seed in range(1, args.seeds + 1):
                    runs.append(run(args.nis, name, int(dim), evals, batch, seed))
                    done += 1
                    print(f"\r[{done}/{total}] {cell} {evals} batch {batch} seed {seed}   ",
                          end="", file=sys.stderr, flush=True)
                med[batch] = (
                    statistics.median(v for v, _, _ in runs),
                    statistics.median(t for _, t, _ in runs),
                    max(abs(p) for _, _, p in runs),
                )
            rows.append((cell, evals, med))
    print(file=sys.stderr)
    when = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    head = " | ".join(f"batch {b}: rel. var/eval, s" for b in args.batches)
    ratios = " | ".join(f"{base}/{b}" for b in args.batches if b != base)
    lines = [
        "## Training batch (`scripts/bench-batch.py`)",
        "",
        f"Machine: {machine()}, {when}. `nis integrate NAME --dim D --method nis --evals N --seed S "
        "--nis-config '{\"batch\": B, \"reuse_training\": 0}'`: the final phase alone makes the estimate, "
        "default settings otherwise (40 % of the evaluations train, "
        f"so a smaller batch takes more Adam steps on the same evaluations); medians over seeds "
        f"1–{args.seeds}. The last columns: variance per evaluation with batch {base} over that with "
        "the smaller batch (above 1: the smaller batch is better); worst |pull| over all runs of the row.",
        "",
        f"| integrand | evaluations | {head} | {ratios} | worst \\|pull\\| |",
        "|---|---:|" + "---:|" * len(args.batches) + "---:|" * (len(args.batches) - 1) + "---:|",
    ]
    for cell, evals, med in rows:
        cols = " | ".join(f"{med[b][0]:.3g}, {med[b][1]:.2f}" for b in args.batches)
        rat = " | ".join(f"{med[base][0] / med[b][0]:.2f}" for b in args.batches if b != base)
        worst = max(m[2] for m in med.values())
        lines.append(f"| {cell.replace(':', ' d')} | {evals:.1e} | {cols} | {rat} | {worst:.2f} |")
    write_section(args.docs, "training-batch", "\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
