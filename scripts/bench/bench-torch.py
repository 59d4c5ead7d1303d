#!/usr/bin/env python3
"""PyTorch eager baseline for `nis bench flow`: the reference flow R1 (D = 2, piecewise-quadratic
couplings with 32 bins, 2 coupling layers, one-blob encoding with 32 bins, MLP 3×256) written the
way a PyTorch user would, timed for (a) sampling with log-density and (b) one on-policy KL
training step (sample without grad, recompute log q with grad, backward, Adam), batch 16384, on
1 and 2 threads.

Usage: python3 scripts/bench/bench-torch.py [--batch 16384]
It creates its own virtual environment (target/torch-venv) with torch from PyPI on first use.
"""
import os
import subprocess
import sys
import time

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
VENV = os.path.join(ROOT, "target", "torch-venv")


def ensure_venv():
    py = os.path.join(VENV, "bin", "python")
    if sys.executable != py:
        if not os.path.exists(py):
            subprocess.check_call([sys.executable, "-m", "venv", VENV])
            subprocess.check_call([py, "-m", "pip", "install", "-q", "torch"])
        os.execv(py, [py] + sys.argv)


ensure_venv()

import argparse  # noqa: E402

import torch  # noqa: E402

K, BLOB, WIDTH, MIN_W, MIN_D = 32, 32, 256, 1e-3, 1e-3


def one_blob(s):
    c = (torch.arange(BLOB, dtype=s.dtype) + 0.5) / BLOB
    return torch.exp(-0.5 * BLOB * BLOB * (c - s.unsqueeze(-1)) ** 2)


class Coupling(torch.nn.Module):
    def __init__(self, a, b):
        super().__init__()
        self.a, self.b = a, b
        layers, d = [], BLOB
        for _ in range(3):
            layers += [torch.nn.Linear(d, WIDTH), torch.nn.ReLU()]
            d = WIDTH
        last = torch.nn.Linear(d, 2 * K + 1)
        torch.nn.init.zeros_(last.weight)
        torch.nn.init.zeros_(last.bias)
        self.mlp = torch.nn.Sequential(*layers, last)

    def knots(self, xa):
        out = self.mlp(one_blob(xa))
        w = MIN_W / K + (1 - MIN_W) * torch.softmax(out[:, :K], -1)
        e = torch.exp(out[:, K:] - out[:, K:].max(-1, keepdim=True).values)
        norm = (0.5 * (e[:, :-1] + e[:, 1:]) * w).sum(-1, keepdim=True)
        v = MIN_D + (1 - MIN_D) * e / norm
        return w, v

    def forward(self, x):  # data -> latent, log det
        xa, xb = x[:, self.a], x[:, self.b]
        w, v = self.knots(xa)
        edges = torch.cumsum(w, -1)
        b = torch.searchsorted(edges, xb.unsqueeze(-1).contiguous()).clamp(max=K - 1).squeeze(-1)
        left = torch.cat([torch.zeros_like(edges[:, :1]), edges[:, :-1]], -1)
        mass = 0.5 * (v[:, :-1] + v[:, 1:]) * w
        cdf = torch.cat([torch.zeros_like(mass[:, :1]), torch.cumsum(mass, -1)[:, :-1]], -1)
        g = lambda t: t.gather(-1, b.unsqueeze(-1)).squeeze(-1)  # noqa: E731
        wb, v0, v1 = g(w), g(v), v.gather(-1, (b + 1).unsqueeze(-1)).squeeze(-1)
        alpha = ((xb - g(left)) / wb).clamp(0, 1)
        y = g(cdf) + wb * alpha * (v0 + 0.5 * alpha * (v1 - v0))
        out = x.clone()
        out[:, self.b] = y
        return out, torch.log(v0 + alpha * (v1 - v0))

    def inverse(self, z):
        za, zb = z[:, self.a], z[:, self.b]
        w, v = self.knots(za)
        mass = 0.5 * (v[:, :-1] + v[:, 1:]) * w
        cdf_r = torch.cumsum(mass, -1)
        b = torch.searchsorted(cdf_r, zb.unsqueeze(-1).contiguous()).clamp(max=K - 1).squeeze(-1)
        cdf = torch.cat([torch.zeros_like(mass[:, :1]), cdf_r[:, :-1]], -1)
        left = torch.cat([torch.zeros_like(w[:, :1]), torch.cumsum(w, -1)[:, :-1]], -1)
        g = lambda t: t.gather(-1, b.unsqueeze(-1)).squeeze(-1)  # noqa: E731
        wb, v0, v1 = g(w), g(v), v.gather(-1, (b + 1).unsqueeze(-1)).squeeze(-1)
        a, bq, c = 0.5 * (v1 - v0) * wb, v0 * wb, (zb - g(cdf)).clamp(min=0)
        alpha = (2 * c / (bq + torch.sqrt((bq * bq + 4 * a * c).clamp(min=0)))).clamp(0, 1)
        out = z.clone()
        out[:, self.b] = g(left) + alpha * wb
        return out, torch.log(v0 + alpha * (v1 - v0))


class Flow(torch.nn.Module):
    def __init__(self):
        super().__init__()
        self.layers = torch.nn.ModuleList([Coupling(0, 1), Coupling(1, 0)])
        with torch.no_grad():  # not the identity: random output layers
            for p in self.parameters():
                p.add_(0.01 * torch.randn_like(p))

    def log_q(self, x):
        ld = torch.zeros(x.shape[0])
        for layer in self.layers:
            x, l = layer(x)
            ld = ld + l
        return ld

    def sample(self, n):
        x, ld = torch.rand(n, 2), torch.zeros(n)
        for layer in reversed(self.layers):
            x, l = layer.inverse(x)
            ld = ld + l
        return x, ld


def timed(fn, reps=5):
    fn()
    ts = []
    for _ in range(reps):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return sorted(ts)[reps // 2]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--batch", type=int, default=16384)
    args = ap.parse_args()
    torch.manual_seed(0)
    flow = Flow()
    opt = torch.optim.Adam(flow.parameters(), lr=1e-3)
    n = args.batch

    def sample():
        with torch.no_grad():
            flow.sample(n)

    def train():
        with torch.no_grad():
            x, lq = flow.sample(n)
            f = x[:, 0] + 0.1
            w = f / torch.exp(lq)
            w = w / w.sum()
        opt.zero_grad()
        loss = -(w * flow.log_q(x)).sum()
        loss.backward()
        opt.step()

    print(f"PyTorch {torch.__version__}, batch {n}")
    print("| threads | sample + log q (samples/s) | train step (samples/s) |")
    print("|---:|---:|---:|")
    for threads in (1, 2):
        torch.set_num_threads(threads)
        print(f"| {threads} | {n / timed(sample):.0f} | {n / timed(train):.0f} |")


if __name__ == "__main__":
    main()
