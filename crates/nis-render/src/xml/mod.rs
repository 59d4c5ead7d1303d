//! A loader for the subset of Mitsuba 3's XML scene format that the experiments use.
//!
//! Supported: `<default>` parameters; the `path` integrator (`max_depth`, `rr_depth`,
//! `hide_emitters`); a `perspective` sensor (`fov`, `fov_axis`, `to_world`) with an `hdrfilm`
//! (`width`, `height`, a `box` rfilter) and a sampler (`sample_count`); shapes `obj`,
//! `rectangle`, `cube`, `sphere` (with `to_world`, `flip_normals`, `face_normals`); BSDFs
//! `diffuse`, `conductor`, `roughconductor`, `dielectric`, `roughdielectric` (GGX only) and
//! `twosided`, inline or by `<ref id=…>`; `area` emitters in shapes and a `constant`
//! environment. Values mean what they mean in Mitsuba 3 (its plugin documentation is the
//! reference): `rgb` values are linear, `fov_axis` defaults to `x`, the film's resolution and the
//! sampler's sample count are defaults that the caller may override. Anything else is an error
//! that names the element and its line, so a scene never renders differently in silence.
//! One deliberate difference: without an `<rfilter>` Mitsuba uses a Gaussian; we always use a box.

mod dom;
mod props;

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use glam::{Mat3, Vec3};

use crate::bsdf::{Bsdf, Material};
use crate::camera::{Camera, FovAxis};
use crate::geometry::Rgb;
use crate::scene::{RenderSettings, Scene};
use crate::shape::{Geometry, Shape, Sphere, TriangleMesh};
use crate::Error;
use dom::{err, Element, XmlError};
use props::{ior, Props, PROPERTY_TAGS};

/// Load a Mitsuba 3 XML scene file; `params` override its `<default>`s (`$name` values).
pub fn load_scene(path: &Path, params: &[(String, String)]) -> Result<Scene, Error> {
    let text = std::fs::read_to_string(path).map_err(|source| Error::Io {
        path: path.display().to_string(),
        source,
    })?;
    let base = path.parent().map(Path::to_path_buf).unwrap_or_default();
    load_scene_str(&text, &base, &path.display().to_string(), params)
}

/// Load a scene from XML text; relative mesh paths are resolved against `base_dir`, and
/// errors name `source` as the file.
pub fn load_scene_str(
    text: &str,
    base_dir: &Path,
    source: &str,
    params: &[(String, String)],
) -> Result<Scene, Error> {
    let to_error = |e: XmlError| Error::Xml {
        file: source.to_string(),
        line: e.line,
        message: e.message,
    };
    let mut root = dom::parse(text).map_err(to_error)?;
    if root.name != "scene" {
        return Err(to_error(XmlError {
            line: root.line,
            message: format!("the root element must be <scene>, not <{}>", root.name),
        }));
    }
    let mut values: HashMap<String, String> = params.iter().cloned().collect();
    for d in root.children.iter().filter(|c| c.name == "default") {
        let name = d.required("name").map_err(to_error)?;
        let value = d.required("value").map_err(to_error)?;
        values
            .entry(name.to_string())
            .or_insert_with(|| value.to_string());
    }
    // Substitution may add up to the file's own size again, plus a margin for short files.
    let mut budget = text.len() + (1 << 16);
    dom::substitute(&mut root, &values, &mut budget).map_err(to_error)?;
    let mut loader = Loader {
        base_dir: base_dir.to_path_buf(),
        ..Default::default()
    };
    loader.scene(&root).map_err(|e| match e {
        LoadError::Xml(x) => to_error(x),
        LoadError::Other(e) => e,
    })
}

enum LoadError {
    Xml(XmlError),
    Other(Error),
}

impl From<XmlError> for LoadError {
    fn from(e: XmlError) -> Self {
        LoadError::Xml(e)
    }
}

type LoadResult<T> = Result<T, LoadError>;

