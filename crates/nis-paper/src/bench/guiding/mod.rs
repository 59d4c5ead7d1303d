//! `nis bench guiding`: every path-guiding method against a high-sample reference, at equal
//! samples per pixel and at equal time, as in the paper's Figure 5: MAPE, relMSE and the share
//! of fireflies over several seeds, montages of central crops with error maps, a table in
//! `docs/results/guiding.md`.
//!
//! Scenes are built-in names or scene files (the guiding literature's scenes, read as
//! published). The reference is a Mitsuba 3 render when one is cached beside the renders
//! (`scripts/scenes/guiding-references.py` writes it), else our own path tracing at high spp.
//!
//! Equal time is one wall-clock budget `T` per scene and seed for every method: the time
//! unguided path tracing takes for [`Settings::equal_time_spp`] samples per pixel (or
//! `--seconds`). Each method also renders at `T/2`, `T/4`, …, so its error-vs-time curve (MAPE
//! against the wall seconds it took, a PNG plot) shows where one method overtakes another, and
//! the table gives the time each method needs to reach one MAPE (interpolated on its curve).

mod table;

use std::path::{Path, PathBuf};

use nis_render::compare::{compare, ImageErrors};
use nis_render::film::Image;
use nis_render::guiding::factory::GuideSpec;
use nis_render::path_tracer::{PathTracer, Strategy};
use nis_render::render::{Budget, RenderOptions, RenderOutput, Schedule};
use nis_render::scene::Scene;
use nis_render::xml::LoadOptions;

use crate::error::{Error, Result};
use crate::image::figure::{error_time, png_bytes};
use crate::report::{self, create_dir};

/// Salt of the reference renders' seed: the reference must not share its random streams with
/// the renders it judges (equal streams would correlate their errors).
pub const REFERENCE_SEED_SALT: u64 = 0x0005_eed0_f4ef;

/// Settings of the comparison.
#[derive(Clone, Debug)]
pub struct Settings {
    /// Built-in scene names or scene files to render (empty: every built-in scene).
    pub scenes: Vec<String>,
    /// Samples per pixel of every method at equal samples (training included).
    pub spp: u32,
    /// Longer side of the image in pixels (a scene file keeps its film's aspect ratio).
    pub res: u32,
    /// Samples per pixel of the cached path-traced reference.
    pub reference_spp: u32,
    /// Seconds per method at equal time (default: what unguided path tracing takes for
    /// `equal_time_spp` samples per pixel).
    pub seconds: Option<f64>,
    /// Samples per pixel of unguided path tracing whose wall time is the equal-time budget.
    pub equal_time_spp: u32,
    /// Budgets on each method's error-vs-time curve: the equal-time budget and its halvings.
    pub curve_points: u32,
    /// The MAPE whose reach time the table gives (default: path tracing's at the equal-time
    /// budget, or the best method's when path tracing is not among the methods).
    pub target_mape: Option<f64>,
    /// Methods by [`GuideSpec`] name (empty: all).
    pub methods: Vec<String>,
    /// Seed of the first run (the reference salts it with [`REFERENCE_SEED_SALT`]).
    pub seed: u64,
    /// Runs per scene and method, with seeds `seed`, `seed + 1`, ….
    pub seeds: u32,
    /// Leave out the shapes of a scene file whose meshes are missing (a public snapshot that
    /// lacks some), as the Mitsuba reference script does.
    pub drop_missing_meshes: bool,
    /// Folder for renders, error maps and cached references.
    pub out: PathBuf,
    /// Markdown file the table goes to (section "guiding", or "guiding-scenes" with scene files).
    pub docs: PathBuf,
    /// Folder for the montages linked from `docs`.
    pub img: PathBuf,
}

/// Renders one scene with one guide, labelled for a progress display.
pub type Render<'a> =
    dyn FnMut(&Scene, &RenderOptions, &GuideSpec, &str) -> Result<RenderOutput> + 'a;

/// What the driver asks of its caller: rendering (with progress) and a line logger.
pub struct Io<'a> {
    pub render: &'a mut Render<'a>,
    pub log: &'a mut dyn FnMut(&str),
}

/// One method's result in one comparison.
struct Run {
    method: String,
    errors: ImageErrors,
    output: RenderOutput,
}

