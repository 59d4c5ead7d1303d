#!/usr/bin/env python3
"""Write a large test mesh (a bumpy sphere, 490,000 triangles, no normals in the file) and a
scene that places it in the built-in Cornell box, for BVH and OBJ-loading checks.

Usage: python3 scripts/scenes/bumpy-sphere.py [OUT_DIR]   (default: out/)
Then:  nis render out/bumpy.xml --spp 16 --res 256 --out out/bumpy.exr
The same out/bumpy.xml loads in Mitsuba 3 (mi.load_file), which is how the numbers in
docs/results/guiding.md were compared.
"""

import math
import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
out = Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT / "out"
out.mkdir(parents=True, exist_ok=True)
nu, nv = 700, 350
# Written to temporary files and renamed into place (atomically, like every writer of nis).
tmp_obj = out / f".bumpy.obj.{os.getpid()}.tmp"
with open(tmp_obj, "w") as f:
    for j in range(nv + 1):
        th = math.pi * j / nv
        for i in range(nu):
            ph = 2 * math.pi * i / nu
            r = 1 + 0.05 * math.sin(7 * th) * math.sin(9 * ph)
            f.write(f"v {r * math.sin(th) * math.cos(ph):.6f} {r * math.cos(th):.6f} "
                    f"{r * math.sin(th) * math.sin(ph):.6f}\n")
    for j in range(nv):
        for i in range(nu):
            a = j * nu + i + 1
            b = j * nu + (i + 1) % nu + 1
            c = (j + 1) * nu + i + 1
            d = (j + 1) * nu + (i + 1) % nu + 1
            f.write(f"f {a} {c} {b}\nf {b} {c} {d}\n")
scene = (ROOT / "crates" / "nis-render" / "scenes" / "cornell-box.xml").read_text()
scene = scene.replace("</scene>", """    <shape type="obj">
        <string name="filename" value="bumpy.obj"/>
        <transform name="to_world"><scale value="0.35"/><translate x="0.1" y="1.2" z="0.2"/></transform>
        <ref id="white"/>
    </shape>
</scene>""")
os.replace(tmp_obj, out / "bumpy.obj")
tmp_xml = out / f".bumpy.xml.{os.getpid()}.tmp"
tmp_xml.write_text(scene)
os.replace(tmp_xml, out / "bumpy.xml")
print(f"wrote {out / 'bumpy.obj'} ({2 * nu * nv} triangles) and {out / 'bumpy.xml'}")
