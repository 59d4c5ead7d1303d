//! Textures: spatially varying BSDF parameters looked up by a surface's texture coordinates
//! (Mitsuba 3's `bitmap`, `checkerboard`, `rawconstant` and `mesh_attribute` plugins, their
//! conventions and defaults).
//!
//! A bitmap is read from PNG, JPEG, TGA, BMP (8-bit sRGB, decoded to linear unless `raw`),
//! OpenEXR or Radiance HDR (linear); it is looked up at `to_uv · uv` with texel centres at
//! `(i + ½)/width`, row 0 at `v = 0` (an OBJ's `v` is flipped on loading, as Mitsuba does), with
//! bilinear (default) or nearest filtering and `repeat` (default), `mirror` or `clamp` wrapping.
//! 8-bit images stay 8-bit in memory (a 4k texture takes 48 MiB, not 192) and are decoded
//! through a table.

use std::path::Path;
use std::sync::Arc;

use glam::{Mat3, Vec2, Vec3};

use crate::geometry::{luminance, Rgb};
use crate::spectrum::srgb_to_linear;
use crate::Error;

/// How texel values are interpolated.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum FilterMode {
    /// Bilinear between the four nearest texel centres.
    Bilinear,
    /// The nearest texel.
    Nearest,
}

/// What happens outside `[0, 1]²`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum WrapMode {
    /// Tile the image.
    Repeat,
    /// Tile it mirrored.
    Mirror,
    /// Repeat the edge texels.
    Clamp,
}

/// Texel storage.
#[derive(Clone, Debug, PartialEq)]
enum Texels {
    /// 8-bit values, decoded through `lut` (sRGB → linear, or /255 when raw).
    U8 {
        data: Vec<[u8; 3]>,
        lut: Box<[f32; 256]>,
    },
    /// Linear floating-point values.
    F32(Vec<[f32; 3]>),
}

/// An image texture.
#[derive(Clone, Debug, PartialEq)]
pub struct Bitmap {
    width: usize,
    height: usize,
    texels: Texels,
    filter: FilterMode,
    wrap: WrapMode,
    /// Wrapping along v (rows), when it differs from `wrap` (an environment map's poles).
    wrap_v: WrapMode,
    mean: Rgb,
}

/// A texture.
#[derive(Clone, Debug, PartialEq)]
pub enum Texture {
    /// An image.
    Bitmap {
        /// The image, shared by every use.
        image: Arc<Bitmap>,
        /// Affine map applied to the texture coordinates.
        to_uv: Mat3,
    },
    /// Alternating squares of two colours, each half of `[0, 1]²` along both axes.
    Checkerboard {
        /// The colour where `⌊2u⌋ + ⌊2v⌋` is even.
        color0: Rgb,
        /// The other colour.
        color1: Rgb,
        /// Affine map applied to the texture coordinates.
        to_uv: Mat3,
    },
    /// A value used as given, with no colour conversion or range check (Mitsuba 3's
    /// `rawconstant`): a number (the same in every channel) or a 3-vector.
    RawConstant {
        /// The value; a number is stored in all three channels.
        value: Rgb,
        /// Whether it was given as a 3-vector, which has no scalar reading (Mitsuba's `eval_1`
        /// throws; the reader refuses it where a number is needed).
        vector: bool,
    },
    /// The named attribute of the mesh a path hits, interpolated over the triangle (a
    /// `vertex_…` one) or constant on it (`face_…`), times `scale` (Mitsuba 3's
    /// `mesh_attribute`); zero where no mesh attributes are given.
    MeshAttribute {
        /// The attribute's name, as Mitsuba names a PLY file's properties.
        name: String,
        /// Factor on the value.
        scale: f32,
    },
}

/// The mesh attributes where a path hits a triangle, as a `mesh_attribute` texture reads them.
#[derive(Clone, Copy, Debug)]
pub struct AttributeHit<'a> {
    /// The names of the attributes the scene's textures read.
    pub names: &'a [String],
    /// Their values at the triangle's three corners, in `names`' order: the colour and the
    /// number ([`crate::shape::MeshAttribute::texel`]).
    pub corners: &'a [[[f32; 4]; 3]],
    /// The hit's barycentric coordinates (the weights of the three corners).
    pub bary: Vec3,
}

