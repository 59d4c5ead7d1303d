#!/usr/bin/env python3
"""The scene-reader feature scenes and their Mitsuba 3 reference means.

Writes crates/nis-render/tests/scenes/features/*.xml (one small scene per feature the reader
supports: filters, BSDFs, spectra, emitters, shapes, Mitsuba 0.x names, integrator plugins),
renders each with Mitsuba 3 (scalar_rgb) over several seeds, and writes their mean radiance and
its standard error to mitsuba-means.json beside them; `tests/mitsuba_features.rs` renders the
same files with nis-render and compares. A scene that Mitsuba 3 itself cannot read as written
(a Mitsuba 0.4 `<lookAt>`, a guiding paper's integrator plugin) is rendered from its Mitsuba 3
twin, which says the same thing in Mitsuba 3's words.

    python3 -m venv target/mitsuba-venv && target/mitsuba-venv/bin/pip install mitsuba==3.9.1
    target/mitsuba-venv/bin/python scripts/scenes/feature-references.py [--spp 4096] [--seeds 4]
"""
import argparse
import json
import math
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
OUT = ROOT / "crates/nis-render/tests/scenes/features"
RES = 24

BASE = """<?xml version="1.0" encoding="utf-8"?>
<!-- nis-render feature scene '{name}' (scripts/scenes/feature-references.py writes it). -->
<scene version="{version}">
    <default name="spp" value="64"/>
    {integrator}
    <sensor type="perspective">
        <float name="fov" value="40"/>
        <transform name="to_world">
            <lookat origin="0, 1.6, 3" target="0, 0.4, 0" up="0, 1, 0"/>
        </transform>
        <sampler type="independent">
            <integer name="sample_count" value="$spp"/>
        </sampler>
        <film type="hdrfilm">
            <integer name="width" value="{res}"/>
            <integer name="height" value="{res}"/>
            {filter}
        </film>
    </sensor>
    <shape type="rectangle">
        <transform name="to_world"><rotate x="1" angle="-90"/><scale value="2"/></transform>
        {floor}
    </shape>
    <shape type="sphere">
        <point name="center" x="0" y="0.5" z="0"/>
        <float name="radius" value="0.5"/>
        {sphere}
    </shape>
    {light}
</scene>
"""

AREA = """<shape type="rectangle">
        <transform name="to_world"><rotate x="1" angle="90"/><scale value="0.5"/><translate x="0.4" y="2.2" z="0.3"/></transform>
        <emitter type="area"><rgb name="radiance" value="12, 11, 10"/></emitter>
    </shape>
    <emitter type="constant"><rgb name="radiance" value="0.15, 0.2, 0.25"/></emitter>"""

DIFFUSE = '<bsdf type="diffuse"><rgb name="reflectance" value="0.6, 0.55, 0.5"/></bsdf>'
PATH = '<integrator type="path"><integer name="max_depth" value="8"/></integrator>'
BOX = '<rfilter type="box"/>'


def scene(name, *, floor=DIFFUSE, sphere=DIFFUSE, light=AREA, integrator=PATH, rfilter=BOX,
          version="3.0.0"):
    return BASE.format(name=name, version=version, integrator=integrator, res=RES,
                       filter=rfilter, floor=floor, sphere=sphere, light=light)


