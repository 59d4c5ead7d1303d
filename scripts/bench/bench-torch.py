#!/usr/bin/env python3
"""PyTorch baseline for `nis bench flow`: a reference flow written the way a PyTorch user would,
timed for (a) sampling with log-density and (b) one on-policy KL training step (sample without
grad, recompute log q with grad, backward, Adam); the median of --reps timed runs after a warm-up.

Flows (--config): R1 (default; D = 2, piecewise-quadratic couplings with 32 bins, 2 coupling
layers, one-blob encoding with 32 bins, MLP 3×256 ReLU) and R2 (D = 8, piecewise-quadratic with 16
bins, 6 coupling layers, one-blob with 32 bins per conditioner input, MLP 3×64 ReLU; layer l, in
data-to-latent order, uses partition l % 6: for bit b = 0, 1, 2 the conditioner inputs
A = {i : bit b of i is 0} and transformed dims B = the rest, then A and B swapped).

Usage: python3 scripts/bench/bench-torch.py [--batch 16384] [--batches 4096,65536,...]
           [--config R1|R2] [--device cpu|cuda] [--compile] [--reps 5]
  --batch N        one batch size (default 16384); --batches takes a comma list instead, one row
                   (or table, on CPU) per batch
  --config R1|R2   the flow (default R1)
  --device cpu     (default) eager on 1 and 2 threads: per batch a line `PyTorch V, batch N` and a
                   table `| threads | sample + log q (samples/s) | train step (samples/s) |`
                   (this is what `nis bench flow --torch` parses; with --compile a mode column
                   is added after threads)
  --device cuda    uses the running interpreter's torch (no venv), synchronises before reading
                   the clock and prints `| config | batch | mode | sample ... | train ... |`
  --compile        also times the torch.compile'd functions (mode `compile`: the whole
                   `flow.sample` under no_grad, and the loss -Σ w log q(x), whose backward and the
                   Adam step stay eager; the training step samples with the compiled sampler);
                   3 warm-up calls absorb compilation; a failure prints `compile failed: ...`
  --reps N         timed repetitions (default 5)
On CPU it creates its own virtual environment (target/torch-venv) with torch from PyPI on first use
and re-executes itself there; NIS_TORCH_NO_VENV=1 skips that and uses the running interpreter.
"""
import argparse
import os
import subprocess
import sys
import time
import traceback

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
VENV = os.path.join(ROOT, "target", "torch-venv")


def parse_args(argv=None):
    ap = argparse.ArgumentParser(description="PyTorch baseline for `nis bench flow`")
    ap.add_argument("--batch", type=int, default=16384)
    ap.add_argument("--batches", type=lambda s: [int(v) for v in s.split(",") if v])
    ap.add_argument("--config", choices=["R1", "R2"], default="R1")
    ap.add_argument("--device", choices=["cpu", "cuda"], default="cpu")
    ap.add_argument("--compile", action="store_true")
    ap.add_argument("--reps", type=int, default=5)
    return ap.parse_args(argv)


def ensure_venv(args):
    if args.device == "cuda" or os.environ.get("NIS_TORCH_NO_VENV") == "1":
        return
    py = os.path.join(VENV, "bin", "python")
    if sys.executable != py:
        if not os.path.exists(py):
            subprocess.check_call([sys.executable, "-m", "venv", VENV])
            subprocess.check_call([py, "-m", "pip", "install", "-q", "torch"])
        os.execv(py, [py] + sys.argv)


if __name__ == "__main__":
    ensure_venv(parse_args())

import torch  # noqa: E402

BLOB, MIN_W, MIN_D = 32, 1e-3, 1e-3
# dim, bins K, MLP width, coupling layers
CONFIGS = {"R1": (2, 32, 256, 2), "R2": (8, 16, 64, 6)}


def partitions(dim):
    """(A, B) per pattern: for each bit b, A = {i : bit b of i is 0}, B = the rest, then swapped."""
    out = []
    for bit in range(dim.bit_length() - 1):
        a = [i for i in range(dim) if not (i >> bit) & 1]
        b = [i for i in range(dim) if (i >> bit) & 1]
        out += [(a, b), (b, a)]
    return out


def one_blob(s):  # [n, |A|] -> [n, BLOB·|A|], dim after dim
    c = (torch.arange(BLOB, dtype=s.dtype, device=s.device) + 0.5) / BLOB
    e = torch.exp(-0.5 * BLOB * BLOB * (c - s.unsqueeze(-1)) ** 2)
    return e.reshape(s.shape[0], -1)


