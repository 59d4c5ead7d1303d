//! A loader for Mitsuba 3's XML scene format, and for Mitsuba 0.x files by their own names.
//!
//! Values mean what they mean in Mitsuba 3 (its plugin documentation is the reference): `rgb`
//! values are linear, spectra convert to RGB as in its RGB variants, `fov_axis` defaults to `x`,
//! the film's filter to a Gaussian, the film's resolution and the sampler's sample count are
//! defaults that the caller may override. A Mitsuba 0.x file (`version` below 2) is upgraded
//! first (`upgrade.rs`). What the renderer leaves out (participating media, say) is an error
//! that names the element and its line, before anything renders, so a scene never renders
//! differently in silence; what it reads differently is a warning ([`Scene::warnings`]): an
//! integrator plugin other than `path` (a guiding paper's, `volpath`) is read as `path`,
//! `direct` as `path` with `max_depth = 2`.
//!
//! One file per kind of element: `sensor.rs` (camera, film, filter, sampler), `bsdf.rs`,
//! `emitter.rs` (the scene's own emitters, `sunsky.rs` for the sun and sky; area emitters are
//! read with their shape),
//! `texture.rs`, `shape.rs`; `include.rs` splices `<include>`d files in first.

mod bsdf;
mod dom;
mod emitter;
mod include;
mod principled;
mod props;
mod sensor;
mod shape;
mod sunsky;
mod texture;
mod upgrade;

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use crate::bsdf::Material;
use crate::camera::Camera;
use crate::geometry::Rgb;
use crate::light::{DeltaLight, EnvironmentLight};
use crate::scene::{RenderSettings, Scene};
use crate::shape::Shape;
use crate::texture::{Bitmap, Texture};
use crate::Error;
use dom::{Element, XmlError};
use props::Props;

/// How a scene is loaded, beyond what its file says.
#[derive(Default)]
pub struct LoadOptions<'a> {
    /// Leave out, with a warning, the shapes whose mesh files are missing (instead of failing).
    pub drop_missing_meshes: bool,
    /// Called after each shape is read with the shapes read so far and their number.
    pub progress: Option<&'a dyn Fn(usize, usize)>,
}

/// Load a Mitsuba 3 XML scene file; `params` override its `<default>`s (`$name` values).
pub fn load_scene(path: &Path, params: &[(String, String)]) -> Result<Scene, Error> {
    load_scene_with(path, params, &LoadOptions::default())
}

/// [`load_scene`] with [`LoadOptions`].
pub fn load_scene_with(
    path: &Path,
    params: &[(String, String)],
    options: &LoadOptions,
) -> Result<Scene, Error> {
    let text = std::fs::read_to_string(path).map_err(|source| Error::Io {
        path: path.display().to_string(),
        source,
    })?;
    let base = path.parent().map(Path::to_path_buf).unwrap_or_default();
    load(&text, &base, &path.display().to_string(), params, options)
}

/// Load a scene from XML text; relative mesh paths are resolved against `base_dir`, and
/// errors name `source` as the file.
pub fn load_scene_str(
    text: &str,
    base_dir: &Path,
    source: &str,
    params: &[(String, String)],
) -> Result<Scene, Error> {
    load(text, base_dir, source, params, &LoadOptions::default())
}

fn load(
    text: &str,
    base_dir: &Path,
    source: &str,
    params: &[(String, String)],
    options: &LoadOptions,
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
    let legacy = upgrade::is_legacy(&root).map_err(to_error)?;
    let mut upgrade_warnings = Vec::new();
    if legacy {
        upgrade::upgrade(&mut root, &mut upgrade_warnings).map_err(to_error)?;
    }
    let mut search_paths = Vec::new();
    include::expand(
        &mut root,
        base_dir,
        base_dir,
        &mut search_paths,
        &mut upgrade_warnings,
        0,
    )
    .map_err(to_error)?;
    include::inline_references(&mut root);
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
        search_paths,
        options: LoaderOptions {
            drop_missing_meshes: options.drop_missing_meshes,
        },
        warnings: upgrade_warnings,
        ..Default::default()
    };
    let mut scene = loader.scene(&root, options.progress).map_err(|e| match e {
        LoadError::Xml(x) => to_error(x),
        LoadError::Other(e) => e,
    })?;
    scene.warnings = loader
        .warnings
        .iter()
        .map(|(line, m)| format!("{source}:{line}: {m}"))
        .collect();
    Ok(scene)
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

/// A reader's error `message` at `line`, as a [`LoadResult`].
fn fail<T>(line: usize, message: impl Into<String>) -> LoadResult<T> {
    Err(dom::error_at(line, message).into())
}

/// The [`LoadOptions`] the reader of each element sees.
#[derive(Default)]
struct LoaderOptions {
    drop_missing_meshes: bool,
}