def features():
    """(name, our XML, Mitsuba 3's XML or None when it reads ours as written)."""
    out = []

    def add(name, mitsuba=None, **kw):
        out.append((name, scene(name, **kw), mitsuba))

    add("filter-gaussian", rfilter="")
    add("filter-tent", rfilter='<rfilter type="tent"><float name="radius" value="1.5"/></rfilter>')
    add("plastic", sphere='<bsdf type="plastic"><rgb name="diffuse_reflectance" value="0.6, 0.2, 0.1"/></bsdf>',
        floor='<bsdf type="plastic"/>')
    add("roughplastic-beckmann",
        sphere='<bsdf type="roughplastic"><float name="alpha" value="0.2"/><boolean name="nonlinear" value="true"/>'
               '<rgb name="diffuse_reflectance" value="0.1, 0.3, 0.7"/></bsdf>')
    add("roughplastic-ggx",
        floor='<bsdf type="roughplastic"><string name="distribution" value="ggx"/><float name="alpha" value="0.3"/></bsdf>')
    add("roughconductor-beckmann",
        sphere='<bsdf type="roughconductor"><string name="material" value="Au"/><float name="alpha" value="0.15"/></bsdf>',
        floor='<bsdf type="roughconductor"><string name="material" value="Al"/><float name="alpha" value="0.3"/></bsdf>')
    add("conductor-named", sphere='<bsdf type="conductor"><string name="material" value="Cu"/></bsdf>')
    add("roughdielectric-beckmann",
        sphere='<bsdf type="roughdielectric"><float name="alpha" value="0.2"/></bsdf>')
    add("thindielectric", sphere='<bsdf type="thindielectric"/>')
    add("mask", sphere='<bsdf type="mask"><float name="opacity" value="0.4"/>'
                       '<bsdf type="diffuse"><rgb name="reflectance" value="0.8, 0.1, 0.1"/></bsdf></bsdf>')
    add("spectra",
        sphere='<bsdf type="diffuse"><spectrum name="reflectance" value="400:0.04, 500:0.06, 550:0.3, 600:0.6, 700:0.64"/></bsdf>',
        light="""<shape type="rectangle">
        <transform name="to_world"><rotate x="1" angle="90"/><scale value="0.5"/><translate x="0.4" y="2.2" z="0.3"/></transform>
        <emitter type="area"><spectrum name="radiance" value="400:0, 500:8, 600:15.6, 700:18.4"/></emitter>
    </shape>
    <emitter type="constant"><spectrum name="radiance" value="0.2"/></emitter>""")
    add("integrator-direct", integrator='<integrator type="direct"/>')
    add("directional", light=AREA + """
    <emitter type="directional"><vector name="direction" x="-0.4" y="-1" z="-0.3"/><rgb name="irradiance" value="2, 1.8, 1.5"/></emitter>""")
    add("disk", light="""<shape type="disk">
        <transform name="to_world"><rotate x="1" angle="90"/><scale value="0.4"/><translate x="0.4" y="2.2" z="0.3"/></transform>
        <emitter type="area"><rgb name="radiance" value="12, 11, 10"/></emitter>
    </shape>
    <shape type="disk">
        <transform name="to_world"><scale value="0.6"/><translate x="-0.8" y="0.8" z="-1.2"/></transform>
        <bsdf type="diffuse"><rgb name="reflectance" value="0.2, 0.7, 0.3"/></bsdf>
    </shape>""")
    add("integrator-plugin", mitsuba=scene("integrator-plugin", integrator='<integrator type="path"><integer name="max_depth" value="6"/></integrator>'),
        integrator='<integrator type="guided_path"><integer name="max_depth" value="6"/><string name="budget_type" value="spp"/></integrator>')
    legacy = scene("legacy-0.5", version="0.5.0",
                   sphere='<bsdf type="roughconductor"><float name="alpha" value="0.2"/><string name="material" value="Cu"/>'
                          '<float name="extEta" value="1.0"/></bsdf>',
                   floor='<bsdf type="diffuse"><srgb name="diffuseReflectance" value="0.5, 0.6, 0.7"/></bsdf>',
                   integrator='<integrator type="path"><integer name="maxDepth" value="8"/><integer name="rrDepth" value="5"/></integrator>')
    legacy = (legacy.replace('name="to_world"', 'name="toWorld"').replace("<lookat", "<lookAt")
              .replace('name="sample_count"', 'name="sampleCount"'))
    twin = scene("legacy-0.5",
                 sphere='<bsdf type="roughconductor"><float name="alpha" value="0.2"/><string name="material" value="Cu"/></bsdf>',
                 floor='<bsdf type="diffuse"><rgb name="reflectance" value="%s"/></bsdf>'
                       % ", ".join(f"{srgb_to_linear(c):.6f}" for c in (0.5, 0.6, 0.7)),
                 integrator='<integrator type="path"><integer name="max_depth" value="8"/><integer name="rr_depth" value="5"/></integrator>')
    out.append(("legacy-0.5", legacy, twin))
    return out


def srgb_to_linear(c):
    return c / 12.92 if c <= 0.04045 else ((c + 0.055) / 1.055) ** 2.4


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spp", type=int, default=4096, help="samples per pixel per seed")
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--only", nargs="*", help="feature names to render (default: all)")
    args = ap.parse_args()
    import mitsuba as mi
    mi.set_variant("scalar_rgb")
    OUT.mkdir(parents=True, exist_ok=True)
    means_path = OUT / "mitsuba-means.json"
    means = json.loads(means_path.read_text()) if means_path.exists() else {}
    for name, ours, theirs in features():
        (OUT / f"{name}.xml").write_text(ours)
        if args.only and name not in args.only:
            continue
        with tempfile.NamedTemporaryFile("w", suffix=".xml", delete=False) as f:
            f.write(theirs or ours)
        sc = mi.load_file(f.name, spp=args.spp)
        values = []
        for seed in range(args.seeds):
            img = mi.TensorXf(mi.render(sc, seed=seed + 1, spp=args.spp))
            import numpy as np
            values.append(float(np.asarray(img)[..., :3].mean()))
        m = sum(values) / len(values)
        se = math.sqrt(sum((v - m) ** 2 for v in values) / (len(values) - 1) / len(values))
        means[name] = {"mean": m, "std_err": se, "spp": args.spp * args.seeds, "mitsuba": mi.__version__}
        print(f"{name:28s} {m:.6f} ± {se:.6f}", flush=True)
    means_path.write_text(json.dumps(means, indent=1, sort_keys=True) + "\n")
    print(f"wrote {means_path}")


if __name__ == "__main__":
    main()
