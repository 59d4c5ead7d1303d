//! Textures: `bitmap`, `checkerboard`, `rawconstant` and `mesh_attribute` (Mitsuba 3's plugins), nested in a BSDF under a
//! parameter's name, or defined once at the top with an `id` and used by
//! `<ref name="reflectance" id="…"/>`. An image file is read once however often it is used.

use std::path::PathBuf;
use std::sync::Arc;

use glam::{Mat3, Mat4, Vec3};

use super::dom::error_at;
use super::dom::{err, Element, XmlError};
use super::fail;
use super::props::Props;
use super::{unsupported, LoadResult, Loader};
use crate::geometry::Rgb;
use crate::texture::{Bitmap, FilterMode, Texture, WrapMode};

/// The 2-D affine part of a `to_uv` transform (x and y rows, translation).
fn uv_transform(m: Mat4) -> Mat3 {
    Mat3::from_cols(
        Vec3::new(m.x_axis.x, m.x_axis.y, 0.0),
        Vec3::new(m.y_axis.x, m.y_axis.y, 0.0),
        Vec3::new(m.w_axis.x, m.w_axis.y, 1.0),
    )
}

impl Loader {
    /// A `<texture>` element.
    pub(super) fn texture(&mut self, el: &Element) -> LoadResult<Arc<Texture>> {
        let kind = el.required("type")?;
        let p = Props::new(el)?;
        let to_uv = uv_transform(p.transform("to_uv")?);
        let texture = match kind {
            "bitmap" => {
                let Some(file) = p.string("filename")? else {
                    return fail(
                        el.line,
                        "<texture type=\"bitmap\"> needs <string name=\"filename\">",
                    );
                };
                let filter = match p.string("filter_type")?.unwrap_or("bilinear") {
                    "bilinear" => FilterMode::Bilinear,
                    "nearest" => FilterMode::Nearest,
                    // Mitsuba 0.x's mipmapped filters, without the mipmap.
                    "ewa" | "trilinear" => FilterMode::Bilinear,
                    other => {
                        return fail(
                            el.line,
                            format!("unknown filter_type '{other}' (bilinear, nearest)"),
                        )
                    }
                };
                let wrap_name = p
                    .string("wrap_mode")?
                    .or(p.string("wrap_mode_u")?)
                    .unwrap_or("repeat");
                p.ignore(&["wrap_mode_v", "format", "max_anisotropy", "accel", "cache"]);
                let wrap = match wrap_name {
                    "repeat" => WrapMode::Repeat,
                    "mirror" => WrapMode::Mirror,
                    "clamp" => WrapMode::Clamp,
                    // Mitsuba 0.x: outside the image is black or white; clamping is nearest.
                    "zero" | "one" => WrapMode::Clamp,
                    other => {
                        return fail(
                            el.line,
                            format!("unknown wrap_mode '{other}' (repeat, mirror, clamp)"),
                        )
                    }
                };
                // Mitsuba 0.x's `gamma` (−1: sRGB, 1: linear), Mitsuba 3's `raw`; any other
                // power has no Mitsuba 3 reading.
                let gamma = p.float("gamma", -1.0)?;
                if gamma != -1.0 && gamma != 1.0 {
                    return fail(
                        el.line,
                        format!(
                            "bitmap gamma {gamma} is not supported: -1 (sRGB) or 1 (linear, \
                             Mitsuba 3's raw)"
                        ),
                    );
                }
                let raw = p.boolean("raw", false)? || gamma == 1.0;
                let path = self.resolve(file);
                let key = (path.clone(), raw, filter, wrap);
                let image = match self.bitmaps.get(&key) {
                    Some(b) => b.clone(),
                    None => {
                        let b = Arc::new(
                            Bitmap::load(&path, raw, filter, wrap)
                                .map_err(|e| error_at(el.line, e.to_string()))?,
                        );
                        self.bitmaps.insert(key, b.clone());
                        b
                    }
                };
                Texture::Bitmap { image, to_uv }
            }
            "checkerboard" => Texture::Checkerboard {
                color0: p.rgb("color0", Rgb::splat(0.4))?,
                color1: p.rgb("color1", Rgb::splat(0.2))?,
                to_uv,
            },
            "rawconstant" => match p.get("value", &["float", "vector", "point"])? {
                Some(v) if v.name == "float" => Texture::RawConstant {
                    value: Rgb::splat(p.float("value", 0.0)?),
                    vector: false,
                },
                Some(_) => Texture::RawConstant {
                    value: p.point("value", Vec3::ZERO)?,
                    vector: true,
                },
                None => {
                    return fail(
                        el.line,
                        "<texture type=\"rawconstant\"> needs a <float> or <vector> \"value\"",
                    )
                }
            },
            "mesh_attribute" => {
                let Some(name) = p.string("name")? else {
                    return fail(
                        el.line,
                        "<texture type=\"mesh_attribute\"> needs <string name=\"name\">",
                    );
                };
                // Mitsuba 3 checks for either word anywhere in the name.
                if !name.contains("vertex_") && !name.contains("face_") {
                    return fail(
                        el.line,
                        format!(
                            "mesh attribute name '{name}' must start with \"vertex_\" or \"face_\""
                        ),
                    );
                }
                Texture::MeshAttribute {
                    name: name.to_string(),
                    scale: p.float("scale", 1.0)?,
                }
            }
            _ => return unsupported(el, "bitmap, checkerboard, rawconstant, mesh_attribute"),
        };
        p.finish()?;
        Ok(Arc::new(texture))
    }