/// One seed's renders of one scene.
struct SeedRuns {
    /// Every method at equal samples per pixel.
    equal_spp: Vec<Run>,
    /// The equal-time budget in seconds.
    seconds: f64,
    /// Every method at the equal-time budget.
    equal_time: Vec<Run>,
    /// Every method's error-vs-time curve.
    curves: Vec<Curve>,
}

/// Most budgets on an error-vs-time curve.
pub const MAX_CURVE_POINTS: u32 = 12;

/// When an error-vs-time curve reaches a MAPE.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Reach {
    /// Already at its first point, which took these seconds.
    By(f64),
    /// After these seconds, interpolated between the two points around the crossing as a power
    /// law (a straight line on log-log axes, as error falls like a power of time).
    At(f64),
    /// Not within the curve, whose last point took these seconds.
    After(f64),
}

impl std::fmt::Display for Reach {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Reach::By(t) => write!(f, "≤ {t:.2}"),
            Reach::At(t) => write!(f, "{t:.2}"),
            Reach::After(t) => write!(f, "> {t:.2}"),
        }
    }
}

/// When the curve of (seconds, MAPE) points reaches `target`: the first crossing from above
/// in order of time. `None` for an empty curve.
pub fn time_to_reach(curve: &[(f64, f64)], target: f64) -> Option<Reach> {
    let mut points = curve.to_vec();
    points.sort_by(|a, b| a.0.total_cmp(&b.0));
    let &(t0, m0) = points.first()?;
    if m0 <= target {
        return Some(Reach::By(t0));
    }
    for w in points.windows(2) {
        let ((ta, ma), (tb, mb)) = (w[0], w[1]);
        if mb <= target {
            let f = if ma > mb && mb > 0.0 && target > 0.0 {
                (ma / target).ln() / (ma / mb).ln()
            } else {
                1.0
            };
            return Some(Reach::At(ta * (tb / ta).powf(f)));
        }
    }
    Some(Reach::After(points.last().expect("not empty").0))
}

/// The image size whose longer side is `res`, at the film's aspect ratio (rounded half up,
/// as `scripts/scenes/guiding-references.py` does).
pub fn fit_resolution(width: u32, height: u32, res: u32) -> (u32, u32) {
    let scaled =
        |a: u32, b: u32| ((f64::from(a) * f64::from(res) / f64::from(b)).round() as u32).max(1);
    if width >= height {
        (res, scaled(height, width))
    } else {
        (scaled(width, height), res)
    }
}

/// A scene file's name in the tables: its file name without extension, or its folder's name
/// for a file called `scene.xml` (the layout of Bitterli's scenes).
pub fn scene_name(path: &Path) -> String {
    let stem = path.file_stem().map(|s| s.to_string_lossy().into_owned());
    match stem.as_deref() {
        Some("scene") | None => path
            .parent()
            .and_then(Path::file_name)
            .map_or_else(|| "scene".into(), |s| s.to_string_lossy().into_owned()),
        Some(s) => s.to_string(),
    }
}

/// A scene of the comparison: its name, the scene at the bench's resolution, and whether it is
/// a built-in one (not a file).
fn load(entry: &str, args: &Settings) -> Result<(String, Scene, bool)> {
    let path = Path::new(entry);
    if path.is_file() {
        let options = LoadOptions {
            drop_missing_meshes: args.drop_missing_meshes,
            progress: None,
        };
        let mut scene = nis_render::xml::load_scene_with(path, &[], &options)?;
        let (w, h) = fit_resolution(scene.camera.width(), scene.camera.height(), args.res);
        scene.camera.set_resolution(w, h);
        Ok((scene_name(path), scene, false))
    } else {
        let params = [("res".to_string(), args.res.to_string())];
        Ok((
            entry.to_string(),
            nis_render::scenes::load_with(entry, &params)?,
            true,
        ))
    }
}

