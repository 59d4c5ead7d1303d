//! Pictures of a trained density model: a grid of samples and the latent-space manifold of the
//! paper's Figure 4 (four images in the corners, bilinear interpolation of their latents between).

use std::io::Cursor;

use ::image::codecs::png::{CompressionType, FilterType, PngEncoder};
use ::image::GrayImage;
use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;

use super::cell_centres;
use crate::data::Images;
use crate::error::{Error, Result};
use nis::flow::Bijection;

/// Pixels per image pixel that make a `width`-wide image about 64 pixels wide (at least 2).
pub fn default_scale(width: usize) -> usize {
    (64 / width).max(2)
}

/// The PNG of the manifold of `model` spanned by validation images `first..first + 4` of
/// `images` (at the centres of their cells), on a `side × side` grid, each pixel `scale`-fold.
pub fn manifold_png(
    model: &dyn Bijection,
    images: &Images,
    first: usize,
    side: usize,
    scale: usize,
) -> Result<Vec<u8>> {
    if first + 4 > images.len() {
        return Err(Error::Config(format!(
            "the manifold needs images {first}..{} but there are only {}",
            first + 4,
            images.len()
        )));
    }
    let corners = cell_centres(images, &[first, first + 1, first + 2, first + 3]);
    let grid = interpolate(model, &corners, side)?;
    grid_png(
        &grid,
        images.width,
        images.height,
        images.levels,
        side,
        scale,
    )
}

/// `n` samples x = h⁻¹(z), z ~ U\[0,1\]^D from `seed` (row-major, n × D).
pub fn samples(model: &dyn Bijection, n: usize, seed: u64) -> Result<Vec<f32>> {
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    Ok(model.sample(n, None, &mut rng)?.x)
}

/// The manifold spanned by four points `corners` (4 × D: top-left, top-right, bottom-left,
/// bottom-right): each is mapped to its latent z = h(x), the latents are interpolated
/// bilinearly on a `side × side` grid, and the grid is mapped back. Row-major, side² × D; the
/// corners come back as (numerically) themselves.
pub fn interpolate(model: &dyn Bijection, corners: &[f32], side: usize) -> Result<Vec<f32>> {
    if side < 2 || corners.len() % 4 != 0 || corners.is_empty() {
        return Err(Error::Config(format!(
            "interpolation needs 4 corner images and a grid of at least 2×2, got {} values and side {side}",
            corners.len()
        )));
    }
    let dim = corners.len() / 4;
    let (z, _) = model.forward(corners, None)?;
    let c = |k: usize, i: usize| z[k * dim + i] as f64;
    let mut grid = Vec::with_capacity(side * side * dim);
    for r in 0..side {
        let t = r as f64 / (side - 1) as f64;
        for col in 0..side {
            let s = col as f64 / (side - 1) as f64;
            for i in 0..dim {
                let v = (1.0 - t) * ((1.0 - s) * c(0, i) + s * c(1, i))
                    + t * ((1.0 - s) * c(2, i) + s * c(3, i));
                grid.push(v.clamp(0.0, 1.0) as f32);
            }
        }
    }
    Ok(model.inverse(&grid, None)?.0)
}

/// A PNG of images (`n × width·height` values in [0, 1], shown quantised to their `levels`
/// levels) laid out `cols` to a row, each pixel `scale`×`scale`, with a one-pixel grey border.
pub fn grid_png(
    images: &[f32],
    width: usize,
    height: usize,
    levels: usize,
    cols: usize,
    scale: usize,
) -> Result<Vec<u8>> {
    let dim = width * height;
    let n = images.len() / dim.max(1);
    if n == 0 || cols == 0 || scale == 0 || levels < 2 {
        return Err(Error::Figure("nothing to draw".into()));
    }
    let rows = n.div_ceil(cols);
    let (cw, ch) = (width * scale + 1, height * scale + 1);
    let (w, h) = (cols * cw + 1, rows * ch + 1);
    let mut img = GrayImage::from_pixel(w as u32, h as u32, ::image::Luma([96]));
    for k in 0..n {
        let (x0, y0) = ((k % cols) * cw + 1, (k / cols) * ch + 1);
        for py in 0..height * scale {
            for px in 0..width * scale {
                let v = images[k * dim + (py / scale) * width + px / scale];
                let level = ((v.clamp(0.0, 1.0) * levels as f32) as usize).min(levels - 1);
                let grey = (255 * level / (levels - 1)) as u8;
                img.put_pixel((x0 + px) as u32, (y0 + py) as u32, ::image::Luma([grey]));
            }
        }
    }
    let mut bytes = Vec::new();
    let encoder = PngEncoder::new_with_quality(
        Cursor::new(&mut bytes),
        CompressionType::Best,
        FilterType::Adaptive,
    );
    img.write_with_encoder(encoder)
        .map_err(|e| Error::Figure(e.to_string()))?;
    Ok(bytes)
}
