//! The `<sensor>`: a `perspective`, `thinlens` or `orthographic` camera with its film (`hdrfilm`, or Mitsuba 0.x's `ldrfilm`,
//! whose tonemapping does not change the linear image), reconstruction filter and sampler
//! (any type: only its `sample_count` matters to an unbiased renderer).

use super::dom::error_at;
use super::dom::Element;
use super::fail;
use super::props::{Props, PROPERTY_TAGS};
use super::{out_of_range, unsupported, LoadResult, Loader, MAX_FILM_PIXELS, MAX_FILM_SIDE};
use crate::camera::{Camera, FovAxis, Projection};
use crate::filter::{Filter, FilterKind};

impl Loader {
    pub(super) fn sensor(&mut self, el: &Element) -> LoadResult<()> {
        let kind = el.required("type")?;
        if !["perspective", "thinlens", "orthographic"].contains(&kind) {
            return unsupported(el, "perspective, thinlens, orthographic");
        }
        if self.camera.is_some() {
            return fail(el.line, "only one <sensor> is supported");
        }
        let p = Props::new(el)?;
        let projection = projection(el, &p, kind)?;
        // Parallel rays have no field of view (a value given is read and left unused).
        // Without `fov`, a perspective's `focal_length` (default 50mm) along the diagonal; Mitsuba
        // refuses both.
        let focal = match projection {
            Projection::Orthographic => None,
            _ => p.string("focal_length")?,
        };
        let (fov, fov_axis) = match (p.float_opt("fov")?, focal) {
            (Some(_), Some(_)) => {
                return fail(
                    el.line,
                    "give the sensor either fov or focal_length, not both",
                )
            }
            (Some(fov), None) => (fov, fov_axis(el, &p)?),
            (None, _) if projection == Projection::Orthographic => (40.0, fov_axis(el, &p)?),
            (None, f) => (focal_length_fov(el, f)?, FovAxis::Diagonal),
        };
        if !(fov > 0.0 && fov < 180.0) {
            return fail(
                el.line,
                format!("the field of view must be between 0 and 180 degrees, got {fov}"),
            );
        }
        let to_world = p.transform("to_world")?;
        p.ignore(&["near_clip", "far_clip", "shutter_open", "shutter_close"]);
        if projection == Projection::Perspective {
            p.ignore(&["focus_distance"]);
        }
        p.finish()?;
        let (mut width, mut height) = (768, 576);
        for c in el
            .children
            .iter()
            .filter(|c| !PROPERTY_TAGS.contains(&c.name.as_str()))
        {
            match c.name.as_str() {
                "film" => (width, height) = self.film(c)?,
                "sampler" => {
                    let s = Props::new(c)?;
                    let spp = s.int("sample_count", 4)?;
                    self.settings.spp = u32::try_from(spp)
                        .ok()
                        .filter(|&n| n >= 1)
                        .ok_or_else(|| out_of_range(c, "sample_count", spp, "1..=2^32-1"))?;
                    // Every sampler type gives the same expected image; the rest of its
                    // settings only change the noise.
                    let others: Vec<&str> = s
                        .by_name
                        .keys()
                        .copied()
                        .filter(|k| *k != "sample_count")
                        .collect();
                    s.ignore(&others);
                    s.finish()?;
                }
                _ => return unsupported(c, "film, sampler"),
            }
        }
        self.camera = Some(
            Camera::new(to_world, fov, fov_axis, width as u32, height as u32)
                .with_projection(projection),
        );
        Ok(())
    }

    /// The film's size, and its reconstruction filter into the settings.
    fn film(&mut self, c: &Element) -> LoadResult<(i64, i64)> {
        let kind = c.required("type")?;
        if kind != "hdrfilm" && kind != "ldrfilm" {
            return unsupported(c, "hdrfilm, ldrfilm");
        }
        let f = Props::new(c)?;
        let width = f.int("width", 768)?;
        let height = f.int("height", 576)?;
        f.ignore(&[
            "pixel_format",
            "component_format",
            "file_format",
            "banner",
            "rfilter",
            "high_quality_edges",
            "sample_border",
            "attach_log",
            "compensate",
            // ldrfilm's tonemapping: the image we keep is the linear one.
            "tonemap_method",
            "gamma",
            "exposure",
            "key",
            "burn",
        ]);
        if f.by_name.contains_key("crop_width") || f.by_name.contains_key("crop_offset_x") {
            return fail(
                c.line,
                "crop windows (crop_width, crop_offset_x, …) are not supported",
            );
        }
        f.finish()?;
        if !(1..=MAX_FILM_SIDE).contains(&width)
            || !(1..=MAX_FILM_SIDE).contains(&height)
            || width * height > MAX_FILM_PIXELS
        {
            return fail(c.line,
                format!("film of {width}×{height} pixels: each side must be 1..={MAX_FILM_SIDE} and the film at most {MAX_FILM_PIXELS} pixels"));
        }
        // Mitsuba's default filter is the Gaussian of standard deviation ½.
        let mut filter = FilterKind::Gaussian { stddev: 0.5 };
        for r in c
            .children
            .iter()
            .filter(|r| !PROPERTY_TAGS.contains(&r.name.as_str()))
        {
            if r.name != "rfilter" {
                return unsupported(r, "rfilter inside a film");
            }
            filter = rfilter(r)?;
        }
        self.settings.filter = Filter::new(filter)
            .map_err(|m| error_at(c.line, format!("reconstruction filter: {m}")))?;
        Ok((width, height))
    }
}

