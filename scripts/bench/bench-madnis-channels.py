#!/usr/bin/env python3
"""MadNIS's multi-channel integrator against nis on the built-in multi-channel examples, with the
same channel maps and the same prior weights, all evaluations counted (issue 39's peer row).

Both run in one venv (made by scripts/bench/bench-madnis-channels.sh): the integrand and the
channels are nis's built-ins (`nis.integrands.example`, `nis.integrands.channels`), evaluated by
the same Rust code for both. MadNIS gets, as its documentation describes for channel-dependent
mappings (`madnis.integrator.Integrand(..., remapped_dim=d, has_channel_weight_prior=True)`),
for its flow's point u in channel k: y = φ_k(u), the weight f(y)/g_k(y) and the prior channel
weights α_j(y) = a_j g_j(y) / Σ_i a_i g_i(y); its defaults otherwise (one flow conditioned on
the channel, a learned correction of the channel weights, the stratified-variance loss, Adam at
10⁻³, batches of 1024), trained on 40 % of the evaluations, as nis adapts on by default, then
`integrate` with the rest. nis: `nis.Integrator(d, "nis", channels=...)` with its defaults (one
flow conditioned on the channel, trained on the variance).

The figure is the relative variance per evaluation σ²·N/F² with N every evaluation of the
integrand (training included), the same as `nis bench channels`.

    scripts/bench/bench-madnis-channels.sh [--seeds 3] [--evals 1000000]
"""

import argparse
import json
import os
import statistics
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "lib"))
from docs_section import machine, write_section  # noqa: E402

EXAMPLES = ["resonances-4d", "phase-space-8d", "dalitz", "gauss-pm"]


def madnis_integrand(name):
    """MadNIS's Integrand for a built-in example through its own channels."""
    import numpy as np
    import torch
    from madnis.integrator import Integrand

    import nis

    f = nis.integrands.example(name)
    chans = nis.integrands.channels(name)
    dim = f.dim
    priors = np.array([c.prior for c in chans], dtype=np.float64)
    priors /= priors.sum()

    def function(u, c):
        u_np = u.detach().double().cpu().numpy()
        c_np = c.detach().cpu().numpy()
        y = np.empty_like(u_np)
        for k, chan in enumerate(chans):
            rows = c_np == k
            if rows.any():
                y[rows] = chan.sample(u_np[rows])
        g = np.stack([chan.density(y) for chan in chans], axis=1)  # (n, K)
        own = g[np.arange(len(c_np)), c_np]
        w = f(y) / own
        ag = g * priors
        alpha = ag / ag.sum(axis=1, keepdims=True)
        to = lambda a: torch.from_numpy(a).to(u.dtype)  # noqa: E731
        return to(w), to(y), to(alpha)

    integrand = Integrand(function, input_dim=dim, channel_count=len(chans), remapped_dim=dim,
                          has_channel_weight_prior=True)
    return integrand, f.exact


def run_madnis(name, seed, evals):
    import torch
    from madnis.integrator import Integrator

    torch.set_num_threads(os.cpu_count() or 1)
    torch.manual_seed(seed)
    integrand, exact = madnis_integrand(name)
    batch = 1024
    steps = int(0.4 * evals) // batch
    integ = Integrator(integrand, batch_size=batch, learning_rate=1e-3)
    t = time.perf_counter()
    integ.train(steps)
    n_final = evals - steps * batch
    value, err = integ.integrate(n_final)
    wall = time.perf_counter() - t
    return dict(method="MadNIS 1.0 (its defaults)", value=value, std_err=err, n_eval=evals,
                seconds=wall, exact=exact)


