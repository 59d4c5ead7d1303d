//! A 2-D target density given by an image: f(x) is the bilinearly interpolated luminance of the
//! pixels over the unit square, as in the 2-D experiments of Müller et al. 2019 (section 2.3,
//! Figure 3), which fit flows to densities "given by images".
//!
//! Coordinates: x runs left to right, y bottom to top, so a plot of the density with y up shows
//! the image upright. Pixel (i, j) (column i, row j counted from the top) has its centre at
//! ((i + ½)/w, 1 − (j + ½)/h); between centres f is bilinear, beyond the outermost centres it
//! is constant (clamped to the edge). A non-square image is stretched to the unit square.

use std::path::Path;

use crate::error::{Error, Result};
use crate::image::builtin::Builtin;

/// Most pixels an image target may have (2048², far more than a 2-D density needs).
pub const MAX_PIXELS: u64 = 1 << 22;

/// The decoders' own limits, a second line behind [`MAX_PIXELS`]: no side beyond 16384 pixels
/// and no decoder buffer beyond 64 MiB (a 2048² RGBA image at 16 bits is 32 MiB).
fn decoder_limits() -> ::image::Limits {
    let mut limits = ::image::Limits::default();
    limits.max_image_width = Some(1 << 14);
    limits.max_image_height = Some(1 << 14);
    limits.max_alloc = Some(64 << 20);
    limits
}

/// A non-negative raster on the unit square, read through bilinear interpolation.
///
/// ```
/// use nis_paper::image::Target;
/// let t = Target::from_luminance("ramp", 2, 1, vec![0.0, 1.0]).unwrap();
/// assert!((t.value(0.5, 0.5) - 0.5).abs() < 1e-12);
/// assert_eq!(t.value(0.0, 0.5), 0.0); // clamped to the left pixel
/// ```
#[derive(Clone, Debug)]
pub struct Target {
    name: String,
    width: usize,
    height: usize,
    /// Row-major luminance, row 0 at the top of the image.
    luminance: Vec<f64>,
}

impl Target {
    /// A target from raw luminance values (row-major, row 0 at the top). Fails on an empty
    /// raster, a negative or non-finite value, or a raster that is zero everywhere (no density).
    pub fn from_luminance(
        name: &str,
        width: usize,
        height: usize,
        luminance: Vec<f64>,
    ) -> Result<Target> {
        let bad = |reason: String| {
            Err(Error::Target {
                name: name.to_string(),
                reason,
            })
        };
        if width == 0 || height == 0 {
            return bad(format!("the image is empty ({width}×{height} pixels)"));
        }
        if luminance.len() != width * height {
            return Err(Error::Nis(nis::Error::Dimension {
                what: "target luminance",
                expected: width * height,
                got: luminance.len(),
            }));
        }
        if let Some(v) = luminance.iter().find(|v| !v.is_finite() || **v < 0.0) {
            return bad(format!("luminance {v} is not a finite non-negative number"));
        }
        if luminance.iter().all(|&v| v == 0.0) {
            return bad("the image is black everywhere, so it defines no density".into());
        }
        Ok(Target {
            name: name.to_string(),
            width,
            height,
            luminance,
        })
    }

    /// Reads a PNG or JPEG file; colour is converted to luma Y′ = 0.2126 R′ + 0.7152 G′ +
    /// 0.0722 B′ of the stored (gamma-encoded) values, so what looks bright is dense. Alpha is
    /// ignored. A missing or unreadable path, a file that is not an image, and an empty or
    /// all-black image are errors.
    pub fn from_path(path: &Path) -> Result<Target> {
        let image_error = |reason: String| Error::Image {
            path: path.to_path_buf(),
            reason,
        };
        let bytes = std::fs::read(path).map_err(|e| image_error(format!("cannot read it: {e}")))?;
        let format = ::image::guess_format(&bytes)
            .map_err(|_| image_error("not a PNG or JPEG image".into()))?;
        let reader = || {
            let mut r = ::image::ImageReader::with_format(std::io::Cursor::new(&bytes), format);
            r.limits(decoder_limits());
            r
        };
        // The header's size is checked before any pixel is decoded: a tiny file may claim
        // 100000×100000 pixels (a decompression bomb).
        let (w, h) = reader()
            .into_dimensions()
            .map_err(|e| image_error(format!("cannot decode it: {e}")))?;
        if w as u64 * h as u64 > MAX_PIXELS {
            return Err(image_error(format!(
                "{w}×{h} pixels is more than the {MAX_PIXELS} a target may have"
            )));
        }
        let decoded = reader()
            .decode()
            .map_err(|e| image_error(format!("cannot decode it: {e}")))?;
        let rgb = decoded.to_rgb32f();
        let (width, height) = (rgb.width() as usize, rgb.height() as usize);
        let luminance = rgb
            .pixels()
            .map(|p| 0.2126 * p[0] as f64 + 0.7152 * p[1] as f64 + 0.0722 * p[2] as f64)
            .collect();
        let name = path.file_name().map_or_else(
            || path.display().to_string(),
            |n| n.to_string_lossy().into_owned(),
        );
        Target::from_luminance(&name, width, height, luminance).map_err(|e| match e {
            Error::Target { reason, .. } => image_error(reason),
            other => other,
        })
    }