/// A `<rfilter>` as Mitsuba 3 defines its plugins' parameters and defaults.
fn rfilter(r: &Element) -> LoadResult<FilterKind> {
    let p = Props::new(r)?;
    let kind = match r.required("type")? {
        "box" => FilterKind::Box,
        "tent" => FilterKind::Tent {
            radius: p.float("radius", 1.0)?,
        },
        "gaussian" => FilterKind::Gaussian {
            stddev: p.float("stddev", 0.5)?,
        },
        "mitchell" => FilterKind::Mitchell {
            b: p.float("b", 1.0 / 3.0)?,
            c: p.float("c", 1.0 / 3.0)?,
        },
        "catmullrom" => FilterKind::Mitchell { b: 0.0, c: 0.5 },
        "lanczos" => {
            let lobes = p.int("lobes", 3)?;
            FilterKind::Lanczos {
                lobes: u32::try_from(lobes)
                    .ok()
                    .filter(|l| (1..=16).contains(l))
                    .ok_or_else(|| out_of_range(r, "lobes", lobes, "1..=16"))?,
            }
        }
        _ => return unsupported(r, "box, tent, gaussian, mitchell, catmullrom, lanczos"),
    };
    p.finish()?;
    Ok(kind)
}

/// The projection of a sensor of type `kind`: a thin lens's `aperture_radius` (required, as in
/// Mitsuba) and `focus_distance` (Mitsuba's default: the far clip distance, 10⁴).
fn projection(el: &Element, p: &Props, kind: &str) -> LoadResult<Projection> {
    Ok(match kind {
        "thinlens" => {
            let Some(aperture_radius) = p.float_opt("aperture_radius")? else {
                return fail(
                    el.line,
                    "a thinlens sensor needs <float name=\"aperture_radius\">",
                );
            };
            let far = p.float("far_clip", 1e4)?;
            let focus_distance = p.float("focus_distance", far)?;
            for (name, v) in [
                ("aperture_radius", aperture_radius),
                ("focus_distance", focus_distance),
            ] {
                if !(v.is_finite() && v > 0.0) {
                    return fail(
                        el.line,
                        format!("the thinlens sensor's {name} must be a positive number, got {v}"),
                    );
                }
            }
            Projection::ThinLens {
                aperture_radius,
                focus_distance,
            }
        }
        "orthographic" => Projection::Orthographic,
        _ => Projection::Perspective,
    })
}

/// Mitsuba's `fov_axis` (default `x`).
pub(super) fn fov_axis(el: &Element, p: &Props) -> LoadResult<FovAxis> {
    Ok(match p.string("fov_axis")?.unwrap_or("x") {
        "x" => FovAxis::X,
        "y" => FovAxis::Y,
        "diagonal" => FovAxis::Diagonal,
        "smaller" => FovAxis::Smaller,
        "larger" => FovAxis::Larger,
        other => return fail(el.line, format!("unknown fov_axis '{other}'")),
    })
}

/// The field of view, in degrees along the diagonal, of Mitsuba's `focal_length` (default
/// `50mm`, a 35 mm film's: 36 × 24 mm), as its `parse_fov` reads it (the `mm` is optional).
pub(super) fn focal_length_fov(el: &Element, f: Option<&str>) -> LoadResult<f32> {
    let f = f.unwrap_or("50mm");
    let Some(mm) = f
        .strip_suffix("mm")
        .unwrap_or(f)
        .trim()
        .parse::<f32>()
        .ok()
        .filter(|mm| mm.is_finite() && *mm > 0.0)
    else {
        return fail(
            el.line,
            format!("focal_length '{f}' is not a positive length in mm"),
        );
    };
    Ok(2.0
        * ((36f32 * 36.0 + 24.0 * 24.0).sqrt() / (2.0 * mm))
            .atan()
            .to_degrees())
}
