#!/usr/bin/env python3
"""Mitsuba 3's `principled` BSDF evaluated at fixed directions: the values and densities that
`crates/nis-render/src/bsdf/principled_tests.rs` pins (`principled_matches_mitsuba_eval_and_pdf`).

Prints Rust rows `(case, wo, wi, f, pdf)` in nis's convention: `wo` towards the viewer
(Mitsuba's `si.wi`), `wi` the scattered direction, `f` without the cosine (Mitsuba's value over
|wi.z|).

    target/mitsuba-venv/bin/python scripts/scenes/principled-eval.py
"""
import math

import mitsuba as mi

mi.set_variant("scalar_rgb")

# The cases: Mitsuba parameters; the test builds the same BSDFs.
CASES = [
    {"base_color": [0.8, 0.3, 0.2], "roughness": 0.4, "sheen": 0.5, "sheen_tint": 0.5,
     "clearcoat": 0.7, "clearcoat_gloss": 0.3, "spec_tint": 0.3, "flatness": 0.3, "eta": 1.5},
    {"base_color": [0.9, 0.6, 0.3], "roughness": 0.25, "metallic": 0.8, "specular": 0.6},
    {"base_color": [0.7, 0.9, 0.8], "roughness": 0.3, "spec_trans": 0.7, "metallic": 0.1,
     "clearcoat": 0.3, "eta": 1.45},
    {"base_color": [0.6, 0.8, 0.4], "roughness": 0.45, "anisotropic": 0.8, "spec_trans": 0.5,
     "metallic": 0.3, "clearcoat": 0.4, "eta": 1.5},
]


def direction(theta_deg, phi):
    t = math.radians(theta_deg)
    return [math.sin(t) * math.cos(phi), math.sin(t) * math.sin(phi), math.cos(t)]


PAIRS = [
    (direction(30, 0.2), direction(45, 2.5)),
    (direction(60, 0.0), direction(60, math.pi + 0.1)),
    (direction(10, 1.0), direction(80, 4.0)),
    (direction(50, 0.5), direction(140, 3.5)),
    (direction(130, 0.3), direction(150, 2.0)),
    (direction(120, 1.0), direction(20, 4.0)),
]


def main():
    for k, case in enumerate(CASES):
        d = {"type": "principled"}
        for name, v in case.items():
            d[name] = {"type": "rgb", "value": v} if isinstance(v, list) else v
        bsdf = mi.load_dict(d)
        ctx = mi.BSDFContext()
        for wo, wi in PAIRS:
            si = mi.SurfaceInteraction3f()
            # The identity frame: s = x (the anisotropic alpha_x), t = y, n = z.
            si.sh_frame = mi.Frame3f(mi.Vector3f(1, 0, 0), mi.Vector3f(0, 1, 0),
                                     mi.Vector3f(0, 0, 1))
            si.wi = mi.Vector3f(wo)
            value = bsdf.eval(ctx, si, mi.Vector3f(wi))
            pdf = bsdf.pdf(ctx, si, mi.Vector3f(wi))
            c = abs(wi[2])
            f = [value[i] / c for i in range(3)]
            fmt = lambda v: "[" + ", ".join(f"{x:.7e}" for x in v) + "]"
            print(f"    ({k}, {fmt(wo)}, {fmt(wi)}, {fmt(f)}, {float(pdf):.7e}),")


if __name__ == "__main__":
    main()