#[derive(Default)]
struct Loader {
    base_dir: PathBuf,
    /// Folders named by `<path>`, where relative file names are also looked for.
    search_paths: Vec<PathBuf>,
    options: LoaderOptions,
    materials: Vec<Material>,
    bsdf_ids: HashMap<String, usize>,
    shapes: Vec<Shape>,
    /// The shapes of each `shapegroup`, with their lines, by id.
    shape_groups: HashMap<String, Vec<(usize, Shape)>>,
    environment: Option<Rgb>,
    camera: Option<Camera>,
    settings: RenderSettings,
    delta: Vec<DeltaLight>,
    environment_map: Option<EnvironmentLight>,
    /// Textures defined at the top with an `id`.
    textures: HashMap<String, Arc<Texture>>,
    /// Images read so far.
    bitmaps: HashMap<texture::BitmapKey, Arc<Bitmap>>,
    /// What was read differently from Mitsuba 3, with its line.
    warnings: Vec<(usize, String)>,
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
    fail(
        el.line,
        format!("unsupported element {what} (supported: {supported})"),
    )
}

impl Loader {
    /// A file the scene names: relative to the scene's folder or to a `<path>`.
    fn resolve(&self, name: &str) -> PathBuf {
        include::resolve(&self.base_dir, &self.search_paths, name)
    }

    fn scene(
        &mut self,
        root: &Element,
        progress: Option<&dyn Fn(usize, usize)>,
    ) -> LoadResult<Scene> {
        let total = root.children.iter().filter(|c| c.name == "shape").count();
        let mut done = 0;
        for c in &root.children {
            match c.name.as_str() {
                "default" => {}
                "integrator" => self.integrator(c)?,
                "sensor" => self.sensor(c)?,
                "bsdf" => {
                    let m = self.bsdf(c)?;
                    // One without an id can never be used (Mitsuba 0.x scenes have such, with
                    // the id on a BSDF nested in it).
                    if let Some(id) = c.attr("id") {
                        self.materials.push(m);
                        self.bsdf_ids
                            .insert(id.to_string(), self.materials.len() - 1);
                    }
                }
                "shape" => {
                    self.shape(c)?;
                    done += 1;
                    if let Some(report) = progress {
                        report(done, total);
                    }
                }
                "emitter" => self.emitter(c)?,
                "texture" => {
                    let id = c.required("id")?.to_string();
                    let t = self.texture(c)?;
                    self.textures.insert(id, t);
                }
                _ => {
                    return unsupported(
                        c,
                        "default, integrator, sensor, bsdf, texture, shape, emitter",
                    )
                }
            }
        }
        let Some(camera) = self.camera.take() else {
            return fail(root.line, "the scene has no <sensor>");
        };
        let mut scene = Scene::new(
            camera,
            self.settings.clone(),
            std::mem::take(&mut self.materials),
            std::mem::take(&mut self.shapes),
            self.environment,
        )
        .map_err(LoadError::Other)?;
        if let Some(map) = self.environment_map.take() {
            scene.lights.set_environment_light(map);
        }
        if !self.delta.is_empty() {
            scene.lights.set_delta(std::mem::take(&mut self.delta));
        }
        Ok(scene)
    }

    /// The `<integrator>`: `path` and its parameters; any other plugin is read as `path` with
    /// a warning (`direct` with `max_depth = 2`, the light it sees directly and once
    /// reflected), and a wrapper (`aov`, `moment`, …) by the integrator it nests.
    fn integrator(&mut self, el: &Element) -> LoadResult<()> {
        let kind = el.required("type")?;
        let nested: Vec<&Element> = el
            .children
            .iter()
            .filter(|c| c.name == "integrator")
            .collect();
        if let [inner] = nested.as_slice() {
            self.warnings.push((
                el.line,
                format!("integrator '{kind}' is read as the integrator it wraps"),
            ));
            return self.integrator(inner);
        }
        let p = Props::new(el)?;
        let (default_depth, note) = match kind {
            "path" => (-1, None),
            "direct" => (2, Some("read as 'path' with max_depth = 2")),
            "volpath" | "volpathmis" => (-1, Some("read as 'path' (the scene has no media)")),
            _ => (-1, Some("read as 'path'")),
        };
        if let Some(note) = note {
            self.warnings
                .push((el.line, format!("integrator '{kind}' {note}")));
        }
        let max_depth = p.int("max_depth", default_depth)?;
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
        if kind == "path" {
            p.finish()?;
        } else {
            // Another renderer's settings (a guide's budget, light samples) do not change the
            // image that `path` converges to.
            let others: Vec<&str> = p.by_name.keys().copied().collect();
            p.ignore(&others);
        }
        Ok(())
    }
}

#[cfg(test)]
mod emitter_tests;
#[cfg(test)]
mod rough_tests;
#[cfg(test)]
mod shape_tests;
#[cfg(test)]
mod sunsky_tests;
#[cfg(test)]
mod tests;