def run_nis(name, seed, evals):
    import nis

    f = nis.integrands.example(name)
    integ = nis.Integrator(f.dim, "nis", channels=nis.integrands.channels(name), seed=seed)
    t = time.perf_counter()
    r = integ(f, evals=evals)
    wall = time.perf_counter() - t
    return dict(method="nis (its defaults)", value=r.mean, std_err=r.sdev,
                n_eval=r.n_eval, seconds=wall, exact=f.exact)


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", type=int, default=3)
    p.add_argument("--evals", type=int, default=1_000_000)
    p.add_argument("--only", nargs="*", default=EXAMPLES)
    p.add_argument("--out", default="docs/results/integration.md")
    p.add_argument("--jsonl", help="also append every run as a JSON line to this file")
    p.add_argument("--reuse", action="store_true",
                   help="take the runs already in --jsonl (same evaluations) instead of rerunning them")
    args = p.parse_args()

    rows, done = {}, set()
    if args.reuse and args.jsonl and os.path.exists(args.jsonl):
        for line in open(args.jsonl):
            r = json.loads(line)
            if r["n_eval"] >= args.evals - 10 and r["example"] in args.only:
                rows.setdefault((r["example"], r["method"]), []).append(r)
                done.add((r["example"], r["seed"], r["method"].split()[0]))
    for name in args.only:
        for seed in range(1, args.seeds + 1):
            for run, key in ((run_nis, "nis"), (run_madnis, "MadNIS")):
                if (name, seed, key) in done:
                    continue
                r = run(name, seed, args.evals)
                r.update(example=name, seed=seed)
                print(json.dumps(r), file=sys.stderr, flush=True)
                if args.jsonl:
                    with open(args.jsonl, "a") as fh:
                        fh.write(json.dumps(r) + "\n")
                rows.setdefault((name, r["method"]), []).append(r)

    lines = [
        "## MadNIS on the multi-channel examples (`scripts/bench/bench-madnis-channels.sh`)",
        "",
        f"Machine: {machine()}; {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}.",
        "",
        f"{args.evals} evaluations per run, seeds 1–{args.seeds}, the same channel maps and "
        "equal priors for both (the examples' own, docs/INTEGRANDS.md); rel. var./eval = "
        "σ²·N/F² with N every evaluation (training included; for gauss-pm, whose F = 0, the absolute "
        "σ²·N), the mean over the seeds (unbiased) "
        "and the median; worst "
        "|pull| = |value − exact|/σ; median wall time of the integration call. MadNIS 1.0 with "
        "its defaults (one flow conditioned on the channel, learned channel weights, "
        "stratified-variance loss, Adam 10⁻³, batches of 1024), 40 % of the evaluations in "
        "training, torch on every core; nis with its defaults (one flow conditioned on the "
        "channel, the χ² loss, the a-priori weights adapted once, Kleiss–Pittau; "
        "docs/guide/02-integrate.md).",
        "",
        "| example | method | rel. var./eval (mean) | (median) | worst \\|pull\\| | seconds "
        "| MadNIS/nis variance | MadNIS/nis time |",
        "|---|---|---:|---:|---:|---:|---:|---:|",
    ]
    for name in args.only:
        stats = {}
        for (ex, method), rs in rows.items():
            if ex != name:
                continue
            # gauss-pm's integral is 0: its figure is the absolute σ²·N.
            rvs = [r["std_err"] ** 2 * r["n_eval"] / (r["exact"] or 1.0) ** 2 for r in rs]
            pull = max(abs(r["value"] - r["exact"]) / r["std_err"] for r in rs)
            sec = statistics.median(r["seconds"] for r in rs)
            stats[method] = (statistics.mean(rvs), statistics.median(rvs), pull, sec)
        nis_key = next(k for k in stats if k.startswith("nis"))
        for method, (rv, med, pull, sec) in sorted(stats.items(), key=lambda kv: kv[0] != nis_key):
            ratio_v = f"{rv / stats[nis_key][0]:.1f}" if method != nis_key else ""
            ratio_t = f"{sec / stats[nis_key][3]:.0f}" if method != nis_key else ""
            lines.append(f"| {name} | {method} | {rv:.3e} | {med:.3e} | {pull:.2f} | {sec:.1f} "
                         f"| {ratio_v} | {ratio_t} |")
    write_section(args.out, "madnis-channels", "\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
