//! Images: a linear RGB pixel buffer, written as full-float OpenEXR or as a tonemapped PNG,
//! and read back from EXR.
//!
//! Files are written atomically (`nis::io::AtomicFile`): to a temporary file in the destination's
//! directory, which is then renamed over the destination, so a crash never leaves a half-written
//! image behind.
//! The PNG tonemap is a clamp to `[0, 1]` followed by the sRGB transfer curve (IEC 61966-2-1).

use std::path::Path;

use exr::prelude::{SpecificChannels, Vec2, WritableImage};
use image::codecs::png::PngEncoder;
use image::ImageEncoder;
use nis::io::AtomicFile;

use crate::geometry::Rgb;
use crate::Error;

/// A linear RGB image, rows from the top.
#[derive(Clone, Debug, PartialEq)]
pub struct Image {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// `width × height` pixels, row-major.
    pub pixels: Vec<Rgb>,
}

impl Image {
    /// A black image.
    pub fn new(width: u32, height: u32) -> Self {
        Image {
            width,
            height,
            pixels: vec![Rgb::ZERO; width as usize * height as usize],
        }
    }

    /// Pixel at column `x`, row `y`.
    pub fn get(&self, x: u32, y: u32) -> Rgb {
        self.pixels[y as usize * self.width as usize + x as usize]
    }

    /// Mean over pixels and channels.
    pub fn mean(&self) -> f64 {
        let s: f64 = self
            .pixels
            .iter()
            .map(|p| f64::from(p.x) + f64::from(p.y) + f64::from(p.z))
            .sum();
        s / (3.0 * self.pixels.len().max(1) as f64)
    }

    /// Write as OpenEXR with 32-bit float RGB channels.
    pub fn write_exr(&self, path: &Path) -> Result<(), Error> {
        let w = self.width as usize;
        let channels = SpecificChannels::rgb(|pos: Vec2<usize>| {
            let p = self.pixels[pos.y() * w + pos.x()];
            (p.x, p.y, p.z)
        });
        let image = exr::prelude::Image::from_channels((w, self.height as usize), channels);
        write_atomically(path, |file| {
            image.write().to_buffered(file).map_err(|e| e.to_string())
        })
    }

    /// Write as an 8-bit sRGB PNG (clamped, no exposure change).
    pub fn write_png(&self, path: &Path) -> Result<(), Error> {
        let bytes: Vec<u8> = self
            .pixels
            .iter()
            .flat_map(|p| p.to_array())
            .map(|c| (srgb_encode(c) * 255.0 + 0.5) as u8)
            .collect();
        write_atomically(path, |file| {
            PngEncoder::new(file)
                .write_image(
                    &bytes,
                    self.width,
                    self.height,
                    image::ExtendedColorType::Rgb8,
                )
                .map_err(|e| e.to_string())
        })
    }

    /// Write as EXR or PNG according to the file extension.
    pub fn write(&self, path: &Path) -> Result<(), Error> {
        match path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase)
        {
            Some(e) if e == "exr" => self.write_exr(path),
            Some(e) if e == "png" => self.write_png(path),
            _ => Err(Error::Image {
                path: path.display().to_string(),
                message: "unknown image format (use .exr or .png)".into(),
            }),
        }
    }

    /// Read the first RGB(A) layer of an OpenEXR file.
    pub fn read_exr(path: &Path) -> Result<Image, Error> {
        let img = exr::prelude::read_first_rgba_layer_from_file(
            path,
            |res, _| Image::new(res.width() as u32, res.height() as u32),
            |img: &mut Image, pos, (r, g, b, _a): (f32, f32, f32, f32)| {
                let w = img.width as usize;
                img.pixels[pos.y() * w + pos.x()] = Rgb::new(r, g, b);
            },
        )
        .map_err(|e| Error::Image {
            path: path.display().to_string(),
            message: e.to_string(),
        })?;
        Ok(img.layer_data.channel_data.pixels)
    }
}

/// The sRGB transfer curve applied to a linear value clamped to `[0, 1]`.
pub fn srgb_encode(c: f32) -> f32 {
    let c = if c.is_finite() {
        c.clamp(0.0, 1.0)
    } else {
        0.0
    };
    if c <= 0.003_130_8 {
        12.92 * c
    } else {
        1.055 * c.powf(1.0 / 2.4) - 0.055
    }
}

/// Run `write` on a [`AtomicFile`] for `path` and commit it (see `nis::io::atomic`).
fn write_atomically(
    path: &Path,
    write: impl FnOnce(&mut AtomicFile) -> Result<(), String>,
) -> Result<(), Error> {
    let err = |message: String| Error::Image {
        path: path.display().to_string(),
        message,
    };
    let mut file = AtomicFile::create(path).map_err(|e| err(e.to_string()))?;
    write(&mut file).map_err(err)?;
    file.commit().map_err(|e| err(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn exr_round_trips_full_float() {
        let dir = std::env::temp_dir().join(format!("nis-render-film-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mut img = Image::new(3, 2);
        img.pixels[4] = Rgb::new(1e-7, 123.456, 0.333_333_34);
        let path = dir.join("a.exr");
        img.write_exr(&path).unwrap();
        assert_eq!(Image::read_exr(&path).unwrap(), img);
        img.write(&dir.join("a.png")).unwrap();
        assert!(img.write(&dir.join("a.bmp")).is_err());
        let leftovers = std::fs::read_dir(&dir)
            .unwrap()
            .filter(|e| {
                e.as_ref()
                    .unwrap()
                    .file_name()
                    .to_string_lossy()
                    .ends_with(".tmp")
            })
            .count();
        assert_eq!(leftovers, 0);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
