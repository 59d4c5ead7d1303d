#!/usr/bin/env python3
"""Render nis-render's built-in scenes with Mitsuba 3 and compare them with our renders.

The *same* XML files (crates/nis-render/scenes/*.xml) go to both renderers. For every scene,
each renderer makes two independent renders (different seeds) at the same resolution, sample
count and max depth. We report

* the mean radiance of both (average of the two renders) and their relative difference, with
  its standard error estimated per pixel from the two seeds (pixels are independent: each has
  its own random stream), and the difference in units of that error (z);
* relMSE between our render and Mitsuba's, next to what pure noise predicts: the average of
  Mitsuba-vs-Mitsuba and nis-vs-nis (same seeds pairs), all with one common denominator (the
  mean of the four images), so that the ratio is ~1 when the two renderers agree.

With --bench it also times both renderers on the Cornell box at 256x256 (samples/s; rays/s
for nis) with Mitsuba's scalar_rgb and llvm_ad_rgb variants, in the same run.

Usage (from the repository root; Python 3.11 and pip are all that is needed):
    python3 scripts/scenes/reference-mitsuba.py                 # comparison, 128x128, 512 spp
    python3 scripts/scenes/reference-mitsuba.py --spp 1024 --res 256 --scenes cornell-box
    python3 scripts/scenes/reference-mitsuba.py --bench-only    # speed benchmark only

On first use the script creates target/mitsuba-venv and installs mitsuba (and numpy) there,
then re-runs itself inside it. It builds `nis` with cargo (release). Images and a Markdown
summary go to out/reference/. The LLVM variant needs libLLVM (Debian: apt-get install
libllvm15); without it that row of the benchmark is skipped with the reason.
"""

import argparse
import os
import re
import subprocess
import sys
import time
import venv
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
VENV = ROOT / "target" / "mitsuba-venv"
MITSUBA = "mitsuba==3.9.1"
SCENES = ["cornell-box", "cornell-indirect", "two-rooms-door", "cornell-glossy"]
EPS = 0.01  # the epsilon of relMSE and MAPE


def ensure_venv():
    """Re-run this script inside target/mitsuba-venv, creating it first if needed."""
    python = VENV / "bin" / "python"
    if Path(sys.prefix).resolve() == VENV.resolve():
        return
    if not python.exists():
        print(f"creating {VENV} and installing {MITSUBA} ...", file=sys.stderr)
        venv.create(VENV, with_pip=True)
        subprocess.run([str(python), "-m", "pip", "install", "-q", MITSUBA, "numpy"], check=True)
    os.execv(str(python), [str(python), __file__, *sys.argv[1:]])


def find_llvm():
    """Dr.Jit's LLVM backend needs LLVM >= 16; point it at one if the default is older."""
    if "DRJIT_LIBLLVM_PATH" in os.environ:
        return
    for v in (20, 19, 18, 17, 16):
        for d in ("/usr/lib/x86_64-linux-gnu", "/usr/lib64", "/usr/lib"):
            p = Path(d) / f"libLLVM-{v}.so"
            if p.exists():
                os.environ["DRJIT_LIBLLVM_PATH"] = str(p)
                return


def build_nis():
    env = dict(os.environ, CARGO_BUILD_JOBS=os.environ.get("CARGO_BUILD_JOBS", "1"))
    subprocess.run(["cargo", "build", "--release", "-p", "nis-cli"], cwd=ROOT, check=True, env=env)
    return ROOT / "target" / "release" / "nis"


def run_nis(nis, scene_xml, spp, res, seed, out):
    cmd = [str(nis), "render", str(scene_xml), "--spp", str(spp), "--res", str(res),
           "--seed", str(seed), "--out", str(out)]
    r = subprocess.run(cmd, check=True, capture_output=True, text=True)
    line = r.stdout.strip().splitlines()[-1]
    m = re.search(r"in ([\d.]+) s; ([\d.]+) M rays/s, ([\d.]+) M samples/s", line)
    return {"seconds": float(m[1]), "rays_per_s": float(m[2]) * 1e6,
            "samples_per_s": float(m[3]) * 1e6}


def bench_mitsuba(variant, spp, res):
    """Time one Mitsuba variant (run in a subprocess: an LLVM failure aborts the process)."""
    import mitsuba as mi
    import numpy as np

    mi.set_variant(variant)
    xml = ROOT / "crates" / "nis-render" / "scenes" / "cornell-box.xml"
    scene = mi.load_file(str(xml), spp=spp, res=res)
    np.array(mi.render(scene, seed=0, spp=4))  # warm-up (JIT compilation for LLVM)
    times = []
    for s in range(3):
        t = time.perf_counter()
        np.array(mi.render(scene, seed=s + 1, spp=spp))  # np.array forces evaluation
        times.append(time.perf_counter() - t)
    t = min(times)
    print(f"| Mitsuba {mi.__version__} {variant} | {t:.2f} | {res * res * spp / t / 1e6:.2f} M | n/a |")