    /// The textures among a plugin's children, by parameter name: nested `<texture name=…>`
    /// and `<ref name=… id=…>` to a texture defined before. Other `<ref>`s are left to the
    /// caller (a wrapper's BSDF).
    pub(super) fn named_textures(
        &mut self,
        el: &Element,
    ) -> LoadResult<Vec<(String, Arc<Texture>)>> {
        let mut out = Vec::new();
        for c in &el.children {
            let Some(name) = c.attr("name") else { continue };
            let texture = match c.name.as_str() {
                "texture" => self.texture(c)?,
                "ref" => {
                    let id = c.required("id")?;
                    match self.textures.get(id) {
                        Some(t) => t.clone(),
                        None => {
                            return super::fail(
                                c.line,
                                format!("no texture with id '{id}' is defined before this point"),
                            )
                        }
                    }
                }
                _ => continue,
            };
            if out.iter().any(|(n, _)| n == name) {
                return fail(c.line, format!("parameter '{name}' is given twice"));
            }
            out.push((name.to_string(), texture));
        }
        Ok(out)
    }
}

/// Refuse a texture read as a number (`name`, on the element at `line`) that has none: a
/// 3-vector `rawconstant`, whose `eval_1` Mitsuba 3 refuses.
pub(super) fn check_scalar(t: &Texture, line: usize, name: &str) -> Result<(), XmlError> {
    match t {
        Texture::RawConstant { vector: true, .. } => err(
            line,
            format!("'{name}' is a number: a rawconstant 3-vector cannot stand for it"),
        ),
        _ => Ok(()),
    }
}

/// Refuse a `mesh_attribute` texture where nis reads a texture without a mesh hit (`what`:
/// a bump or normal map, an emitter), on the element at `line`.
pub(super) fn check_not_attribute(t: &Texture, line: usize, what: &str) -> Result<(), XmlError> {
    match t {
        Texture::MeshAttribute { .. } => err(
            line,
            format!("a mesh_attribute texture as {what} is not supported"),
        ),
        _ => Ok(()),
    }
}

/// Keys of the loaded-image cache: the file and how it is read.
pub(super) type BitmapKey = (PathBuf, bool, FilterMode, WrapMode);
