#!/usr/bin/env python3
"""Write crates/nis-render/src/spectrum/cie.rs: the CIE 1931 matching functions and D65 every
5 nm from 360 to 830 nm, read from Mitsuba 3 (so that our spectrum-to-RGB conversion is its).

    python3 -m venv target/mitsuba-venv && target/mitsuba-venv/bin/pip install mitsuba==3.9.1
    target/mitsuba-venv/bin/python scripts/scenes/cie-tables.py
"""
import sys
from pathlib import Path

import mitsuba as mi

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "lib"))
from rust_literals import f32_literal  # noqa: E402

mi.set_variant("scalar_rgb")
OUT = Path(__file__).resolve().parents[2] / "crates/nis-render/src/spectrum/cie.rs"
HEADER = '''//! CIE 1931 2° colour-matching functions x̄, ȳ, z̄ and the D65 illuminant, tabulated every 5 nm
//! from 360 to 830 nm (CIE 015:2018). The values are those of Mitsuba 3's tables (its D65 is
//! scaled so that its columns match; `scripts/scenes/cie-tables.py` regenerates this file), so
//! spectra convert to the same RGB as in Mitsuba's RGB variants.

/// First tabulated wavelength, nm.
pub const MIN: f64 = 360.0;
/// Last tabulated wavelength, nm.
pub const MAX: f64 = 830.0;
/// Ȳ normalisation: one over the integral of ȳ·D65 as Mitsuba defines it.
pub const Y_NORMALIZATION: f64 = 1.0 / 106.750_259_399_414_06;

/// `[x̄, ȳ, z̄, D65]` at 360, 365, …, 830 nm.
#[rustfmt::skip]
pub const TABLE: [[f32; 4]; 95] = [
'''


rows = []
for k in range(95):
    w = 360.0 + 5 * k
    x = mi.cie1931_xyz(w)
    rows.append("    [" + ", ".join(f32_literal(v) for v in (x[0], x[1], x[2], mi.cie_d65(w))) + "],")
OUT.write_text(HEADER + "\n".join(rows) + "\n];\n")
print(f"wrote {OUT}")