def main():
    ensure_venv()
    find_llvm()
    if len(sys.argv) == 5 and sys.argv[1] == "--bench-mitsuba":
        bench_mitsuba(sys.argv[2], int(sys.argv[3]), int(sys.argv[4]))
        return
    import mitsuba as mi
    import numpy as np

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--spp", type=int, default=512)
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--scenes", nargs="*", default=SCENES)
    ap.add_argument("--out", type=Path, default=ROOT / "out" / "reference")
    ap.add_argument("--bench", action="store_true", help="also run the speed benchmark")
    ap.add_argument("--bench-only", action="store_true", help="only run the speed benchmark")
    ap.add_argument("--bench-spp", type=int, default=64)
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    nis = build_nis()
    report = []

    def read(path):
        return np.array(mi.Bitmap(str(path)), dtype=np.float64)[..., :3]

    if not args.bench_only:
        mi.set_variant("scalar_rgb")
        report.append(f"Comparison at {args.res}x{args.res}, {args.spp} spp per render, "
                      f"two renders (seeds) per renderer; Mitsuba {mi.__version__} scalar_rgb.\n")
        report.append("| scene | mean nis | mean Mitsuba | difference | std. err. | z "
                      "| relMSE nis vs Mitsuba | noise-only prediction | ratio | MAPE |")
        report.append("|---|---|---|---|---|---|---|---|---|---|")
        for name in args.scenes:
            xml = ROOT / "crates" / "nis-render" / "scenes" / f"{name}.xml"
            mit, ours = [], []
            for seed in (0, 1):
                scene = mi.load_file(str(xml), spp=args.spp, res=args.res)
                img = mi.render(scene, seed=seed, spp=args.spp)
                path = args.out / f"{name}-mitsuba-s{seed}.exr"
                mi.Bitmap(img).write(str(path))
                mit.append(read(path))
                path = args.out / f"{name}-nis-s{seed}.exr"
                run_nis(nis, xml, args.spp, args.res, seed + 1, path)
                ours.append(read(path))
            n = mit[0].size
            mean_m = (mit[0].mean() + mit[1].mean()) / 2
            mean_n = (ours[0].mean() + ours[1].mean()) / 2
            # Variance of one render's mean from the per-pixel two-seed differences; halved
            # for the average of two renders.
            var_m = ((mit[0] - mit[1]) ** 2 / 2).sum() / n**2 / 2
            var_n = ((ours[0] - ours[1]) ** 2 / 2).sum() / n**2 / 2
            se = np.sqrt(var_m + var_n)
            common = (mit[0] + mit[1] + ours[0] + ours[1]) / 4
            def rel(a, b):
                return float(((a - b) ** 2 / (common**2 + EPS)).mean())
            r_nm = rel(ours[0], mit[0])
            predicted = (rel(mit[0], mit[1]) + rel(ours[0], ours[1])) / 2
            mape = float((np.abs(ours[0] - mit[0]) / (np.abs(mit[0]) + EPS)).mean())
            row = (f"| {name} | {mean_n:.5f} | {mean_m:.5f} | {100 * (mean_n / mean_m - 1):+.3f}% "
                   f"| {100 * se / mean_m:.3f}% | {(mean_n - mean_m) / se:+.2f} | {r_nm:.5f} "
                   f"| {predicted:.5f} | {r_nm / predicted:.3f} | {mape:.4f} |")
            report.append(row)
            print(row, flush=True)

    if args.bench or args.bench_only:
        res, spp = 256, args.bench_spp
        xml = ROOT / "crates" / "nis-render" / "scenes" / "cornell-box.xml"
        threads = os.cpu_count()
        cpu = "unknown CPU"
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
        report.append(f"\nSpeed: cornell-box, {res}x{res}, {spp} spp, max_depth -1 (Russian roulette "
                      f"from depth 5), {threads} threads on {cpu}, best of 3.\n")
        report.append("| renderer | seconds | samples/s | rays/s |")
        report.append("|---|---|---|---|")
        best = min((run_nis(nis, xml, spp, res, s, args.out / "bench-nis.exr") for s in range(3)),
                   key=lambda r: r["seconds"])
        row = (f"| nis-render | {best['seconds']:.2f} | {best['samples_per_s'] / 1e6:.2f} M "
               f"| {best['rays_per_s'] / 1e6:.2f} M |")
        report.append(row)
        print(row, flush=True)
        for variant in ("scalar_rgb", "llvm_ad_rgb"):
            r = subprocess.run([sys.executable, __file__, "--bench-mitsuba", variant, str(spp),
                                str(res)], capture_output=True, text=True)
            rows = [l for l in r.stdout.splitlines() if l.startswith("| Mitsuba")]
            if r.returncode == 0 and rows:
                row = rows[-1]
            else:
                why = (r.stderr.strip().splitlines() or ["unknown error"])[0][:120]
                row = f"| Mitsuba {variant} | failed: {why} | | |"
            report.append(row)
            print(row, flush=True)

    text = "\n".join(report) + "\n"
    name = "benchmark.md" if args.bench_only else "summary.md"
    # Atomically, like every writer of nis: a temporary file beside it, then a rename.
    tmp = args.out / f".{name}.{os.getpid()}.tmp"
    tmp.write_text(text)
    os.replace(tmp, args.out / name)
    print(f"\nwrote {args.out / name}")


if __name__ == "__main__":
    main()