impl AttributeHit<'_> {
    /// The interpolated colour and number of attribute `name` (zero if the scene has none).
    fn value(&self, name: &str) -> [f32; 4] {
        let Some(c) = self
            .names
            .iter()
            .position(|n| n == name)
            .and_then(|k| self.corners.get(k))
        else {
            return [0.0; 4];
        };
        let b = self.bary;
        std::array::from_fn(|i| c[0][i] * b.x + (c[1][i] * b.y + c[2][i] * b.z))
    }
}

impl Texture {
    /// The value at texture coordinates `uv`.
    pub fn eval(&self, uv: Vec2) -> Rgb {
        self.eval_at(uv, None)
    }

    /// The value at texture coordinates `uv` of a hit with mesh attributes `attributes`.
    pub fn eval_at(&self, uv: Vec2, attributes: Option<&AttributeHit>) -> Rgb {
        match self {
            Texture::Bitmap { image, to_uv } => image.eval(to_uv.transform_point2(uv)),
            Texture::Checkerboard {
                color0,
                color1,
                to_uv,
            } => {
                let p = to_uv.transform_point2(uv);
                let (x, y) = (p.x - p.x.floor(), p.y - p.y.floor());
                if (x > 0.5) == (y > 0.5) {
                    *color0
                } else {
                    *color1
                }
            }
            Texture::RawConstant { value, .. } => *value,
            Texture::MeshAttribute { name, scale } => {
                let v = attributes.map_or([0.0; 4], |a| a.value(name));
                Rgb::new(v[0], v[1], v[2]) * *scale
            }
        }
    }

    /// The value as a scalar (the luminance of a colour), as a float parameter reads it.
    /// Mitsuba 3.9's checkerboard gives its scalar reading (`eval_1`, what a mask's opacity, a
    /// blend's weight or a principled BSDF's parameters take) the two colours swapped, and so
    /// does this one, to render as Mitsuba does.
    pub fn eval_scalar(&self, uv: Vec2) -> f32 {
        self.eval_scalar_at(uv, None)
    }

    /// [`Texture::eval_scalar`] of a hit with mesh attributes `attributes` (a 1-channel
    /// attribute as it is; a 3-channel one is zero, as Mitsuba 3 reads it).
    pub fn eval_scalar_at(&self, uv: Vec2, attributes: Option<&AttributeHit>) -> f32 {
        match self {
            Texture::Checkerboard {
                color0,
                color1,
                to_uv,
            } => {
                let swapped = Texture::Checkerboard {
                    color0: *color1,
                    color1: *color0,
                    to_uv: *to_uv,
                };
                luminance(swapped.eval(uv))
            }
            Texture::Bitmap { .. } => luminance(self.eval(uv)),
            // A number is read as it is (a vector is refused where a number is needed).
            Texture::RawConstant { value, .. } => value.x,
            Texture::MeshAttribute { name, scale } => {
                attributes.map_or(0.0, |a| a.value(name)[3]) * *scale
            }
        }
    }

    /// The gradient of [`Texture::eval_scalar`] with respect to `uv` (zero for the nearest
    /// filter and the checkerboard, which are flat almost everywhere), as a bump map reads it.
    pub fn eval_scalar_grad(&self, uv: Vec2) -> Vec2 {
        match self {
            Texture::Bitmap { image, to_uv } => {
                let g = image.luminance_grad(to_uv.transform_point2(uv));
                // Chain rule through the affine map: ∂f/∂uv = Mᵀ ∂f/∂uv'.
                Vec2::new(
                    to_uv.x_axis.x * g.x + to_uv.x_axis.y * g.y,
                    to_uv.y_axis.x * g.x + to_uv.y_axis.y * g.y,
                )
            }
            Texture::Checkerboard { .. }
            | Texture::RawConstant { .. }
            | Texture::MeshAttribute { .. } => Vec2::ZERO,
        }
    }

