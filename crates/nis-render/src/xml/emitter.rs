//! The scene's own emitters: a `constant` environment, an `envmap` or a `sunsky`
//! (`sunsky.rs`), `directional`, `point` and `spot` lights, a spot projecting a `texture`, and a
//! `projector` (Mitsuba 3's plugins, their parameters and defaults). Area emitters belong to
//! their shape.

use std::sync::Arc;

use glam::{Mat3, Vec2, Vec3};

use super::dom::error_at;
use super::dom::Element;
use super::fail;
use super::props::{Props, PROPERTY_TAGS};
use super::sensor::{focal_length_fov, fov_axis};
use super::{unsupported, LoadResult, Loader};
use crate::camera::{half_tangents, FovAxis};
use crate::envmap::EnvMap;
use crate::geometry::Rgb;
use crate::light::{DeltaLight, DirectionalLight, EnvironmentLight, ProjectorLight, SpotLight};
use crate::spectrum::Role;
use crate::texture::{Bitmap, FilterMode, Texture, WrapMode};

impl Loader {
    pub(super) fn emitter(&mut self, c: &Element) -> LoadResult<()> {
        let kind = c.required("type")?;
        // A spot's `texture` and a projector's `irradiance` are the textures emitters take.
        let slot = match kind {
            "spot" => Some("texture"),
            "projector" => Some("irradiance"),
            _ => None,
        };
        let takes_texture = |x: &Element| {
            slot.is_some() && matches!(x.name.as_str(), "texture" | "ref") && x.attr("name") == slot
        };
        if let Some(x) = c
            .children
            .iter()
            .find(|x| !PROPERTY_TAGS.contains(&x.name.as_str()) && !takes_texture(x))
        {
            return unsupported(
                x,
                "properties inside an emitter; a spot's <texture name=\"texture\">, a \
                 projector's <texture name=\"irradiance\">",
            );
        }
        let texture = match slot {
            Some(_) => self.named_textures(c)?.pop().map(|(_, t)| t),
            None => None,
        };
        if let Some(t) = &texture {
            super::texture::check_not_attribute(t, c.line, "an emitter's texture")?;
        }
        let p = Props::new(c)?;
        match kind {
            "constant" | "envmap" | "sunsky" if self.environment.is_some() || self.environment_map.is_some() => {
                return fail(c.line, "only one environment emitter (constant, envmap or sunsky) is supported");
            }
            "constant" => {
                self.environment = Some(p.spectrum("radiance", Rgb::ONE, Role::Emission)?);
            }
            "envmap" => {
                let Some(file) = p.string("filename")? else {
                    return fail(c.line, "<emitter type=\"envmap\"> needs <string name=\"filename\">");
                };
                let scale = p.float("scale", 1.0)?;
                let to_world = Mat3::from_mat4(p.transform("to_world")?);
                // Mitsuba 0.x's `gamma` (−1: sRGB for 8-bit images, 1: linear); caching and
                // sampling weights do not change the image.
                let raw = p.float("gamma", -1.0)? == 1.0 || p.boolean("raw", false)?;
                p.ignore(&["cache", "sampling_weight", "filter_type", "mis_compensation"]);
                let path = self.resolve(file);
                let image = Bitmap::load(&path, raw, FilterMode::Bilinear, WrapMode::Repeat)
                    .map_err(|e| error_at(c.line, e.to_string()))?;
                match EnvMap::new(image, scale, to_world) {
                    Some(map) => self.environment_map = Some(EnvironmentLight::Map(map)),
                    None => self
                        .warnings
                        .push((c.line, format!("the environment map {file} is black"))),
                }
            }
            "directional" => {
                let irradiance = p.spectrum("irradiance", Rgb::ONE, Role::Emission)?;
                // `direction`, or the local +z through `to_world` (Mitsuba's two spellings).
                let direction = match p.by_name.contains_key("direction") {
                    true => p.point("direction", Vec3::Z)?,
                    false => p.transform("to_world")?.transform_vector3(Vec3::Z),
                };
                let Some(direction) = direction.try_normalize() else {
                    return fail(c.line, "a directional emitter needs a non-zero direction");
                };
                self.delta.push(DeltaLight::Directional(DirectionalLight {
                    direction,
                    irradiance,
                }));
            }
            "spot" => {
                let intensity = p.spectrum("intensity", Rgb::ONE, Role::Emission)?;
                let cutoff = p.float("cutoff_angle", 20.0)?;
                let beam = p.float("beam_width", cutoff * 0.75)?;
                if !(cutoff > 0.0 && cutoff <= 180.0 && beam > 0.0 && beam < cutoff) {
                    return fail(c.line, format!("a spot needs 0 < beam_width ({beam}) < cutoff_angle ({cutoff}) ≤ 180 degrees"));
                }
                // It sits at to_world's origin and shines along its local +z.
                let to_world = p.transform("to_world")?;
                let linear = Mat3::from_mat4(to_world);
                let Some(axis) = (linear * Vec3::Z)
                    .try_normalize()
                    .filter(|_| linear.determinant() != 0.0)
                else {
                    return fail(c.line, "a spot's to_world has no direction");
                };
                self.delta.push(DeltaLight::Spot(SpotLight {
                    position: to_world.transform_point3(Vec3::ZERO),
                    axis,
                    intensity,
                    cutoff: cutoff.to_radians(),
                    beam_width: beam.to_radians(),
                    texture,
                    to_local: linear.inverse(),
                }));
            }
            "projector" => {
                let light = projector(c, &p, texture)?;
                self.delta.push(DeltaLight::Projector(light));
            }
            "point" => {
                let intensity = p.spectrum("intensity", Rgb::ONE, Role::Emission)?;
                // `position`, or to_world's origin (Mitsuba refuses both).
                let position = match (p.by_name.contains_key("position"), p.by_name.contains_key("to_world")) {
                    (true, true) => {
                        return fail(c.line, "give a point emitter either position or to_world, not both")
                    }
                    (true, false) => p.point("position", Vec3::ZERO)?,
                    (false, _) => p.transform("to_world")?.transform_point3(Vec3::ZERO),
                };
                self.delta.push(DeltaLight::Point { position, intensity });
            }
            "sunsky" => self.sunsky(c, &p)?,
            "sky" | "sun" => {
                return fail(c.line,
                    format!("the emitter <emitter type=\"{kind}\"> is not supported yet (supported: constant, envmap, sunsky, directional, point, spot, projector, area inside a shape)"))
            }
            _ => return unsupported(c, "constant, envmap, sunsky, directional, point, spot, projector; area inside a shape"),
        }
        p.finish()?;
        Ok(())
    }
}