    /// A built-in target rendered at `resolution`² pixels (see [`Builtin`]).
    pub fn builtin(which: Builtin, resolution: usize) -> Result<Target> {
        let luminance = which.raster(resolution);
        Target::from_luminance(which.name(), resolution, resolution, luminance)
    }

    /// The target's name (the file name, or the built-in's name).
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Width in pixels.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> usize {
        self.height
    }

    /// The unnormalised density f at (x, y) ∈ \[0,1\]² (bilinear between pixel centres).
    pub fn value(&self, x: f64, y: f64) -> f64 {
        let (w, h) = (self.width, self.height);
        let u = (x * w as f64 - 0.5).clamp(0.0, (w - 1) as f64);
        let v = ((1.0 - y) * h as f64 - 0.5).clamp(0.0, (h - 1) as f64);
        let (i0, j0) = (u.floor() as usize, v.floor() as usize);
        let (i1, j1) = ((i0 + 1).min(w - 1), (j0 + 1).min(h - 1));
        let (a, b) = (u - i0 as f64, v - j0 as f64);
        let at = |i: usize, j: usize| self.luminance[j * w + i];
        let top = (1.0 - a) * at(i0, j0) + a * at(i1, j0);
        let bottom = (1.0 - a) * at(i0, j1) + a * at(i1, j1);
        (1.0 - b) * top + b * bottom
    }

    /// f at each point of a row-major n×2 batch.
    pub fn values(&self, points: &[f32]) -> Vec<f64> {
        points
            .chunks_exact(2)
            .map(|p| self.value(p[0] as f64, p[1] as f64))
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Writes an 8-bit RGB image in the format its extension names.
    fn write_image(path: &Path, w: u32, h: u32, rgb: &[u8]) {
        let img = ::image::RgbImage::from_raw(w, h, rgb.to_vec()).unwrap();
        img.save(path).unwrap();
    }

    #[test]
    fn bilinear_value_hits_pixel_centres_and_interpolates_between() {
        // 2×2: top row (1, 2), bottom row (3, 4).
        let t = Target::from_luminance("t", 2, 2, vec![1.0, 2.0, 3.0, 4.0]).unwrap();
        assert!((t.value(0.25, 0.75) - 1.0).abs() < 1e-12);
        assert!((t.value(0.75, 0.75) - 2.0).abs() < 1e-12);
        assert!((t.value(0.25, 0.25) - 3.0).abs() < 1e-12);
        assert!((t.value(0.5, 0.5) - 2.5).abs() < 1e-12);
        assert!((t.value(1.0, 0.0) - 4.0).abs() < 1e-12);
    }

    #[test]
    fn png_is_read_as_luma_upright() {
        let dir = std::env::temp_dir().join(format!("nis-target-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("two.png");
        // Top pixel white, bottom pixel black.
        write_image(&path, 1, 2, &[255, 255, 255, 0, 0, 0]);
        let t = Target::from_path(&path).unwrap();
        assert_eq!((t.width(), t.height()), (1, 2));
        assert!((t.value(0.5, 1.0) - 1.0).abs() < 1e-6);
        assert_eq!(t.value(0.5, 0.0), 0.0);
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn jpeg_colour_is_converted_to_luma() {
        let dir = std::env::temp_dir().join(format!("nis-target-jpg-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("green.jpg");
        write_image(&path, 8, 8, &[0, 255, 0].repeat(64));
        let t = Target::from_path(&path).unwrap();
        // Pure green has luma 0.7152 (JPEG rounding aside).
        assert!(
            (t.value(0.5, 0.5) - 0.7152).abs() < 0.03,
            "{}",
            t.value(0.5, 0.5)
        );
        std::fs::remove_dir_all(&dir).ok();
    }

    #[test]
    fn bad_files_are_clear_errors() {
        let dir = std::env::temp_dir().join(format!("nis-target-bad-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let text = dir.join("notes.png");
        std::fs::write(&text, "not an image").unwrap();
        let black = dir.join("black.png");
        write_image(&black, 2, 2, &[0; 12]);
        let missing = dir.join("missing.png");

        let msg = Target::from_path(&text).unwrap_err().to_string();
        assert!(msg.contains("not a PNG or JPEG"), "{msg}");
        let msg = Target::from_path(&black).unwrap_err().to_string();
        assert!(msg.contains("black everywhere"), "{msg}");
        let msg = Target::from_path(&missing).unwrap_err().to_string();
        assert!(msg.contains("cannot read it"), "{msg}");
        assert!(Target::from_luminance("empty", 0, 0, vec![]).is_err());
        std::fs::remove_dir_all(&dir).ok();
    }
}