/// The reference of `name` and where it comes from: for a scene file, a cached Mitsuba 3 render
/// if there is one (`scripts/scenes/guiding-references.py`), else our cached path-traced one,
/// rendered when missing. A built-in scene's are cached apart (`reference/built-in/`): a
/// built-in and a published scene may share a name (`cornell-box`), never a reference.
fn reference(
    name: &str,
    scene: &Scene,
    built_in: bool,
    path_tracer: &PathTracer,
    args: &Settings,
    io: &mut Io<'_>,
) -> Result<(Image, String)> {
    let mut dir = args.out.join("reference");
    if built_in {
        dir = dir.join("built-in");
    }
    let stem = format!("{name}-{}-{}spp", args.res, args.reference_spp);
    let size = (scene.camera.width(), scene.camera.height());
    let (path, ours) = (
        dir.join(format!("{stem}.exr")),
        format!("nis path tracing, {} spp", args.reference_spp),
    );
    let mut cached = vec![(path.clone(), ours.clone())];
    if !built_in {
        cached.insert(
            0,
            (
                dir.join(format!("{stem}-mitsuba.exr")),
                format!("Mitsuba 3, {} spp", args.reference_spp),
            ),
        );
    }
    for (path, source) in cached {
        if path.is_file() {
            let image = Image::read_exr(&path)?;
            if (image.width, image.height) != size {
                return Err(Error::Config(format!(
                    "the reference {} is {}×{}, the renders {}×{}",
                    path.display(),
                    image.width,
                    image.height,
                    size.0,
                    size.1
                )));
            }
            (io.log)(&format!("{name}: reference {} ({source})", path.display()));
            return Ok((image, source));
        }
    }
    let options = RenderOptions {
        path_tracer: *path_tracer,
        budget: Budget::Samples(args.reference_spp),
        seed: args.seed ^ REFERENCE_SEED_SALT,
        schedule: Schedule::Plain,
    };
    let label = format!("{name}: reference, {} spp", args.reference_spp);
    let out = (io.render)(scene, &options, &GuideSpec::None, &label)?;
    create_dir(&dir)?;
    out.image.write(&path)?;
    (io.log)(&format!(
        "{name}: reference in {:.1} s -> {}",
        out.seconds,
        path.display()
    ));
    Ok((out.image, ours))
}

/// Runs the comparison: `io.render` renders one scene with one guide (the caller shows its
/// progress), `io.log` sees a line per render. Writes renders and references into `args.out`,
/// montages into `args.img` and the section "guiding" of `args.docs` ("guiding-scenes" when
/// a scene is a file); returns its Markdown.
pub fn run(args: &Settings, io: &mut Io<'_>) -> Result<String> {
    check(args)?;
    let entries: Vec<String> = if args.scenes.is_empty() {
        nis_render::scenes::names().map(String::from).collect()
    } else {
        args.scenes.clone()
    };
    let methods: Vec<String> = if args.methods.is_empty() {
        GuideSpec::NAMES.iter().map(|s| s.to_string()).collect()
    } else {
        args.methods.clone()
    };
    for m in &methods {
        GuideSpec::parse(m, None, args.seed)?;
    }
    create_dir(&args.out)?;
    create_dir(&args.img)?;
    // Published scenes get a section (and figure names) of their own beside the built-in ones.
    let (key, title) = if entries.iter().any(|e| Path::new(e).is_file()) {
        (
            "guiding-scenes",
            "Path guiding on published scenes: the table",
        )
    } else {
        ("guiding", "Path guiding")
    };
    let mut results = Vec::new();
    for entry in &entries {
        let (name, scene, built_in) = load(entry, args)?;
        if results.iter().any(|r: &table::SceneResult| r.name == name) {
            return Err(Error::Config(format!(
                "two scenes are called '{name}': their references would collide"
            )));
        }
        for w in &scene.warnings {
            (io.log)(&format!("{name}: {w}"));
        }
        let path_tracer = PathTracer::from_scene(&scene, Strategy::Mis);
        let (reference, source) = reference(&name, &scene, built_in, &path_tracer, args, io)?;
        let mut seeds = Vec::new();
        for k in 0..u64::from(args.seeds) {
            let bench = SceneBench {
                name: &name,
                scene: &scene,
                reference: &reference,
                path_tracer,
                args,
                seed: args.seed + k,
            };
            let specs = methods
                .iter()
                .map(|m| Ok((m.clone(), GuideSpec::parse(m, None, bench.seed)?)))
                .collect::<Result<Vec<_>>>()?;
            let equal_spp = bench.equal_samples(&specs, io)?;
            let (seconds, equal_time, curves) = bench.equal_time(&specs, io)?;
            seeds.push(SeedRuns {
                equal_spp,
                seconds,
                equal_time,
                curves,
            });
        }
        let file = format!("{key}-{name}.png");
        table::montage(&reference, &seeds[0].equal_spp)?.write(&args.img.join(&file))?;
        results.push(table::SceneResult {
            name,
            size: (scene.camera.width(), scene.camera.height()),
            reference: source,
            montage: file,
            seeds,
        });
    }
    let plot = format!("{key}-error-time.png");
    let panels: Vec<_> = results.iter().map(table::SceneResult::panel).collect();
    let figure = error_time("MAPE against wall-clock time", &panels)?;
    report::write_file(&args.img.join(&plot), &png_bytes(&figure)?)?;
    let body = table::section(args, &methods, &results, &plot);
    report::write_section(&args.docs, key, title, &body)?;
    Ok(body)
}

