#!/usr/bin/env python3
"""Write crates/nis-render/src/bsdf/conductors.rs: the RGB complex indices of refraction (eta, k)
of Mitsuba 3's named conductors (`<string name="material" value="Au"/>`), as its scalar_rgb
variant derives them from its measured spectral data.

    target/mitsuba-venv/bin/python scripts/scenes/conductor-table.py
"""
import sys
from pathlib import Path

import mitsuba as mi

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "lib"))
from rust_literals import f32_literal  # noqa: E402

mi.set_variant("scalar_rgb")
OUT = Path(__file__).resolve().parents[2] / "crates/nis-render/src/bsdf/conductors.rs"
NAMES = ("a-C Ag Al AlAs AlSb Au Be Cr CsI Cu Cu2O CuO d-C Hg HgTe Ir K Li MgO Mo Na_palik Nb "
         "Ni_palik Rh Se SiC SnTe Ta Te ThF4 TiC TiN TiO2 VC V_palik VN W").split()


rows = []
for name in NAMES:
    params = mi.traverse(mi.load_dict({"type": "conductor", "material": name}))
    eta = ", ".join(f32_literal(float(c)) for c in params["eta.value"])
    k = ", ".join(f32_literal(float(c)) for c in params["k.value"])
    rows.append(f'    ("{name}", [{eta}], [{k}]),')
OUT.write_text(f'''//! Mitsuba 3's named conductors (`material` of `conductor` and `roughconductor`): the
//! complex index of refraction `eta + i k` in linear sRGB, as Mitsuba 3.9's RGB variants derive
//! it from its measured spectra (Palik and others; `scripts/scenes/conductor-table.py`
//! regenerates this file).

/// `(name, eta, k)` of every named conductor.
#[rustfmt::skip]
pub const CONDUCTORS: [(&str, [f32; 3], [f32; 3]); {len(rows)}] = [
{chr(10).join(rows)}
];

/// The `(eta, k)` of a named conductor.
pub fn lookup(name: &str) -> Option<([f32; 3], [f32; 3])> {{
    CONDUCTORS
        .iter()
        .find(|(n, _, _)| *n == name)
        .map(|(_, e, k)| (*e, *k))
}}
''')
print(f"wrote {OUT}")
