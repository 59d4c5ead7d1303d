#!/usr/bin/env python3
"""Render scene files with nis and with Mitsuba 3 (scalar_rgb) at equal settings and compare
their image means: the check that a published scene reads as Mitsuba reads it.

Mitsuba 3 refuses some files as published (a Mitsuba 0.4 `<lookAt>`, a guiding paper's
integrator plugin, a Mitsuba 0.5 `sunsky`): those are handed to it upgraded the way nis reads
them (camelCase names to snake_case, `lookAt`, `srgb` colours, a wrapper integrator (`moment`) as the one it holds, other integrators as `path`,
0.x's mipmapped bitmap filters as bilinear and its bitmap `gamma`, a 0.5 sunsky's frame, scales and sun radius as
`upgrade_sunsky` says, a 0.x `roughdiffuse` as `diffuse`, 0.x film settings Mitsuba 3 lacks such as
`gamma` and `banner` dropped), which says the same thing in Mitsuba 3's words. Shapes whose mesh files are missing are left out for both renderers.

    python3 -m venv target/mitsuba-venv && target/mitsuba-venv/bin/pip install mitsuba==3.9.1 numpy
    cargo build --release -p nis-cli
    target/mitsuba-venv/bin/python scripts/scenes/compare-scenes.py SCENE.xml ... [--spp 16] [--seeds 8]

Both render each scene at its own film size. Prints a Markdown table: both means, their standard
errors (from the spread of `--seeds` seeds' means, 1, 2, …; two by default) and the difference.
Two seeds give a standard error of one degree of freedom, often several times too small on a
scene whose mean rests on rare bright paths (glass, caustics): use eight or more before calling a
difference real (docs/results/guiding.md, `veach-bidir`).
"""
import argparse
import math
import re
import subprocess
import sys
import tempfile
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
NIS = ROOT / "target" / "release" / "nis"


def snake(name):
    return re.sub(r"(?<=[a-z])([A-Z]+)", lambda m: "_" + m.group(1).lower(), name)


def srgb_to_linear(c):
    return c / 12.92 if c <= 0.04045 else ((c + 0.055) / 1.055) ** 2.4


# Mitsuba 0.5's apparent diameter of the sun, degrees.
SUN_DIAMETER_0_5 = 0.5358
# Mitsuba 3's z-up sky frame onto Mitsuba 0.5's y-up one, row by row (a reflection: 0.5 puts the
# sun of zenith angle t and azimuth p at (sin p sin t, cos t, -cos p sin t), Mitsuba 3 at
# (-cos p sin t, -sin p sin t, cos t)).
SKY_FRAME_0_5 = "0 -1 0 0 0 0 1 0 1 0 0 0 0 0 0 1"


def upgrade_sunsky(e):
    """A Mitsuba 0.5 sunsky (names already snake_case) as nis reads it
    (crates/nis-render/src/xml/upgrade.rs): its frame before its to_world, `scale` as the
    default of sun_scale and sky_scale, sun_radius_scale r as sun_aperture r * 0.5358 degrees,
    0.5's albedo default 0.15, `resolution` dropped."""
    def take(name):
        c = e.find(f"*[@name='{name}']")
        if c is not None:
            e.remove(c)
            return float(c.get("value"))
        return None

    def has(name):
        return e.find(f"*[@name='{name}']") is not None

    def add(name, value):
        ET.SubElement(e, "float", name=name, value=repr(value))

    scale = take("scale")
    if scale is not None:
        for name in ("sun_scale", "sky_scale"):
            if not has(name):
                add(name, scale)
    radius = take("sun_radius_scale")
    if radius is not None:
        add("sun_aperture", radius * SUN_DIAMETER_0_5)
    if take("stretch") not in (None, 1.0):
        raise ValueError("a sunsky's stretch has no Mitsuba 3 equivalent")
    take("resolution")
    if not has("albedo"):
        add("albedo", 0.15)
    t = e.find("transform[@name='to_world']")
    if t is None:
        t = ET.SubElement(e, "transform", name="to_world")
    t.insert(0, ET.Element("matrix", value=SKY_FRAME_0_5))


# Mitsuba 0.x film properties (ldrfilm's tonemapping, the banner) that Mitsuba 3 lacks.
FILM_0_X = ("gamma", "banner", "high_quality_edges", "attach_log", "tonemap_method", "exposure",
            "key", "burn")