/// An error for settings that cannot make a comparison.
fn check(args: &Settings) -> Result<()> {
    if args.spp == 0
        || args.res == 0
        || args.reference_spp == 0
        || args.equal_time_spp == 0
        || args.seeds == 0
    {
        return Err(Error::Config(
            "samples per pixel, resolution, reference and equal-time samples and seeds must be \
             positive"
                .into(),
        ));
    }
    if !(1..=MAX_CURVE_POINTS).contains(&args.curve_points) {
        return Err(Error::Config(format!(
            "an error-vs-time curve needs 1..={MAX_CURVE_POINTS} points, got {}",
            args.curve_points
        )));
    }
    if let Some(s) = args.seconds.filter(|s| !(s.is_finite() && *s > 0.0)) {
        return Err(Error::Config(format!(
            "the equal-time budget must be positive seconds, got {s}"
        )));
    }
    if let Some(m) = args.target_mape.filter(|m| !(m.is_finite() && *m > 0.0)) {
        return Err(Error::Config(format!(
            "the target MAPE must be positive, got {m}"
        )));
    }
    Ok(())
}

/// One scene's renders with one seed: its reference and the renders' settings.
struct SceneBench<'a> {
    name: &'a str,
    scene: &'a Scene,
    reference: &'a Image,
    path_tracer: PathTracer,
    args: &'a Settings,
    seed: u64,
}

/// An error-vs-time curve: a method and its (seconds, MAPE) points.
type Curve = (String, Vec<(f64, f64)>);