#[derive(Default)]
struct Loader {
    base_dir: PathBuf,
    materials: Vec<Material>,
    bsdf_ids: HashMap<String, usize>,
    shapes: Vec<Shape>,
    environment: Option<Rgb>,
    camera: Option<Camera>,
    settings: RenderSettings,
}

/// Largest film side the loader accepts, in pixels.
pub const MAX_FILM_SIDE: i64 = 1 << 15;
/// Largest film the loader accepts, in pixels (8192², 768 MiB of RGB f32).
pub const MAX_FILM_PIXELS: i64 = 1 << 26;

fn out_of_range(el: &Element, name: &str, value: i64, range: &str) -> LoadError {
    LoadError::Xml(XmlError {
        line: el.line,
        message: format!("{name} = {value} is out of range (expected {range})"),
    })
}

fn unsupported<T>(el: &Element, supported: &str) -> LoadResult<T> {
    let what = match el.attr("type") {
        Some(t) => format!("<{} type=\"{t}\">", el.name),
        None => format!("<{}>", el.name),
    };
    Err(err::<()>(
        el.line,
        format!("unsupported element {what} (supported: {supported})"),
    )
    .unwrap_err()
    .into())
}

impl Loader {
    fn scene(&mut self, root: &Element) -> LoadResult<Scene> {
        for c in &root.children {
            match c.name.as_str() {
                "default" => {}
                "integrator" => self.integrator(c)?,
                "sensor" => self.sensor(c)?,
                "bsdf" => {
                    let id = c.required("id")?.to_string();
                    let m = self.bsdf(c)?;
                    self.materials.push(m);
                    self.bsdf_ids.insert(id, self.materials.len() - 1);
                }
                "shape" => self.shape(c)?,
                "emitter" => match c.required("type")? {
                    "constant" => {
                        let p = Props::new(c)?;
                        self.environment = Some(p.rgb("radiance", Rgb::ONE)?);
                        p.finish()?;
                    }
                    _ => return unsupported(c, "constant here, area inside a shape"),
                },
                _ => return unsupported(c, "default, integrator, sensor, bsdf, shape, emitter"),
            }
        }
        let Some(camera) = self.camera.take() else {
            return Err(err::<()>(root.line, "the scene has no <sensor>")
                .unwrap_err()
                .into());
        };
        Scene::new(
            camera,
            self.settings.clone(),
            std::mem::take(&mut self.materials),
            std::mem::take(&mut self.shapes),
            self.environment,
        )
        .map_err(LoadError::Other)
    }

    fn integrator(&mut self, el: &Element) -> LoadResult<()> {
        if el.required("type")? != "path" {
            return unsupported(el, "path");
        }
        let p = Props::new(el)?;
        let max_depth = p.int("max_depth", -1)?;
        self.settings.max_depth = i32::try_from(max_depth)
            .ok()
            .filter(|&d| d >= -1)
            .ok_or_else(|| {
                out_of_range(el, "max_depth", max_depth, "-1 (unbounded) or 0..=2^31-1")
            })?;
        let rr_depth = p.int("rr_depth", 5)?;
        self.settings.rr_depth = u32::try_from(rr_depth)
            .map_err(|_| out_of_range(el, "rr_depth", rr_depth, "0..=2^32-1"))?;
        self.settings.hide_emitters = p.boolean("hide_emitters", false)?;
        p.finish()?;
        Ok(())
    }

