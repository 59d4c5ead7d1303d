//! Mitsuba 3's `principled` BSDF: its parameters, numbers or textures (a scalar parameter's
//! texture acts by its luminance, as Mitsuba's `eval_1` does), and the index of refraction given
//! as `eta` or as `specular` (`eta = 2 / (1 − √(0.08 specular)) − 1`). `anisotropic` (in [0, 1])
//! stretches the specular and transmission lobes along the shading frame's `∂p/∂u`.

use super::bsdf::Colours;
use super::dom::{err, Element, XmlError};
use super::props::Props;
use crate::bsdf::{Bsdf, Principled, PrincipledParam, Slot};
use crate::geometry::Rgb;

/// The principled BSDF of `<bsdf type="principled">` at `el`.
pub(super) fn principled(p: &Props, el: &Element, c: &mut Colours) -> Result<Bsdf, XmlError> {
    use PrincipledParam as P;
    // Mitsuba keeps a transmission lobe only when spec_trans is given and not the number 0;
    // with one, an index of exactly 1 is nudged off it.
    let has_trans =
        c.textures.iter().any(|(n, _)| n == "spec_trans") || p.float("spec_trans", 0.0)? != 0.0;
    let eta =
        match (p.float_opt("eta")?, p.float_opt("specular")?) {
            (Some(_), Some(_)) => return err(
                el.line,
                "a principled BSDF takes its index of refraction as eta or as specular, not both",
            ),
            (Some(eta), None) => {
                if !(eta > 0.0 && eta.is_finite()) {
                    return err(el.line, format!("principled eta = {eta} must be positive"));
                }
                if has_trans && eta == 1.0 {
                    1.001
                } else {
                    eta
                }
            }
            (None, specular) => {
                let mut s = specular.unwrap_or(0.5);
                if !(0.0..12.5).contains(&s) {
                    return err(
                        el.line,
                        format!("principled specular = {s} must be in [0, 12.5)"),
                    );
                }
                if has_trans && s == 0.0 {
                    s = 1e-3;
                }
                2.0 / (1.0 - (0.08 * s).sqrt()) - 1.0
            }
        };
    let mut rates = [0.0; 3];
    let names = [
        "main_specular_sampling_rate",
        "clearcoat_sampling_rate",
        "diffuse_reflectance_sampling_rate",
    ];
    for (rate, name) in rates.iter_mut().zip(names) {
        *rate = p.float(name, 1.0)?;
        if !(*rate >= 0.0 && rate.is_finite()) {
            return err(el.line, format!("principled {name} = {rate} must be ≥ 0"));
        }
    }
    let base_color = c.get("base_color", Slot::Reflectance, Rgb::splat(0.5))?;
    let mut scalar = |name: &'static str, param: P, default: f32| -> Result<f32, XmlError> {
        let v = c.scalar(name, Slot::Principled(param), default)?;
        if !v.is_finite() {
            return err(el.line, format!("principled {name} = {v} is not a number"));
        }
        Ok(v)
    };
    let b = Principled {
        base_color,
        roughness: scalar("roughness", P::Roughness, 0.5)?,
        anisotropic: scalar("anisotropic", P::Anisotropic, 0.0)?,
        metallic: scalar("metallic", P::Metallic, 0.0)?,
        spec_tint: scalar("spec_tint", P::SpecTint, 0.0)?,
        spec_trans: scalar("spec_trans", P::SpecTrans, 0.0)?,
        sheen: scalar("sheen", P::Sheen, 0.0)?,
        sheen_tint: scalar("sheen_tint", P::SheenTint, 0.0)?,
        clearcoat: scalar("clearcoat", P::Clearcoat, 0.0)?,
        clearcoat_gloss: scalar("clearcoat_gloss", P::ClearcoatGloss, 0.0)?,
        flatness: scalar("flatness", P::Flatness, 0.0)?,
        eta,
        rates,
    };
    for (name, v) in [
        ("anisotropic", b.anisotropic),
        ("clearcoat_gloss", b.clearcoat_gloss),
    ] {
        if !(0.0..=1.0).contains(&v) {
            return err(
                el.line,
                format!("principled {name} = {v} must be in [0, 1]"),
            );
        }
    }
    Ok(Bsdf::Principled(Box::new(b)))
}