impl SceneBench<'_> {
    fn options(&self, budget: Budget) -> RenderOptions {
        RenderOptions {
            path_tracer: self.path_tracer,
            budget,
            seed: self.seed,
            schedule: Schedule::Plain,
        }
    }

    fn log(
        &self,
        io: &mut Io<'_>,
        method: &str,
        output: &RenderOutput,
        errors: &ImageErrors,
        tail: &str,
    ) {
        (io.log)(&format!(
            "{:>16} {method:>8} seed {} {:>4} spp  MAPE {:.4}  relMSE {:.4}  far off {:.2}‰  {:.2} s{tail}",
            self.name,
            self.seed,
            output.spp,
            errors.mape,
            errors.relmse,
            1e3 * errors.far_off,
            output.seconds
        ));
    }

    /// Every method at the same samples per pixel; the renders are written to `args.out`.
    fn equal_samples(&self, methods: &[(String, GuideSpec)], io: &mut Io<'_>) -> Result<Vec<Run>> {
        let (name, args) = (self.name, self.args);
        let mut runs = Vec::new();
        for (method, spec) in methods {
            let label = format!("{name}: {method}, {} spp, seed {}", args.spp, self.seed);
            let options = self.options(Budget::Samples(args.spp));
            let output = (io.render)(self.scene, &options, spec, &label)?;
            let errors = compare(&output.image, self.reference)?;
            self.log(io, method, &output, &errors, "");
            output.image.write(&args.out.join(format!(
                "{name}-{method}-{}spp-seed{}.exr",
                args.spp, self.seed
            )))?;
            runs.push(Run {
                method: method.clone(),
                errors,
                output,
            });
        }
        Ok(runs)
    }

    /// Every method at the equal-time budget and its halvings: the budget in seconds, each
    /// method's render at the budget, and each method's error-vs-time curve.
    fn equal_time(
        &self,
        methods: &[(String, GuideSpec)],
        io: &mut Io<'_>,
    ) -> Result<(f64, Vec<Run>, Vec<Curve>)> {
        let (name, args) = (self.name, self.args);
        // The equal-time budget: path tracing's time for `equal_time_spp` (that render is
        // path tracing's point at the budget), unless given.
        let mut pt_at_budget = None;
        let seconds = match args.seconds {
            Some(s) => s,
            None => {
                let label = format!(
                    "{name}: none, {} spp (budget), seed {}",
                    args.equal_time_spp, self.seed
                );
                let options = self.options(Budget::Samples(args.equal_time_spp));
                let output = (io.render)(self.scene, &options, &GuideSpec::None, &label)?;
                let s = output.seconds;
                pt_at_budget = Some(output);
                s
            }
        };
        let budgets: Vec<f64> = (0..args.curve_points)
            .rev()
            .map(|k| seconds / f64::from(1u32 << k))
            .collect();
        let mut equal_time = Vec::new();
        let mut curves = Vec::new();
        for (method, spec) in methods {
            let mut curve = Vec::new();
            let mut last = None;
            for &budget in &budgets {
                let reuse = (budget == seconds && matches!(spec, GuideSpec::None))
                    .then(|| pt_at_budget.clone())
                    .flatten();
                let output = match reuse {
                    Some(o) => o,
                    None => {
                        let label = format!("{name}: {method}, {budget:.2} s, seed {}", self.seed);
                        let options = self.options(Budget::Seconds(budget));
                        (io.render)(self.scene, &options, spec, &label)?
                    }
                };
                let errors = compare(&output.image, self.reference)?;
                self.log(
                    io,
                    method,
                    &output,
                    &errors,
                    &format!(" (budget {budget:.2} s)"),
                );
                curve.push((output.seconds, errors.mape));
                last = Some((output, errors));
            }
            let (output, errors) = last.expect("at least one budget");
            curves.push((method.clone(), curve));
            equal_time.push(Run {
                method: method.clone(),
                errors,
                output,
            });
        }
        Ok((seconds, equal_time, curves))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_scene_file_keeps_its_aspect_and_is_named_by_its_folder_when_called_scene() {
        assert_eq!(fit_resolution(1280, 720, 128), (128, 72));
        assert_eq!(fit_resolution(1024, 768, 100), (100, 75));
        assert_eq!(fit_resolution(720, 1280, 64), (36, 64));
        assert_eq!(fit_resolution(512, 512, 96), (96, 96));
        // 3 × 128 / 1000 = 0.384: never an empty image.
        assert_eq!(fit_resolution(1000, 3, 128), (128, 1));
        assert_eq!(
            scene_name(Path::new("a/veach-bidir/scene.xml")),
            "veach-bidir"
        );
        assert_eq!(scene_name(Path::new("a/kitchen/kitchen.xml")), "kitchen");
    }

    #[test]
    fn time_to_reach_interpolates_a_power_law_between_the_crossing_points() {
        // MAPE = t^(-1/2): 0.5 at 4 s, 0.25 at 16 s; 0.3536 = 8^(-1/2) is reached at 8 s.
        let curve = [(16.0, 0.25), (1.0, 1.0), (4.0, 0.5)];
        match time_to_reach(&curve, 8f64.powf(-0.5)) {
            Some(Reach::At(t)) => assert!((t - 8.0).abs() < 1e-9, "{t}"),
            r => panic!("{r:?}"),
        }
        assert_eq!(time_to_reach(&curve, 1.5), Some(Reach::By(1.0)));
        assert_eq!(time_to_reach(&curve, 0.1), Some(Reach::After(16.0)));
        assert_eq!(time_to_reach(&[], 0.1), None);
        // A curve that rises again is judged by its first crossing.
        let bumpy = [(1.0, 1.0), (2.0, 0.5), (4.0, 0.8), (8.0, 0.4)];
        assert_eq!(time_to_reach(&bumpy, 0.5), Some(Reach::At(2.0)));
    }
}