    fn sensor(&mut self, el: &Element) -> LoadResult<()> {
        if el.required("type")? != "perspective" {
            return unsupported(el, "perspective");
        }
        if self.camera.is_some() {
            return Err(err::<()>(el.line, "only one <sensor> is supported")
                .unwrap_err()
                .into());
        }
        let p = Props::new(el)?;
        let Some(fov) = p.float_opt("fov")? else {
            return Err(err::<()>(el.line, "the sensor needs <float name=\"fov\">")
                .unwrap_err()
                .into());
        };
        if !(fov > 0.0 && fov < 180.0) {
            return Err(err::<()>(
                el.line,
                format!("the field of view must be between 0 and 180 degrees, got {fov}"),
            )
            .unwrap_err()
            .into());
        }
        let fov_axis = match p.string("fov_axis")?.unwrap_or("x") {
            "x" => FovAxis::X,
            "y" => FovAxis::Y,
            "diagonal" => FovAxis::Diagonal,
            "smaller" => FovAxis::Smaller,
            "larger" => FovAxis::Larger,
            other => {
                return Err(err::<()>(el.line, format!("unknown fov_axis '{other}'"))
                    .unwrap_err()
                    .into())
            }
        };
        let to_world = p.transform("to_world")?;
        p.ignore(&["near_clip", "far_clip", "focus_distance"]);
        p.finish()?;
        let (mut width, mut height) = (768, 576);
        for c in el
            .children
            .iter()
            .filter(|c| !PROPERTY_TAGS.contains(&c.name.as_str()))
        {
            match c.name.as_str() {
                "film" => {
                    if c.required("type")? != "hdrfilm" {
                        return unsupported(c, "hdrfilm");
                    }
                    let f = Props::new(c)?;
                    width = f.int("width", 768)?;
                    height = f.int("height", 576)?;
                    f.ignore(&[
                        "pixel_format",
                        "component_format",
                        "file_format",
                        "banner",
                        "rfilter",
                    ]);
                    f.finish()?;
                    if !(1..=MAX_FILM_SIDE).contains(&width)
                        || !(1..=MAX_FILM_SIDE).contains(&height)
                        || width * height > MAX_FILM_PIXELS
                    {
                        return Err(err::<()>(
                            c.line,
                            format!("film of {width}×{height} pixels: each side must be 1..={MAX_FILM_SIDE} and the film at most {MAX_FILM_PIXELS} pixels"),
                        )
                        .unwrap_err()
                        .into());
                    }
                    for r in c
                        .children
                        .iter()
                        .filter(|r| !PROPERTY_TAGS.contains(&r.name.as_str()))
                    {
                        if r.name != "rfilter" || r.attr("type") != Some("box") {
                            return unsupported(r, "<rfilter type=\"box\">");
                        }
                    }
                }
                "sampler" => {
                    let s = Props::new(c)?;
                    let spp = s.int("sample_count", 4)?;
                    self.settings.spp = u32::try_from(spp)
                        .ok()
                        .filter(|&n| n >= 1)
                        .ok_or_else(|| out_of_range(c, "sample_count", spp, "1..=2^32-1"))?;
                    s.ignore(&["seed", "jitter"]);
                    s.finish()?;
                }
                _ => return unsupported(c, "film, sampler"),
            }
        }
        self.camera = Some(Camera::new(
            to_world,
            fov,
            fov_axis,
            width as u32,
            height as u32,
        ));
        Ok(())
    }