    /// The mean over the texture (what Mitsuba's BSDFs use to choose lobes).
    pub fn mean(&self) -> Rgb {
        match self {
            Texture::Bitmap { image, .. } => image.mean,
            Texture::Checkerboard { color0, color1, .. } => 0.5 * (*color0 + *color1),
            Texture::RawConstant { value, .. } => *value,
            // Mitsuba 3 has none; ½ stands in where nis needs one before a hit.
            Texture::MeshAttribute { .. } => Rgb::splat(0.5),
        }
    }
}

impl Bitmap {
    /// Read an image file; `raw` keeps 8-bit values as they are (no sRGB decoding).
    pub fn load(
        path: &Path,
        raw: bool,
        filter: FilterMode,
        wrap: WrapMode,
    ) -> Result<Bitmap, Error> {
        let fail = |message: String| Error::Image {
            path: path.display().to_string(),
            message,
        };
        if !path.is_file() {
            return Err(fail("texture file not found".into()));
        }
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase)
            .unwrap_or_default();
        let (width, height, texels) = if ext == "exr" {
            let img = crate::film::Image::read_exr(path)?;
            let data = img.pixels.iter().map(|p| p.to_array()).collect();
            (img.width as usize, img.height as usize, Texels::F32(data))
        } else {
            let img = image::ImageReader::open(path)
                .map_err(|e| fail(e.to_string()))?
                .with_guessed_format()
                .map_err(|e| fail(e.to_string()))?
                .decode()
                .map_err(|e| fail(e.to_string()))?;
            let (w, h) = (img.width() as usize, img.height() as usize);
            if matches!(
                img.color(),
                image::ColorType::Rgb32F | image::ColorType::Rgba32F
            ) {
                let data = img.to_rgb32f().pixels().map(|p| p.0).collect();
                (w, h, Texels::F32(data))
            } else {
                let data = img.to_rgb8().pixels().map(|p| p.0).collect();
                let lut = Box::new(std::array::from_fn(|i| {
                    let c = i as f32 / 255.0;
                    if raw {
                        c
                    } else {
                        srgb_to_linear(c)
                    }
                }));
                (w, h, Texels::U8 { data, lut })
            }
        };
        if width == 0 || height == 0 {
            return Err(fail("the image is empty".into()));
        }
        Ok(Bitmap::new(width, height, texels, filter, wrap))
    }

    /// A bitmap from linear RGB texels, rows from the top (for tests and generated textures).
    pub fn from_linear(
        width: usize,
        height: usize,
        texels: Vec<[f32; 3]>,
        filter: FilterMode,
        wrap: WrapMode,
    ) -> Result<Bitmap, Error> {
        if width == 0 || height == 0 || texels.len() != width * height {
            return Err(Error::Invalid(format!(
                "a {width}×{height} bitmap needs {} texels, got {}",
                width * height,
                texels.len()
            )));
        }
        Ok(Bitmap::new(
            width,
            height,
            Texels::F32(texels),
            filter,
            wrap,
        ))
    }

    fn new(
        width: usize,
        height: usize,
        texels: Texels,
        filter: FilterMode,
        wrap: WrapMode,
    ) -> Bitmap {
        let mut b = Bitmap {
            width,
            height,
            texels,
            filter,
            wrap,
            wrap_v: wrap,
            mean: Rgb::ZERO,
        };
        let mut sum = [0.0f64; 3];
        for i in 0..width * height {
            let t = b.texel(i);
            for k in 0..3 {
                sum[k] += f64::from(t[k]);
            }
        }
        let n = (width * height) as f64;
        b.mean = Vec3::new(
            (sum[0] / n) as f32,
            (sum[1] / n) as f32,
            (sum[2] / n) as f32,
        );
        b
    }

    /// The same image wrapped by `wrap_v` along v.
    pub fn with_wrap_v(mut self, wrap_v: WrapMode) -> Bitmap {
        self.wrap_v = wrap_v;
        self
    }

    /// The texel at column `x`, row `y` (from the top), decoded.
    pub fn texel_at(&self, x: usize, y: usize) -> Rgb {
        self.texel(y * self.width + x)
    }

    /// Width and height in texels.
    pub fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    fn texel(&self, i: usize) -> Rgb {
        match &self.texels {
            Texels::U8 { data, lut } => {
                let [r, g, b] = data[i];
                Vec3::new(lut[r as usize], lut[g as usize], lut[b as usize])
            }
            Texels::F32(data) => Vec3::from_array(data[i]),
        }
    }

    /// Index of texel `i` along an axis of `n` texels, wrapped.
    fn wrap_index(wrap: WrapMode, i: i64, n: usize) -> usize {
        let n = n as i64;
        let j = match wrap {
            WrapMode::Repeat => i.rem_euclid(n),
            WrapMode::Clamp => i.clamp(0, n - 1),
            WrapMode::Mirror => {
                let k = i.rem_euclid(2 * n);
                if k < n {
                    k
                } else {
                    2 * n - 1 - k
                }
            }
        };
        j as usize
    }

    fn at(&self, x: i64, y: i64) -> Rgb {
        let x = Self::wrap_index(self.wrap, x, self.width);
        let y = Self::wrap_index(self.wrap_v, y, self.height);
        self.texel(y * self.width + x)
    }

    /// The value at `uv` (already mapped by `to_uv`).
    pub fn eval(&self, uv: Vec2) -> Rgb {
        if !uv.is_finite() {
            return Rgb::ZERO;
        }
        // Texture coordinates far outside the unit square only repeat; keep them small so
        // that the texel index stays exact.
        let uv = uv.clamp(Vec2::splat(-1e6), Vec2::splat(1e6));
        self.eval_texels(
            uv.x * self.width as f32 - 0.5,
            uv.y * self.height as f32 - 0.5,
        )
    }

    /// The gradient of the bilinearly interpolated luminance at `uv`, per unit of `uv`.
    pub fn luminance_grad(&self, uv: Vec2) -> Vec2 {
        if self.filter == FilterMode::Nearest || !uv.is_finite() {
            return Vec2::ZERO;
        }
        let uv = uv.clamp(Vec2::splat(-1e6), Vec2::splat(1e6));
        let x = uv.x * self.width as f32 - 0.5;
        let y = uv.y * self.height as f32 - 0.5;
        let (x0, y0) = (x.floor(), y.floor());
        let (fx, fy) = (x - x0, y - y0);
        let (x0, y0) = (x0 as i64, y0 as i64);
        let f = |dx, dy| luminance(self.at(x0 + dx, y0 + dy));
        let (f00, f10, f01, f11) = (f(0, 0), f(1, 0), f(0, 1), f(1, 1));
        let dx = (1.0 - fy) * (f10 - f00) + fy * (f11 - f01);
        let dy = (1.0 - fx) * (f01 - f00) + fx * (f11 - f10);
        Vec2::new(dx * self.width as f32, dy * self.height as f32)
    }

    /// The value at texel coordinates `(x, y)`, texel `(i, j)`'s centre at `(i, j)`.
    pub fn eval_texels(&self, x: f32, y: f32) -> Rgb {
        match self.filter {
            FilterMode::Nearest => self.at((x + 0.5).floor() as i64, (y + 0.5).floor() as i64),
            FilterMode::Bilinear => {
                let (x0, y0) = (x.floor(), y.floor());
                let (fx, fy) = (x - x0, y - y0);
                let (x0, y0) = (x0 as i64, y0 as i64);
                let top = self.at(x0, y0) * (1.0 - fx) + self.at(x0 + 1, y0) * fx;
                let bottom = self.at(x0, y0 + 1) * (1.0 - fx) + self.at(x0 + 1, y0 + 1) * fx;
                top * (1.0 - fy) + bottom * fy
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn two_by_two(filter: FilterMode, wrap: WrapMode) -> Bitmap {
        let texels = vec![[0.0; 3], [1.0; 3], [2.0; 3], [3.0; 3]];
        Bitmap::from_linear(2, 2, texels, filter, wrap).unwrap()
    }

    #[test]
    fn bilinear_lookups_hit_texel_centres_and_interpolate_between() {
        let b = two_by_two(FilterMode::Bilinear, WrapMode::Clamp);
        assert_eq!(b.eval(Vec2::new(0.25, 0.25)).x, 0.0);
        assert_eq!(b.eval(Vec2::new(0.75, 0.25)).x, 1.0);
        assert_eq!(b.eval(Vec2::new(0.25, 0.75)).x, 2.0);
        assert!((b.eval(Vec2::new(0.5, 0.5)).x - 1.5).abs() < 1e-6);
        assert_eq!(b.mean, Vec3::splat(1.5));
    }

    #[test]
    fn wrap_modes_tile_mirror_and_clamp() {
        let repeat = two_by_two(FilterMode::Nearest, WrapMode::Repeat);
        let mirror = two_by_two(FilterMode::Nearest, WrapMode::Mirror);
        let clamp = two_by_two(FilterMode::Nearest, WrapMode::Clamp);
        let p = Vec2::new(1.25, 0.25); // one texel past the right edge
        assert_eq!(repeat.eval(p).x, 0.0);
        assert_eq!(mirror.eval(p).x, 1.0);
        assert_eq!(clamp.eval(p).x, 1.0);
        assert_eq!(repeat.eval(Vec2::new(-0.25, 0.25)).x, 1.0);
    }

    #[test]
    fn the_luminance_gradient_matches_finite_differences() {
        let texels = (0..20)
            .map(|i| [i as f32 * 0.1, (i * i) as f32 * 0.01, 0.5])
            .collect();
        let image = Arc::new(
            Bitmap::from_linear(5, 4, texels, FilterMode::Bilinear, WrapMode::Repeat).unwrap(),
        );
        let to_uv = Mat3::from_cols(
            Vec3::new(1.5, 0.2, 0.0),
            Vec3::new(-0.3, 0.8, 0.0),
            Vec3::new(0.1, 0.2, 1.0),
        );
        let t = Texture::Bitmap { image, to_uv };
        let uv = Vec2::new(0.37, 0.61);
        let h = 1e-3;
        let fd = Vec2::new(
            (t.eval_scalar(uv + Vec2::X * h) - t.eval_scalar(uv - Vec2::X * h)) / (2.0 * h),
            (t.eval_scalar(uv + Vec2::Y * h) - t.eval_scalar(uv - Vec2::Y * h)) / (2.0 * h),
        );
        let g = t.eval_scalar_grad(uv);
        assert!(
            (g - fd).length() < 1e-2 * fd.length().max(1.0),
            "{g} vs {fd}"
        );
    }

    #[test]
    fn checkerboard_alternates_by_quadrant() {
        let t = Texture::Checkerboard {
            color0: Rgb::ZERO,
            color1: Rgb::ONE,
            to_uv: Mat3::IDENTITY,
        };
        assert_eq!(t.eval(Vec2::new(0.25, 0.25)), Rgb::ZERO);
        assert_eq!(t.eval(Vec2::new(0.75, 0.25)), Rgb::ONE);
        assert_eq!(t.eval(Vec2::new(0.75, 0.75)), Rgb::ZERO);
        assert_eq!(t.mean(), Rgb::splat(0.5));
        // Read as a scalar, the colours swap places (Mitsuba 3.9's eval_1).
        assert_eq!(t.eval_scalar(Vec2::new(0.25, 0.25)), 1.0);
        assert_eq!(t.eval_scalar(Vec2::new(0.75, 0.25)), 0.0);
    }

    #[test]
    fn missing_and_malformed_images_are_errors() {
        let dir = std::env::temp_dir().join(format!("nis-texture-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let missing = Bitmap::load(
            &dir.join("nope.png"),
            false,
            FilterMode::Bilinear,
            WrapMode::Repeat,
        );
        assert!(missing.unwrap_err().to_string().contains("nope.png"));
        let bad = dir.join("bad.png");
        std::fs::write(&bad, b"not a png").unwrap();
        assert!(Bitmap::load(&bad, false, FilterMode::Bilinear, WrapMode::Repeat).is_err());
        std::fs::remove_dir_all(&dir).ok();
    }
}
