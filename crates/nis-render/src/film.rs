//! Images: a linear RGB pixel buffer, written as full-float OpenEXR or as a tonemapped PNG,
//! and read back from EXR.
//!
//! Files are written atomically (`nis::io::AtomicFile`): to a temporary file in the destination's
//! directory, which is then renamed over the destination, so a crash never leaves a half-written
//! image behind.
//! The PNG tonemap is a clamp to `[0, 1]` followed by the sRGB transfer curve (IEC 61966-2-1).

use std::path::Path;

use exr::prelude::{Encoding, LineOrder, SpecificChannels, Vec2, WritableImage};
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

    /// Write as OpenEXR with 32-bit float RGB channels. The tiles are compressed in parallel
    /// and written in increasing order, so the same image gives the same bytes (with the
    /// crate's default, unspecified order, the file held the tiles in the order their
    /// compression finished).
    pub fn write_exr(&self, path: &Path) -> Result<(), Error> {
        let w = self.width as usize;
        let channels = SpecificChannels::rgb(|pos: Vec2<usize>| {
            let p = self.pixels[pos.y() * w + pos.x()];
            (p.x, p.y, p.z)
        });
        let encoding = Encoding {
            line_order: LineOrder::Increasing,
            ..Encoding::FAST_LOSSLESS
        };
        let size = (w, self.height as usize);
        let image = exr::prelude::Image::from_encoded_channels(size, encoding, channels);
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

    /// Read the first RGB(A) layer of an OpenEXR file. The size its header claims is checked
    /// against the file's length before the pixels are allocated (see [`MAX_EXR_PIXELS_PER_BYTE`]).
    pub fn read_exr(path: &Path) -> Result<Image, Error> {
        let error = |message: String| Error::Image {
            path: path.display().to_string(),
            message,
        };
        let file_len = std::fs::metadata(path)
            .map_err(|e| error(e.to_string()))?
            .len();
        let meta =
            exr::meta::MetaData::read_from_file(path, false).map_err(|e| error(e.to_string()))?;
        let size = meta
            .headers
            .first()
            .ok_or_else(|| error("the file has no layer".into()))?
            .layer_size;
        // The decoder reserves a block's claimed size before reading it; a header whose tiles
        // or scan-line blocks dwarf the file (found by fuzzing: 1.7 GB for a 1 kB file) lies.
        let max_block = MAX_EXR_BLOCK_BYTES.max(16 * file_len);
        if let Some(h) = meta
            .headers
            .iter()
            .find(|h| h.max_block_byte_size() as u64 > max_block)
        {
            return Err(error(format!(
                "the header claims blocks of {} bytes, more than a file of {file_len} bytes can hold",
                h.max_block_byte_size()
            )));
        }
        let pixels = size.width() as u64 * size.height() as u64;
        if pixels > MAX_EXR_PIXELS_PER_BYTE * file_len + (1 << 16) {
            return Err(error(format!(
                "the header claims {}×{} pixels, more than a file of {file_len} bytes can hold",
                size.width(),
                size.height()
            )));
        }
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

/// Most pixels per byte of file an EXR may decode to. No OpenEXR compression packs a pixel
/// (at least 6 bytes: three half floats) into fewer than 1/172 bytes (deflate's limit is
/// 1032:1), so a header claiming more lies, and is refused before anything is allocated.
pub const MAX_EXR_PIXELS_PER_BYTE: u64 = 256;

/// Largest uncompressed EXR block (a tile or a group of scan lines) accepted from any file
/// (16 MiB: a 16-line block of a 65536-wide RGBA f32 image, a 1024² RGBA f32 tile); beyond it, a
/// block may be as large as 16 times the file.
pub const MAX_EXR_BLOCK_BYTES: u64 = 1 << 24;

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
    fn an_exr_header_claiming_more_pixels_than_its_file_holds_is_refused() {
        // Found by the fuzz tests: the pixels were allocated from the header's data window.
        let dir = std::env::temp_dir().join(format!("nis-render-film-bomb-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("bomb.exr");
        Image::new(4, 4).write_exr(&path).unwrap();
        let mut bytes = std::fs::read(&path).unwrap();
        let key = b"dataWindow\0box2i\0";
        let at = bytes.windows(key.len()).position(|w| w == key).unwrap() + key.len() + 4;
        bytes[at + 8..at + 16].copy_from_slice(&[0xff, 0xff, 0x00, 0x00, 0xff, 0xff, 0x00, 0x00]);
        std::fs::write(&path, &bytes).unwrap();
        let e = Image::read_exr(&path).unwrap_err().to_string();
        assert!(e.contains("more than a file of"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn an_exr_header_claiming_huge_tiles_is_refused() {
        // Found by the fuzz tests: a tile size claiming 2^20 × 2^20 pixels made the decoder
        // reserve a block of the size a chunk claimed (1.7 GB) before reading it.
        use exr::prelude::*;
        let dir =
            std::env::temp_dir().join(format!("nis-render-film-tiles-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("tiles.exr");
        let encoding = Encoding {
            compression: Compression::Uncompressed,
            blocks: Blocks::Tiles(Vec2(2, 2)),
            line_order: LineOrder::Increasing,
        };
        let channels = SpecificChannels::rgba(|_: Vec2<usize>| (0.5f32, 0.5f32, 0.5f32, 1.0f32));
        let layer = Layer::new((4, 4), LayerAttributes::named("l"), encoding, channels);
        exr::image::Image::from_layer(layer)
            .write()
            .to_file(&path)
            .unwrap();
        assert_eq!(super::Image::read_exr(&path).unwrap().pixels.len(), 16);
        let mut bytes = std::fs::read(&path).unwrap();
        let key = b"tiles\0tiledesc\0";
        let at = bytes.windows(key.len()).position(|w| w == key).unwrap() + key.len() + 4;
        bytes[at..at + 8].copy_from_slice(&[0, 0, 16, 0, 0, 0, 16, 0]);
        std::fs::write(&path, &bytes).unwrap();
        let e = super::Image::read_exr(&path).unwrap_err().to_string();
        assert!(e.contains("claims blocks of"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn exr_files_hold_their_tiles_in_order() {
        // 200 × 150 pixels are 4 × 3 tiles, compressed on several threads: in increasing order
        // the bytes do not depend on which finished first.
        let dir =
            std::env::temp_dir().join(format!("nis-render-film-order-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mut img = Image::new(200, 150);
        for (i, p) in img.pixels.iter_mut().enumerate() {
            *p = Rgb::splat((i % 97) as f32 / 7.0);
        }
        let (a, b) = (dir.join("a.exr"), dir.join("b.exr"));
        img.write_exr(&a).unwrap();
        img.write_exr(&b).unwrap();
        let meta = exr::meta::MetaData::read_from_file(&a, false).unwrap();
        assert_eq!(meta.headers[0].line_order, LineOrder::Increasing);
        assert_eq!(std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap());
        assert_eq!(Image::read_exr(&a).unwrap(), img);
        std::fs::remove_dir_all(&dir).unwrap();
    }

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
