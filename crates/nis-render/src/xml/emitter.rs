//! The scene's own emitters: a `constant` environment and `directional` lights (Mitsuba 3's
//! plugins, their parameters and defaults). Area emitters belong to their shape.

use glam::Vec3;

use super::dom::{err, Element};
use super::props::Props;
use super::{unsupported, LoadResult, Loader};
use crate::geometry::Rgb;
use crate::light::DirectionalLight;
use crate::spectrum::Role;

impl Loader {
    pub(super) fn emitter(&mut self, c: &Element) -> LoadResult<()> {
        let kind = c.required("type")?;
        let p = Props::new(c)?;
        match kind {
            "constant" => {
                if self.environment.is_some() {
                    return Err(err::<()>(c.line, "only one constant environment is supported")
                        .unwrap_err()
                        .into());
                }
                self.environment = Some(p.spectrum("radiance", Rgb::ONE, Role::Emission)?);
            }
            "directional" => {
                let irradiance = p.spectrum("irradiance", Rgb::ONE, Role::Emission)?;
                // `direction`, or the local +z through `to_world` (Mitsuba's two spellings).
                let direction = match p.by_name.contains_key("direction") {
                    true => p.point("direction", Vec3::Z)?,
                    false => p.transform("to_world")?.transform_vector3(Vec3::Z),
                };
                let Some(direction) = direction.try_normalize() else {
                    return Err(err::<()>(c.line, "a directional emitter needs a non-zero direction")
                        .unwrap_err()
                        .into());
                };
                self.directional.push(DirectionalLight {
                    direction,
                    irradiance,
                });
            }
            "envmap" | "sunsky" | "sky" | "sun" | "point" | "spot" | "projector" => {
                return Err(err::<()>(
                    c.line,
                    format!("the emitter <emitter type=\"{kind}\"> is not supported yet (supported: constant, directional, area inside a shape)"),
                )
                .unwrap_err()
                .into())
            }
            _ => return unsupported(c, "constant, directional; area inside a shape"),
        }
        p.finish()?;
        Ok(())
    }
}