/// A `projector`: its field of view (`fov` along `fov_axis`, or Mitsuba's default 35 mm
/// `focal_length` of 50mm along the diagonal) over the irradiance texture's aspect (a colour's
/// is 1, as Mitsuba's constant texture has resolution 1 × 1).
fn projector(c: &Element, p: &Props, texture: Option<Arc<Texture>>) -> LoadResult<ProjectorLight> {
    let fail = |m: String| -> LoadResult<ProjectorLight> { fail(c.line, m) };
    let irradiance = match texture {
        Some(_) => Rgb::ONE,
        None => p.spectrum("irradiance", Rgb::ONE, Role::Emission)?,
    };
    let scale = p.float("scale", 1.0)?;
    let (w, h) = match texture.as_deref() {
        Some(Texture::Bitmap { image, .. }) => image.size(),
        _ => (1, 1),
    };
    let (fov, axis) = match (p.float_opt("fov")?, p.string("focal_length")?) {
        (Some(_), Some(_)) => {
            return fail("give a projector either fov or focal_length, not both".into())
        }
        (Some(fov), None) => (fov, fov_axis(c, p)?),
        (None, f) => (focal_length_fov(c, f)?, FovAxis::Diagonal),
    };
    if !(fov > 0.0 && fov < 180.0) {
        return fail(format!(
            "the field of view must be between 0 and 180 degrees, got {fov}"
        ));
    }
    let (tx, ty) = half_tangents(fov, axis, w as f32, h as f32);
    let to_world = p.transform("to_world")?;
    if to_world.determinant() == 0.0 {
        return fail("a projector's to_world is singular".into());
    }
    Ok(ProjectorLight {
        position: to_world.transform_point3(Vec3::ZERO),
        to_local: to_world.inverse(),
        axis: to_world.transform_vector3(Vec3::Z),
        tan_half: Vec2::new(tx, ty),
        irradiance: irradiance * scale,
        texture,
    })
}
