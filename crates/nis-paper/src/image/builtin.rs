//! Built-in 2-D targets, generated in code so that `nis fit-image` and its benchmark need no data
//! file. They stand in for the images of Müller et al. 2019, Figure 3, and mix the two kinds of
//! structure that separate the coupling transforms: sharp edges (rings, a checkerboard, text)
//! and smooth modes (a landscape of bumps).

use crate::error::Error;

/// Supersampling per pixel axis when a built-in is rasterised (anti-aliases its sharp edges).
const SUPERSAMPLING: usize = 4;

/// A built-in target density on \[0,1\]² (y up).
///
/// ```
/// use nis_paper::image::Builtin;
/// let b: Builtin = "rings".parse().unwrap();
/// assert_eq!(b.name(), "rings");
/// assert_eq!(b.raster(16).len(), 256);
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Builtin {
    /// Three concentric rings of decreasing brightness: thin, sharp, curved structure.
    Rings,
    /// A 6×6 checkerboard of ones and zeros: axis-aligned discontinuities.
    Checkerboard,
    /// "NIS" over "2019" in a 5×7 pixel font: text-like, many small sharp features.
    Glyphs,
    /// A smooth multi-modal landscape: Gaussian bumps of different widths on a gentle wave.
    Landscape,
}

impl Builtin {
    /// Every built-in, in the order the benchmark shows them.
    pub const ALL: [Builtin; 4] = [
        Builtin::Rings,
        Builtin::Checkerboard,
        Builtin::Glyphs,
        Builtin::Landscape,
    ];

    /// The name used on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Builtin::Rings => "rings",
            Builtin::Checkerboard => "checkerboard",
            Builtin::Glyphs => "glyphs",
            Builtin::Landscape => "landscape",
        }
    }

    /// The density at (x, y) ∈ \[0,1\]², y up (not normalised).
    pub fn density(self, x: f64, y: f64) -> f64 {
        match self {
            Builtin::Rings => rings(x, y),
            Builtin::Checkerboard => checkerboard(x, y),
            Builtin::Glyphs => glyphs(x, y),
            Builtin::Landscape => landscape(x, y),
        }
    }

    /// The density averaged over each pixel of a `resolution`² raster (row-major, row 0 at the
    /// top), by `SUPERSAMPLING`² midpoint samples per pixel.
    pub fn raster(self, resolution: usize) -> Vec<f64> {
        let n = resolution as f64;
        let s = SUPERSAMPLING as f64;
        let mut out = Vec::with_capacity(resolution * resolution);
        for j in 0..resolution {
            for i in 0..resolution {
                let mut sum = 0.0;
                for b in 0..SUPERSAMPLING {
                    for a in 0..SUPERSAMPLING {
                        let x = (i as f64 + (a as f64 + 0.5) / s) / n;
                        let y = 1.0 - (j as f64 + (b as f64 + 0.5) / s) / n;
                        sum += self.density(x, y);
                    }
                }
                out.push(sum / (s * s));
            }
        }
        out
    }
}

impl std::str::FromStr for Builtin {
    type Err = Error;
    fn from_str(s: &str) -> Result<Builtin, Error> {
        Builtin::ALL
            .into_iter()
            .find(|b| b.name() == s)
            .ok_or_else(|| {
                let names: Vec<_> = Builtin::ALL.iter().map(|b| b.name()).collect();
                Error::Config(format!(
                    "unknown target {s:?}; the built-in targets are {}",
                    names.join(", ")
                ))
            })
    }
}

fn rings(x: f64, y: f64) -> f64 {
    let r = ((x - 0.5).powi(2) + (y - 0.5).powi(2)).sqrt();
    [(0.12, 1.0), (0.25, 0.7), (0.38, 0.45)]
        .iter()
        .filter(|(radius, _)| (r - radius).abs() < 0.025)
        .map(|(_, brightness)| brightness)
        .sum()
}

fn checkerboard(x: f64, y: f64) -> f64 {
    let (i, j) = ((x * 6.0).floor() as i64, (y * 6.0).floor() as i64);
    if (i + j).rem_euclid(2) == 0 {
        1.0
    } else {
        0.0
    }
}

/// 5×7 bitmaps, top row first, bit 4 = leftmost column.
fn glyph(c: char) -> [u8; 7] {
    match c {
        'N' => [0x11, 0x19, 0x19, 0x15, 0x13, 0x13, 0x11],
        'I' => [0x1f, 0x04, 0x04, 0x04, 0x04, 0x04, 0x1f],
        'S' => [0x0f, 0x10, 0x10, 0x0e, 0x01, 0x01, 0x1e],
        '2' => [0x0e, 0x11, 0x01, 0x02, 0x04, 0x08, 0x1f],
        '0' => [0x0e, 0x11, 0x13, 0x15, 0x19, 0x11, 0x0e],
        '1' => [0x04, 0x0c, 0x04, 0x04, 0x04, 0x04, 0x0e],
        '9' => [0x0e, 0x11, 0x11, 0x0f, 0x01, 0x02, 0x0c],
        _ => [0; 7],
    }
}

fn glyphs(x: f64, y: f64) -> f64 {
    // Font pixels are squares of side 1/30; each glyph takes 6 columns (one of spacing).
    const PIXEL: f64 = 1.0 / 30.0;
    let lines: [(&str, f64); 2] = [("NIS", 0.82), ("2019", 0.42)];
    for (text, top) in lines {
        let width = (text.len() * 6 - 1) as f64 * PIXEL;
        let left = 0.5 - width / 2.0;
        let (col, row) = ((x - left) / PIXEL, (top - y) / PIXEL);
        if col < 0.0 || !(0.0..7.0).contains(&row) {
            continue;
        }
        let (col, row) = (col as usize, row as usize);
        if let Some(c) = text.chars().nth(col / 6) {
            let bit = col % 6;
            if bit < 5 && glyph(c)[row] & (0x10 >> bit) != 0 {
                return 1.0;
            }
        }
    }
    0.0
}

fn landscape(x: f64, y: f64) -> f64 {
    let bump = |cx: f64, cy: f64, s: f64, w: f64| {
        w * (-((x - cx).powi(2) + (y - cy).powi(2)) / (2.0 * s * s)).exp()
    };
    let wave = 0.08
        * (1.0 + (3.0 * std::f64::consts::PI * x).sin() * (2.0 * std::f64::consts::PI * y).cos());
    bump(0.25, 0.72, 0.08, 1.0)
        + bump(0.72, 0.78, 0.12, 0.6)
        + bump(0.58, 0.3, 0.05, 1.3)
        + bump(0.2, 0.22, 0.1, 0.5)
        + wave
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_builtin_has_mass_and_parses_by_name() {
        for b in Builtin::ALL {
            let r = b.raster(32);
            assert!(r.iter().all(|v| v.is_finite() && *v >= 0.0));
            assert!(r.iter().sum::<f64>() > 0.0, "{}", b.name());
            assert_eq!(b.name().parse::<Builtin>().unwrap(), b);
        }
        assert!("nope".parse::<Builtin>().is_err());
    }

    #[test]
    fn glyphs_spell_the_top_left_of_n() {
        // N's top-left pixel is lit, the pixel right of it is not.
        let left = 0.5 - 17.0 / 60.0;
        assert_eq!(glyphs(left + 0.5 / 30.0, 0.82 - 0.5 / 30.0), 1.0);
        assert_eq!(glyphs(left + 1.5 / 30.0, 0.82 - 0.5 / 30.0), 0.0);
    }
}
