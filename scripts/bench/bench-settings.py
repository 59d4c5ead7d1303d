#!/usr/bin/env python3
"""NIS integrator settings side by side: variance per evaluation and wall time of
`nis integrate NAME --dim D --method nis --nis-config JSON` for several settings at the same
budgets and seeds, medians over seeds, against the first setting, written to a section of
docs/results/integration.md.

    scripts/bench/bench-settings.py --section ID --title TITLE --settings NAME=JSON NAME=JSON ...
                              [--cells camel:4 ...] [--evals 320000 1000000] [--seeds 3]
                              [--nis target/release/nis] [--docs docs/results/integration.md]

Each row: the median relative variance per evaluation and median seconds per setting; then, per
setting after the first, the first's median variance over its own (above 1: this one is better
per evaluation) and the same for variance × seconds (above 1: better at equal time); and the
worst |pull| of the row's runs. Needs a release build of `nis` (cargo build --release -p nis-cli).
"""

import argparse
import datetime
import json
import os
import statistics
import subprocess
import sys

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "lib"))  # scripts/lib
from docs_section import machine, write_section  # noqa: E402

CELLS = ["camel-sharp:8", "camel:4", "gauss:8", "peaks:4", "gauss-diagonal:4", "annulus:2", "camel:2"]


def run(nis, name, dim, evals, settings, seed):
    out = subprocess.run(
        [nis, "integrate", name, "--dim", str(dim), "--method", "nis", "--evals", str(evals),
         "--seed", str(seed), "--json", "--nis-config", json.dumps(settings)],
        check=True, capture_output=True, text=True,
    ).stdout
    r = json.loads(out)
    return r["rel_var_per_eval"], r["seconds"], (r["value"] - r["exact"]) / r["std_err"]


def parse_settings(items):
    named = []
    for item in items:
        name, sep, text = item.partition("=")
        if not sep:
            sys.exit(f"--settings wants NAME=JSON, got {item!r}")
        try:
            named.append((name, json.loads(text)))
        except json.JSONDecodeError as e:
            sys.exit(f"--settings {name}: {e}")
    if len(named) < 2:
        sys.exit("--settings wants at least two, the first being the baseline")
    return named


def main():
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--section", required=True, help="id of the docs section it writes")
    ap.add_argument("--title", required=True, help="heading of that section")
    ap.add_argument("--note", default="", help="a sentence on what is compared, under the heading")
    ap.add_argument("--settings", nargs="+", required=True, help="NAME=JSON, the first the baseline")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--evals", type=int, nargs="+", default=[320_000, 1_000_000])
    ap.add_argument("--cells", nargs="+", default=CELLS)
    ap.add_argument("--nis", default=os.path.join(root, "target", "release", "nis"))
    ap.add_argument("--docs", default=os.path.join(root, "docs", "results", "integration.md"))
    args = ap.parse_args()
    named = parse_settings(args.settings)
    base = named[0][0]
    rows = []
    total = len(args.cells) * len(args.evals) * len(named) * args.seeds
    done = 0
    for cell in args.cells:
        name, dim = cell.split(":")
        for evals in args.evals:
            med = {}
            for label, settings in named:
                runs = []
                for seed in range(1, args.seeds + 1):
                    runs.append(run(args.nis, name, int(dim), evals, settings, seed))
                    done += 1
                    print(f"\r[{done}/{total}] {cell} {evals} {label} seed {seed}   ",
                          end="", file=sys.stderr, flush=True)
                med[label] = (
                    statistics.median(v for v, _, _ in runs),
                    statistics.median(t for _, t, _ in runs),
                    max(abs(p) for _, _, p in runs),
                )
            rows.append((cell, evals, med))
    print(file=sys.stderr)
    when = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    others = [label for label, _ in named[1:]]
    head = " | ".join(f"{label}: rel. var/eval, s" for label, _ in named)
    ratios = " | ".join(f"{base}/{o} per eval | {base}/{o} × time" for o in others)
    settings = "; ".join(f"`{label}` = `{json.dumps(s)}`" for label, s in named)
    lines = [
        f"## {args.title} (`scripts/bench/bench-settings.py --section {args.section}`)",
        "",
        f"Machine: {machine()}, {when}. `nis integrate NAME --dim D --method nis --evals N --seed S "
        f"--nis-config JSON` with {settings}; medians over seeds 1–{args.seeds}. Ratios: the "
        f"median variance per evaluation of `{base}` over that of the other setting (above 1: the "
        "other is better), and the same for variance × seconds (above 1: the other is better at "
        "equal time); worst |pull| over all runs of the row." + (f" {args.note}" if args.note else ""),
        "",
        f"| integrand | evaluations | {head} | {ratios} | worst \\|pull\\| |",
        "|---|---:|" + "---:|" * len(named) + "---:|---:|" * len(others) + "---:|",
    ]
    for cell, evals, med in rows:
        cols = " | ".join(f"{med[label][0]:.3g}, {med[label][1]:.2f}" for label, _ in named)
        b = med[base]
        rat = " | ".join(
            f"{b[0] / med[o][0]:.2f} | {b[0] * b[1] / (med[o][0] * med[o][1]):.2f}" for o in others
        )
        worst = max(m[2] for m in med.values())
        lines.append(f"| {cell.replace(':', ' d')} | {evals:.1e} | {cols} | {rat} | {worst:.2f} |")
    write_section(args.docs, args.section, "\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