def upgrade(root, base):
    """Mitsuba 0.x names to Mitsuba 3's, other integrators to path, missing meshes out."""
    legacy = int(root.get("version", "3").split(".")[0]) < 2
    folders = [base] + [base / p.get("value") for p in root.iter("path")]
    for parent in root.iter():
        for e in list(parent):
            f = e.find("string[@name='filename']")
            if e.tag == "shape" and f is not None and not any(
                    (d / f.get("value")).exists() for d in folders):
                parent.remove(e)
            # A wrapper (`moment`, `aov`) as nis reads it: the integrator it holds.
            while e.tag == "integrator" and len(e.findall("integrator")) == 1:
                inner = e.find("integrator")
                parent[list(parent).index(e)] = inner
                e = inner
    for e in root.iter():
        if legacy:
            if e.tag == "lookAt":
                e.tag = "lookat"
            if e.tag == "srgb":
                e.tag = "rgb"
                v = [float(x) for x in re.split(r"[,\s]+", e.get("value").strip())]
                e.set("value", ", ".join(str(srgb_to_linear(x)) for x in v))
            if e.get("name") and e.tag != "default":
                e.set("name", snake(e.get("name")))
            if e.tag == "bsdf" and e.get("type") == "diffuse":
                for c in e:
                    if c.get("name") == "diffuse_reflectance":
                        c.set("name", "reflectance")
            if e.tag == "bsdf" and e.get("type") == "roughdiffuse":
                # Mitsuba 3 has no Oren-Nayar: a diffuse of the same reflectance, as nis reads it.
                e.set("type", "diffuse")
                for c in list(e):
                    if c.get("name") in ("alpha", "use_fast_approx"):
                        e.remove(c)
            if e.tag == "film":
                # 0.x film settings Mitsuba 3's hdrfilm refuses and nis ignores (xml/sensor.rs).
                e.set("type", "hdrfilm")
                for c in list(e):
                    if c.get("name") in FILM_0_X:
                        e.remove(c)
        if e.tag == "bsdf" and e.get("type") in ("conductor", "roughconductor"):
            # Mitsuba 0.x's exterior index, which Mitsuba 3 lacks: only air is expressible.
            for c in list(e):
                if c.get("name") in ("ext_eta", "extEta") and float(c.get("value")) == 1.0:
                    e.remove(c)
        if e.tag == "integrator" and e.get("type") not in ("path", "direct"):
            keep = [c for c in e if c.get("name") in ("max_depth", "rr_depth", "hide_emitters")]
            for c in list(e):
                e.remove(c)
            e.extend(keep)
            e.set("type", "path")
    if legacy:
        for e in root.iter():
            if e.tag == "emitter" and e.get("type") == "sunsky":
                upgrade_sunsky(e)
            if e.tag == "texture" and e.get("type") == "bitmap":
                # Mitsuba 0.x's mipmapped filters, read as bilinear (nis: xml/texture.rs).
                for c in e.findall("string[@name='filter_type']"):
                    if c.get("value") in ("ewa", "trilinear"):
                        c.set("value", "bilinear")
                # 0.x's gamma: 1 is linear (Mitsuba 3's raw), anything else sRGB.
                for c in e.findall("float[@name='gamma']"):
                    e.remove(c)
                    if float(c.get("value")) == 1.0:
                        ET.SubElement(e, "boolean", name="raw", value="true")
    root.set("version", "3.0.0")


def mean_and_error(means):
    """The mean of per-seed means and its standard error."""
    means = np.asarray(means)
    return float(means.mean()), float(means.std(ddof=1) / math.sqrt(len(means)))


def mitsuba_mean(path, spp, seeds):
    import mitsuba as mi
    mi.set_variant("scalar_rgb")
    base = path.parent
    tree = ET.parse(path)
    upgrade(tree.getroot(), base)
    with tempfile.NamedTemporaryFile("wb", suffix=".xml", dir=base, delete=False) as f:
        tree.write(f)
    try:
        scene = mi.load_file(f.name)
    finally:
        Path(f.name).unlink()
    means = [float(np.asarray(mi.render(scene, seed=s, spp=spp))[..., :3].mean())
             for s in range(1, seeds + 1)]
    return mean_and_error(means)


def nis_mean(path, spp, seeds):
    means = []
    for seed in range(1, seeds + 1):
        with tempfile.TemporaryDirectory() as d:
            out = Path(d) / "img.exr"
            subprocess.run([str(NIS), "render", str(path), "--spp", str(spp),
                            "--seed", str(seed), "--drop-missing-meshes", "--out", str(out)],
                           check=True, capture_output=True)
            import mitsuba as mi
            mi.set_variant("scalar_rgb")
            means.append(float(np.asarray(mi.Bitmap(str(out)))[..., :3].mean()))
    return mean_and_error(means)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenes", nargs="+", type=Path)
    ap.add_argument("--spp", type=int, default=16)
    ap.add_argument("--seeds", type=int, default=2,
                    help="seeds per renderer (1, 2, …), at least 2; their spread gives the errors")
    args = ap.parse_args()
    if args.seeds < 2:
        ap.error("--seeds must be at least 2")
    print(f"<!-- each at its own film size, {args.spp} spp × {args.seeds} seeds -->")
    print("| scene | nis | Mitsuba 3 | difference (± its standard error) |")
    print("|---|---|---|---|")
    for path in args.scenes:
        try:
            ours, ours_se = nis_mean(path.resolve(), args.spp, args.seeds)
            theirs, theirs_se = mitsuba_mean(path.resolve(), args.spp, args.seeds)
        except Exception as e:  # one scene's failure is a row, not the end of the table
            print(f"| {path} | failed: {str(e).splitlines()[-1][:120]} | | |", flush=True)
            continue
        diff = 100 * (ours / theirs - 1)
        sigma = 100 * math.hypot(ours_se, theirs_se) / theirs
        print(f"| {path} | {ours:.5f} ± {ours_se:.5f} | {theirs:.5f} ± {theirs_se:.5f} | "
              f"{diff:+.2f} % (± {sigma:.2f}) |", flush=True)


if __name__ == "__main__":
    sys.exit(main())