class Coupling(torch.nn.Module):
    def __init__(self, a, b, k, width):
        super().__init__()
        self.register_buffer("a", torch.tensor(a), persistent=False)
        self.register_buffer("b", torch.tensor(b), persistent=False)
        self.k = k
        layers, d = [], BLOB * len(a)
        for _ in range(3):
            layers += [torch.nn.Linear(d, width), torch.nn.ReLU()]
            d = width
        last = torch.nn.Linear(d, len(b) * (2 * k + 1))
        torch.nn.init.zeros_(last.weight)
        torch.nn.init.zeros_(last.bias)
        self.mlp = torch.nn.Sequential(*layers, last)

    def knots(self, xa):  # widths [n, |B|, K], vertex heights [n, |B|, K + 1]
        k = self.k
        out = self.mlp(one_blob(xa)).reshape(xa.shape[0], len(self.b), 2 * k + 1)
        w = MIN_W / k + (1 - MIN_W) * torch.softmax(out[..., :k], -1)
        e = torch.exp(out[..., k:] - out[..., k:].max(-1, keepdim=True).values)
        norm = (0.5 * (e[..., :-1] + e[..., 1:]) * w).sum(-1, keepdim=True)
        v = MIN_D + (1 - MIN_D) * e / norm
        return w, v

    def forward(self, x):  # data -> latent, log det
        k = self.k
        xa, xb = x[:, self.a], x[:, self.b]
        w, v = self.knots(xa)
        edges = torch.cumsum(w, -1)
        b = torch.searchsorted(edges, xb.unsqueeze(-1).contiguous()).clamp(max=k - 1).squeeze(-1)
        left = torch.cat([torch.zeros_like(edges[..., :1]), edges[..., :-1]], -1)
        mass = 0.5 * (v[..., :-1] + v[..., 1:]) * w
        cdf = torch.cat([torch.zeros_like(mass[..., :1]), torch.cumsum(mass, -1)[..., :-1]], -1)
        g = lambda t: t.gather(-1, b.unsqueeze(-1)).squeeze(-1)  # noqa: E731
        wb, v0, v1 = g(w), g(v), v.gather(-1, (b + 1).unsqueeze(-1)).squeeze(-1)
        alpha = ((xb - g(left)) / wb).clamp(0, 1)
        y = g(cdf) + wb * alpha * (v0 + 0.5 * alpha * (v1 - v0))
        out = x.clone()
        out[:, self.b] = y
        return out, torch.log(v0 + alpha * (v1 - v0)).sum(-1)

    def inverse(self, z):
        k = self.k
        za, zb = z[:, self.a], z[:, self.b]
        w, v = self.knots(za)
        mass = 0.5 * (v[..., :-1] + v[..., 1:]) * w
        cdf_r = torch.cumsum(mass, -1)
        b = torch.searchsorted(cdf_r, zb.unsqueeze(-1).contiguous()).clamp(max=k - 1).squeeze(-1)
        cdf = torch.cat([torch.zeros_like(mass[..., :1]), cdf_r[..., :-1]], -1)
        left = torch.cat([torch.zeros_like(w[..., :1]), torch.cumsum(w, -1)[..., :-1]], -1)
        g = lambda t: t.gather(-1, b.unsqueeze(-1)).squeeze(-1)  # noqa: E731
        wb, v0, v1 = g(w), g(v), v.gather(-1, (b + 1).unsqueeze(-1)).squeeze(-1)
        a, bq, c = 0.5 * (v1 - v0) * wb, v0 * wb, (zb - g(cdf)).clamp(min=0)
        alpha = (2 * c / (bq + torch.sqrt((bq * bq + 4 * a * c).clamp(min=0)))).clamp(0, 1)
        out = z.clone()
        out[:, self.b] = g(left) + alpha * wb
        return out, torch.log(v0 + alpha * (v1 - v0)).sum(-1)


class Flow(torch.nn.Module):
    """Built (and randomly perturbed) on the CPU, so the parameters do not depend on the device."""

    def __init__(self, config="R1", device="cpu"):
        super().__init__()
        self.dim, k, width, n_layers = CONFIGS[config]
        parts = partitions(self.dim)
        self.layers = torch.nn.ModuleList(
            [Coupling(*parts[i % len(parts)], k, width) for i in range(n_layers)]
        )
        with torch.no_grad():  # not the identity: random output layers
            for p in self.parameters():
                p.add_(0.01 * torch.randn_like(p))
        self.device = torch.device(device)
        self.to(self.device)

    def log_q(self, x):
        ld = torch.zeros(x.shape[0], device=x.device)
        for layer in self.layers:
            x, dl = layer(x)
            ld = ld + dl
        return ld

    def sample(self, n):
        x = torch.rand(n, self.dim, device=self.device)
        ld = torch.zeros(n, device=self.device)
        for layer in reversed(self.layers):
            x, dl = layer.inverse(x)
            ld = ld + dl
        return x, ld