    fn bsdf(&mut self, el: &Element) -> LoadResult<Material> {
        let kind = el.required("type")?;
        if kind == "twosided" {
            let inner: Vec<&Element> = el.children.iter().filter(|c| c.name == "bsdf").collect();
            if inner.len() != 1 || el.children.len() != 1 {
                return Err(err::<()>(
                    el.line,
                    "<bsdf type=\"twosided\"> needs exactly one nested <bsdf>",
                )
                .unwrap_err()
                .into());
            }
            let mut m = self.bsdf(inner[0])?;
            m.two_sided = true;
            return Ok(m);
        }
        if let Some(c) = el
            .children
            .iter()
            .find(|c| !PROPERTY_TAGS.contains(&c.name.as_str()))
        {
            return unsupported(c, "plain properties inside a bsdf (no textures)");
        }
        let p = Props::new(el)?;
        let alpha = |p: &Props| -> Result<f32, XmlError> {
            let dist = p.string("distribution")?.unwrap_or("beckmann");
            if dist != "ggx" {
                return err(el.line, format!("microfacet distribution '{dist}' is not supported: add <string name=\"distribution\" value=\"ggx\"/> (Mitsuba's default is beckmann)"));
            }
            let a = p.float("alpha", 0.1)?;
            let (au, av) = (p.float("alpha_u", a)?, p.float("alpha_v", a)?);
            if au != av {
                return err(
                    el.line,
                    "anisotropic roughness (alpha_u ≠ alpha_v) is not supported",
                );
            }
            p.ignore(&["sample_visible"]);
            Ok(au.max(1e-4))
        };
        let conductor = |p: &Props| -> Result<(Rgb, Rgb), XmlError> {
            let material = p.string("material")?.unwrap_or("none");
            if p.by_name.contains_key("eta") || p.by_name.contains_key("k") {
                return Ok((p.rgb("eta", Rgb::ZERO)?, p.rgb("k", Rgb::ONE)?));
            }
            if material != "none" {
                return err(el.line, format!("conductor material '{material}' is not supported: give <rgb name=\"eta\"> and <rgb name=\"k\">"));
            }
            Ok((Rgb::ZERO, Rgb::ONE))
        };
        let dielectric_eta = |p: &Props| -> Result<f32, XmlError> {
            let int = match p.get("int_ior", &["float", "string"])? {
                Some(e) => ior(e.required("value")?, e.line)?,
                None => 1.5046,
            };
            let ext = match p.get("ext_ior", &["float", "string"])? {
                Some(e) => ior(e.required("value")?, e.line)?,
                None => 1.000_277,
            };
            Ok(int / ext)
        };
        let bsdf = match kind {
            "diffuse" => Bsdf::Diffuse {
                reflectance: p.rgb("reflectance", Rgb::splat(0.5))?,
            },
            "conductor" => {
                let (eta, k) = conductor(&p)?;
                Bsdf::Conductor {
                    eta,
                    k,
                    specular_reflectance: p.rgb("specular_reflectance", Rgb::ONE)?,
                }
            }
            "roughconductor" => {
                let (eta, k) = conductor(&p)?;
                Bsdf::RoughConductor {
                    alpha: alpha(&p)?,
                    eta,
                    k,
                    specular_reflectance: p.rgb("specular_reflectance", Rgb::ONE)?,
                }
            }
            "dielectric" => Bsdf::Dielectric {
                eta: dielectric_eta(&p)?,
                specular_reflectance: p.rgb("specular_reflectance", Rgb::ONE)?,
                specular_transmittance: p.rgb("specular_transmittance", Rgb::ONE)?,
            },
            "roughdielectric" => Bsdf::RoughDielectric {
                alpha: alpha(&p)?,
                eta: dielectric_eta(&p)?,
                specular_reflectance: p.rgb("specular_reflectance", Rgb::ONE)?,
                specular_transmittance: p.rgb("specular_transmittance", Rgb::ONE)?,
            },
            _ => {
                return unsupported(
                    el,
                    "diffuse, conductor, roughconductor, dielectric, roughdielectric, twosided",
                )
            }
        };
        p.finish()?;
        Ok(Material::new(bsdf))
    }

    fn shape(&mut self, el: &Element) -> LoadResult<()> {
        let geometry = self.geometry(el)?;
        let (material, emission) = self.shape_children(el)?;
        let material = match material {
            Some(m) => m,
            None => {
                // Mitsuba's default BSDF: diffuse with reflectance 0.5.
                self.materials.push(Material::new(Bsdf::Diffuse {
                    reflectance: Rgb::splat(0.5),
                }));
                self.materials.len() - 1
            }
        };
        self.shapes.push(Shape {
            geometry,
            material,
            emission,
        });
        Ok(())
    }

