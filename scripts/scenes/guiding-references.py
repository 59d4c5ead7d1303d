#!/usr/bin/env python3
"""Render the references of `nis bench guiding` with Mitsuba 3: each scene file at the bench's
image size (longer side --res, the film's aspect ratio, rounded half up as nis does), with the
path integrator at high spp, into the bench's reference cache, where the bench prefers it to
its own path-traced reference.

Files are handed to Mitsuba upgraded the way nis reads them (see compare-scenes.py: Mitsuba
0.x names, a guiding paper's integrator read as `path`, missing meshes left out, which the
bench must then be told with --drop-missing-meshes).

    python3 -m venv target/mitsuba-venv && target/mitsuba-venv/bin/pip install mitsuba==3.9.1 numpy
    target/mitsuba-venv/bin/python scripts/scenes/guiding-references.py SCENE.xml ... \\
        [--res 128] [--spp 4096] [--out out/guiding]

Writes OUT/reference/NAME-RES-SPPspp-mitsuba.exr, NAME being the file's stem, or its folder's
name for a file called scene.xml (as the bench names it). Renders in passes of --pass-spp with
distinct seeds and averages them, printing progress; a reference already there is kept.
"""
import argparse
import importlib.util
import math
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
spec = importlib.util.spec_from_file_location("compare_scenes", HERE / "compare-scenes.py")
compare_scenes = importlib.util.module_from_spec(spec)
spec.loader.exec_module(compare_scenes)

# The seed salt of the bench's own references (REFERENCE_SEED_SALT): not any render's seed.
SEED = 0x0005EED0F4EF & 0xFFFF_FFFF  # Mitsuba takes 32-bit seeds


def name_of(path):
    return path.parent.name if path.stem == "scene" else path.stem


def fit(width, height, res):
    scaled = lambda a, b: max(1, math.floor(a * res / b + 0.5))
    return (res, scaled(height, width)) if width >= height else (scaled(width, height), res)


def resize_film(root, res):
    """Sets the film's width and height to the bench's size; returns it."""
    defaults = {d.get("name"): d.get("value") for d in root.iter("default")}
    film = next(root.iter("film"))
    sizes = {"width": 768, "height": 576}  # Mitsuba's hdrfilm defaults
    elements = {}
    for e in film.findall("integer"):
        if e.get("name") in sizes:
            value = e.get("value")
            if value.startswith("$"):
                value = defaults[value[1:]]
            sizes[e.get("name")] = int(value)
            elements[e.get("name")] = e
    w, h = fit(sizes["width"], sizes["height"], res)
    for key, value in (("width", w), ("height", h)):
        e = elements.get(key)
        if e is None:
            e = ET.SubElement(film, "integer", name=key)
        e.set("value", str(value))
    return w, h


def render(path, args):
    import mitsuba as mi
    mi.set_variant(args.variant)
    out = args.out / "reference" / f"{name_of(path)}-{args.res}-{args.spp}spp-mitsuba.exr"
    if out.exists():
        print(f"{path}: kept {out}")
        return
    tree = ET.parse(path)
    root = tree.getroot()
    compare_scenes.upgrade(root, path.parent)
    w, h = resize_film(root, args.res)
    with tempfile.NamedTemporaryFile("wb", suffix=".xml", dir=path.parent, delete=False) as f:
        tree.write(f)
    try:
        scene = mi.load_file(f.name)
    finally:
        Path(f.name).unlink()
    passes = max(1, math.ceil(args.spp / args.pass_spp))
    total = np.zeros((h, w, 3))
    start = time.time()
    done = 0
    for k in range(passes):
        spp = min(args.pass_spp, args.spp - done)
        image = np.asarray(mi.render(scene, seed=(SEED + k) & 0xFFFF_FFFF, spp=spp))[..., :3]
        total += spp * image
        done += spp
        print(f"\r{path}: {done}/{args.spp} spp, {time.time() - start:.0f} s", end="",
              flush=True)
    print()
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(".tmp.exr")
    mi.Bitmap((total / done).astype(np.float32), mi.Bitmap.PixelFormat.RGB).write(str(tmp))
    tmp.replace(out)  # atomic: a cut-off run leaves no half reference
    print(f"{path}: {w}×{h}, mean {float((total / done).mean()):.5f} -> {out}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenes", nargs="+", type=Path)
    ap.add_argument("--res", type=int, default=128)
    ap.add_argument("--spp", type=int, default=4096)
    ap.add_argument("--pass-spp", type=int, default=256)
    ap.add_argument("--out", type=Path, default=Path("out/guiding"))
    ap.add_argument("--variant", default="scalar_rgb", help="Mitsuba variant")
    args = ap.parse_args()
    for path in args.scenes:
        render(path.resolve(), args)


if __name__ == "__main__":
    sys.exit(main())