def timed(fn, reps=5, warmup=1, sync=None):
    """Median seconds of `reps` calls after `warmup` calls; `sync` (e.g. torch.cuda.synchronize)
    runs after the warm-ups and after each call, before the clock is read."""
    for _ in range(warmup):
        fn()
    if sync:
        sync()
    ts = []
    for _ in range(reps):
        t = time.perf_counter()
        fn()
        if sync:
            sync()
        ts.append(time.perf_counter() - t)
    return sorted(ts)[reps // 2]


def benches(config, n, device, compiled):
    """(sample, train) closures on a fresh flow (seed 0) and Adam; with `compiled`, through
    torch.compile (the sampler, and the loss given the samples and weights)."""
    torch.manual_seed(0)
    flow = Flow(config, device)
    opt = torch.optim.Adam(flow.parameters(), lr=1e-3)

    def sample_ng(n):
        with torch.no_grad():
            return flow.sample(n)

    def loss_fn(x, w):
        return -(w * flow.log_q(x)).sum()

    if compiled:
        torch._dynamo.reset()
        sample_ng = torch.compile(sample_ng, dynamic=False)
        loss_fn = torch.compile(loss_fn, dynamic=False)

    def sample():
        sample_ng(n)

    def train():
        x, lq = sample_ng(n)
        with torch.no_grad():
            f = x[:, 0] + 0.1
            w = f / torch.exp(lq)
            w = w / w.sum()
        opt.zero_grad()
        loss = loss_fn(x, w)
        loss.backward()
        opt.step()

    return sample, train


def rate(n, fn, reps, compiled, sync):
    """Samples/s as a table cell; for compiled code (3 warm-ups), `compile failed: ...` if it
    raises (the traceback goes to stderr)."""
    if not compiled:
        return f"{n / timed(fn, reps, 1, sync):.0f}"
    try:
        return f"{n / timed(fn, reps, 3, sync):.0f}"
    except Exception as e:  # noqa: BLE001 -- torch.compile raises many kinds
        traceback.print_exc()
        lines = [line.strip() for line in str(e).splitlines() if line.strip()]
        msg = " ".join(lines[:3])[:300].replace("|", "/")
        return f"compile failed: {type(e).__name__}: {msg}"


def main():
    args = parse_args()
    batches = args.batches or [args.batch]
    modes = [False, True] if args.compile else [False]
    mode_name = {False: "eager", True: "compile"}
    if args.device == "cuda":
        sync = torch.cuda.synchronize
        print(f"PyTorch {torch.__version__}, device {torch.cuda.get_device_name()}")
        print("| config | batch | mode | sample + log q (samples/s) | train step (samples/s) |")
        print("|---|---:|---|---:|---:|")
        for n in batches:
            for compiled in modes:
                sample, train = benches(args.config, n, "cuda", compiled)
                s = rate(n, sample, args.reps, compiled, sync)
                t = rate(n, train, args.reps, compiled, sync)
                print(f"| {args.config} | {n} | {mode_name[compiled]} | {s} | {t} |", flush=True)
        return
    for n in batches:
        config = "" if args.config == "R1" else f", config {args.config}"
        print(f"PyTorch {torch.__version__}{config}, batch {n}")
        if args.compile:
            print("| threads | mode | sample + log q (samples/s) | train step (samples/s) |")
            print("|---:|---|---:|---:|")
        else:
            print("| threads | sample + log q (samples/s) | train step (samples/s) |")
            print("|---:|---:|---:|")
        for compiled in modes:
            # eager: one flow trained on across the thread counts; compiled: recompiled per count
            sample = train = None
            for threads in (1, 2):
                torch.set_num_threads(threads)
                if compiled or sample is None:
                    sample, train = benches(args.config, n, "cpu", compiled)
                s = rate(n, sample, args.reps, compiled, None)
                t = rate(n, train, args.reps, compiled, None)
                mode = f" {mode_name[compiled]} |" if args.compile else ""
                print(f"| {threads} |{mode} {s} | {t} |", flush=True)


if __name__ == "__main__":
    main()