    /// A shape's geometry: its `type` with its properties, transformed to world space, its
    /// normals flipped when asked.
    fn geometry(&self, el: &Element) -> LoadResult<Geometry> {
        let kind = el.required("type")?;
        let p = Props::new(el)?;
        let to_world = p.transform("to_world")?;
        let flip = p.boolean("flip_normals", false)?;
        let geometry = match kind {
            "rectangle" => Geometry::Mesh(TriangleMesh::rectangle(&to_world)),
            "cube" => Geometry::Mesh(TriangleMesh::cube(&to_world)),
            "obj" => {
                let file = p.string("filename")?.ok_or_else(|| {
                    LoadError::Xml(XmlError {
                        line: el.line,
                        message: "<shape type=\"obj\"> needs <string name=\"filename\">".into(),
                    })
                })?;
                let face_normals = p.boolean("face_normals", false)?;
                p.ignore(&["flip_tex_coords"]);
                let path = self.base_dir.join(file);
                let mesh = TriangleMesh::load_obj(&path, &to_world, face_normals).map_err(|e| {
                    LoadError::Xml(XmlError {
                        line: el.line,
                        message: e.to_string(),
                    })
                })?;
                Geometry::Mesh(mesh)
            }
            "sphere" => {
                let center = p.point("center", Vec3::ZERO)?;
                let radius = p.float("radius", 1.0)?;
                let m3 = Mat3::from_mat4(to_world);
                let scale = m3.x_axis.length();
                if (m3.y_axis.length() - scale).abs() > 1e-4 * scale
                    || (m3.z_axis.length() - scale).abs() > 1e-4 * scale
                {
                    return Err(
                        err::<()>(el.line, "a sphere's to_world must scale uniformly")
                            .unwrap_err()
                            .into(),
                    );
                }
                Geometry::Sphere(Sphere {
                    center: to_world.transform_point3(center),
                    radius: radius * scale,
                    inward: false,
                })
            }
            _ => return unsupported(el, "obj, rectangle, cube, sphere"),
        };
        p.finish()?;
        let geometry = match geometry {
            Geometry::Mesh(mut m) if flip => {
                m.flip();
                Geometry::Mesh(m)
            }
            Geometry::Sphere(mut s) if flip => {
                s.inward = true;
                Geometry::Sphere(s)
            }
            g => g,
        };
        Ok(geometry)
    }

    /// A shape's material (its own `<bsdf>`, or a `<ref>` to one defined before; `None`: the
    /// default) and the radiance of its area `<emitter>`, if any.
    fn shape_children(&mut self, el: &Element) -> LoadResult<(Option<usize>, Option<Rgb>)> {
        let mut material = None;
        let mut emission = None;
        for c in el
            .children
            .iter()
            .filter(|c| !PROPERTY_TAGS.contains(&c.name.as_str()))
        {
            match c.name.as_str() {
                "bsdf" | "ref" if material.is_some() => {
                    return Err(err::<()>(c.line, "a shape can have only one bsdf")
                        .unwrap_err()
                        .into())
                }
                "bsdf" => {
                    let m = self.bsdf(c)?;
                    self.materials.push(m);
                    material = Some(self.materials.len() - 1);
                }
                "ref" => {
                    let id = c.required("id")?;
                    let Some(&i) = self.bsdf_ids.get(id) else {
                        return Err(err::<()>(
                            c.line,
                            format!("no bsdf with id '{id}' is defined before this point"),
                        )
                        .unwrap_err()
                        .into());
                    };
                    material = Some(i);
                }
                "emitter" => {
                    if c.required("type")? != "area" {
                        return unsupported(c, "area (inside a shape)");
                    }
                    let e = Props::new(c)?;
                    emission = Some(e.rgb("radiance", Rgb::ONE)?);
                    e.finish()?;
                }
                _ => return unsupported(c, "bsdf, ref, emitter inside a shape"),
            }
        }
        Ok((material, emission))
    }
}

#[cfg(test)]
mod tests;
