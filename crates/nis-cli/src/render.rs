//! `nis render` and `nis compare`: the command-line front end of `nis-render`.
//!
//! Only argument parsing, progress and printing live here; everything else is a library call.

use std::path::{Path, PathBuf};
use std::time::Duration;

use indicatif::{ProgressBar, ProgressStyle};
use nis::comm::Comm;
use nis_render::compare::{compare, error_map};
use nis_render::film::Image;
use nis_render::guiding::factory::GuideSpec;
use nis_render::path_tracer::{PathTracer, Strategy};
use nis_render::render::{render_any, Budget, RenderOptions, RenderOutput, Schedule};
use nis_render::scene::Scene;

/// Render a scene with the CPU path tracer.
#[derive(Debug, clap::Args)]
#[command(after_help = "\
Examples:
  nis render cornell-box --spp 256 --out out/cornell.exr --out out/cornell.png
  nis render my-scene.xml --seconds 30 --res 512 -D max_depth=8 --out render.exr
  nis render two-rooms-door --export-xml two-rooms-door.xml

Built-in scenes: cornell-box, cornell-indirect, two-rooms-door, cornell-glossy.")]
pub struct RenderArgs {
    /// A Mitsuba 3 XML scene file, or the name of a built-in scene.
    pub scene: String,

    /// Samples per pixel (default: the scene's sampler `sample_count`).
    #[arg(long, conflicts_with = "seconds")]
    pub spp: Option<u32>,

    /// Render for this many seconds instead of a fixed sample count.
    #[arg(long)]
    pub seconds: Option<f64>,

    /// Output image; `.exr` is linear 32-bit float, `.png` is clamped sRGB. Repeat for several.
    #[arg(long, short, default_value = "render.exr")]
    pub out: Vec<PathBuf>,

    /// Image width and height in pixels (default: the scene's film).
    #[arg(long)]
    pub res: Option<u32>,

    /// Image width (overrides --res).
    #[arg(long)]
    pub width: Option<u32>,

    /// Image height (overrides --res).
    #[arg(long)]
    pub height: Option<u32>,

    /// Longest path in segments, `-1` for unbounded (default: the scene's integrator).
    #[arg(long, allow_hyphen_values = true)]
    pub max_depth: Option<i32>,

    /// Light-transport estimator: `mis` (NEE + BSDF sampling), `nee` or `bsdf` only.
    #[arg(long, default_value = "mis", value_parser = ["mis", "nee", "bsdf"])]
    pub strategy: String,

    /// Path guiding: `none` (unidirectional path tracing), `ppg` (practical path guiding's
    /// SD-tree), `gmm` (Gaussian mixtures after Vorba et al.) or `nis-kl` / `nis-chi2` (a
    /// normalizing flow trained while rendering, with the KL or χ² gradient). Guided renders
    /// spend up to half of the samples on training passes of 1, 2, 4, … spp; the image
    /// combines every pass, weighted by its inverse variance. The neural guide serves a path's
    /// first four non-delta vertices (`guided_bounces`), the others every one; no guide serves a
    /// glossy lobe narrower than 22.5° (the neural guide's `narrowest_lobe_degrees`).
    #[arg(long, default_value = "none", value_parser = GUIDES)]
    pub guide: String,

    /// Settings of the neural guide as JSON, merged over the defaults, e.g.
    /// '{"hidden_width": 128, "learning_rate": 0.002}' (fields: see `NisGuideConfig`).
    #[arg(long, value_name = "JSON")]
    pub guide_config: Option<String>,

    /// Random seed; the same seed and sample count give the same image on any thread count.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,

    /// Worker threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,

    /// Set a scene parameter used as `$NAME` in the XML (overrides its `<default>`).
    #[arg(short = 'D', value_name = "NAME=VALUE")]
    pub define: Vec<String>,

    /// Leave out, with a warning, the shapes whose mesh files are missing (public snapshots of
    /// scenes sometimes lack their largest files) instead of stopping with an error.
    #[arg(long)]
    pub drop_missing_meshes: bool,

    /// Write the scene's Mitsuba XML to this file (for built-in scenes) and do not render.
    #[arg(long, value_name = "FILE")]
    pub export_xml: Option<PathBuf>,
}

/// Compare an image with a reference: MAPE, relMSE and a false-colour error map.
#[derive(Debug, clap::Args)]
#[command(after_help = "\
Example:
  nis compare out/cornell.exr reference/cornell.exr --error-map out/cornell-error.png")]
pub struct CompareArgs {
    /// The image to evaluate (OpenEXR).
    pub image: PathBuf,

    /// The reference image (OpenEXR), e.g. a high-sample render.
    pub reference: PathBuf,

    /// Where to write the false-colour map of per-pixel relative error (default:
    /// IMAGE with `-error.png` in place of `.exr`).
    #[arg(long)]
    pub error_map: Option<PathBuf>,

    /// Relative error shown at the top of the colour scale.
    #[arg(long, default_value_t = 1.0)]
    pub max_error: f32,
}

/// The `--guide` choices.
pub const GUIDES: [&str; 5] = GuideSpec::NAMES;

/// Render with the guide named `guide` and its `--guide-config` settings (see
/// [`GuideSpec::parse`]).
pub fn render_with(
    scene: &Scene,
    options: &RenderOptions,
    guide: &str,
    guide_config: Option<&str>,
    comm: &Comm,
    progress: &(dyn Fn(f64) + Sync),
) -> Result<RenderOutput, Box<dyn std::error::Error>> {
    let spec = GuideSpec::parse(guide, guide_config, options.seed)?;
    Ok(render_spec(scene, options, &spec, comm, progress)?)
}

/// Render with the guide `spec` describes: `none` is plain path tracing in one pass, every
/// other guide trains in passes of its own first ([`Schedule::Training`]), whatever
/// `options.schedule` says.
pub fn render_spec(
    scene: &Scene,
    options: &RenderOptions,
    spec: &GuideSpec,
    comm: &Comm,
    progress: &(dyn Fn(f64) + Sync),
) -> Result<RenderOutput, nis_render::Error> {
    let mut guide = spec.build(scene)?;
    let schedule = if guide.learns() {
        Schedule::Training
    } else {
        Schedule::Plain
    };
    let options = RenderOptions {
        schedule,
        ..*options
    };
    Ok(render_any(scene, &options, &mut guide, comm, progress))
}

/// Peak resident memory of this process in MiB (Linux's `VmHWM`), where the system says.
fn peak_memory_mib() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib / 1024.0)
}

/// The scene of `args`; with `show`, a progress bar over its shapes and a line on what loaded.
fn load(
    args: &RenderArgs,
    params: &[(String, String)],
    show: bool,
) -> Result<Scene, Box<dyn std::error::Error>> {
    if Path::new(&args.scene).is_file() {
        let started = std::time::Instant::now();
        let bar = if show {
            ProgressBar::new(0)
        } else {
            ProgressBar::hidden()
        };
        bar.set_style(ProgressStyle::with_template(
            "loading {msg} [{elapsed_precise}] {wide_bar} {pos}/{len} shapes",
        )?);
        bar.set_message(args.scene.clone());
        let report = |done: usize, total: usize| {
            bar.set_length(total as u64);
            bar.set_position(done as u64);
        };
        let options = nis_render::xml::LoadOptions {
            drop_missing_meshes: args.drop_missing_meshes,
            progress: Some(&report),
        };
        let scene = nis_render::xml::load_scene_with(Path::new(&args.scene), params, &options);
        bar.finish_and_clear();
        let scene = scene?;
        if show {
            let memory = peak_memory_mib()
                .map(|m| format!(", peak memory {m:.0} MiB"))
                .unwrap_or_default();
            eprintln!(
                "loaded {}: {} triangles, {} area-light triangles, {} materials in {:.2} s{memory}",
                args.scene,
                scene.triangle_count(),
                scene.lights.area.len(),
                scene.materials.len(),
                started.elapsed().as_secs_f64()
            );
        }
        Ok(scene)
    } else if nis_render::scenes::xml(&args.scene).is_some() {
        Ok(nis_render::scenes::load_with(&args.scene, params)?)
    } else {
        Err(format!(
            "'{}' is neither a scene file nor a built-in scene ({})",
            args.scene,
            nis_render::scenes::names().collect::<Vec<_>>().join(", ")
        )
        .into())
    }
}

/// Run `nis render` on every rank of `comm`; rank 0 prints and writes the image.
pub fn run_render(args: &RenderArgs, comm: &Comm) -> Result<(), Box<dyn std::error::Error>> {
    if let Some(path) = &args.export_xml {
        if !comm.is_root() {
            return Ok(());
        }
        let xml = nis_render::scenes::xml(&args.scene)
            .ok_or_else(|| format!("'{}' is not a built-in scene", args.scene))?;
        nis::io::write_atomic(path, xml.as_bytes())?;
        eprintln!("wrote {}", path.display());
        return Ok(());
    }
    let (scene, width, height) = scene_of(args, comm.is_root())?;
    if comm.is_root() {
        for w in &scene.warnings {
            eprintln!("warning: {w}");
        }
    }
    let strategy = match args.strategy.as_str() {
        "nee" => Strategy::Nee,
        "bsdf" => Strategy::Bsdf,
        _ => Strategy::Mis,
    };
    let path_tracer = PathTracer::from_scene(&scene, strategy);
    let budget = match (args.seconds, args.spp) {
        (Some(t), _) if t > 0.0 => Budget::Seconds(t),
        (Some(_), _) => return Err("--seconds must be positive".into()),
        (None, Some(0)) => return Err("--spp must be at least 1".into()),
        (None, spp) => Budget::Samples(spp.unwrap_or(scene.settings.spp)),
    };
    let bar = if comm.is_root() {
        ProgressBar::new(1000)
    } else {
        ProgressBar::hidden()
    };
    bar.set_style(ProgressStyle::with_template(
        "{spinner} [{elapsed_precise}] {wide_bar} {percent}% (eta {eta})",
    )?);
    bar.enable_steady_tick(Duration::from_millis(250));
    let progress = |f: f64| bar.set_position((f * 1000.0) as u64);
    let run = || {
        let options = RenderOptions {
            path_tracer,
            budget,
            seed: args.seed,
            schedule: Schedule::Plain,
        };
        render_with(
            &scene,
            &options,
            &args.guide,
            args.guide_config.as_deref(),
            comm,
            &progress,
        )
        .map_err(|e| e.to_string())
    };
    let out = match args.threads {
        Some(n) => rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()?
            .install(run)?,
        None => run()?,
    };
    bar.finish_and_clear();
    if !comm.is_root() {
        return Ok(());
    }
    report(args, &out, width, height)
}

/// The scene `args` name, with its `-D` parameters, resolution and depth applied: the scene and
/// the image's width and height.
fn scene_of(
    args: &RenderArgs,
    show: bool,
) -> Result<(Scene, u32, u32), Box<dyn std::error::Error>> {
    let params = args
        .define
        .iter()
        .map(|d| {
            d.split_once('=')
                .map(|(k, v)| (k.to_string(), v.to_string()))
                .ok_or_else(|| format!("-D expects NAME=VALUE, got '{d}'"))
        })
        .collect::<Result<Vec<_>, _>>()?;
    let mut scene = load(args, &params, show)?;
    let width = args.width.or(args.res).unwrap_or(scene.camera.width());
    let height = args.height.or(args.res).unwrap_or(scene.camera.height());
    if width == 0 || height == 0 {
        return Err("the image must have at least one pixel".into());
    }
    scene.camera.set_resolution(width, height);
    if let Some(d) = args.max_depth {
        scene.settings.max_depth = d;
    }
    Ok((scene, width, height))
}

/// Prints what the render `out` took and writes its image to every `--out`.
fn report(
    args: &RenderArgs,
    out: &RenderOutput,
    width: u32,
    height: u32,
) -> Result<(), Box<dyn std::error::Error>> {
    let rays = out.stats.rays + out.stats.shadow_rays;
    println!(
        "{}: {}x{}, {} spp in {:.2} s; {:.2} M rays/s, {:.2} M samples/s; mean radiance {:.6}",
        args.scene,
        width,
        height,
        out.spp,
        out.seconds,
        rays as f64 / out.seconds / 1e6,
        out.stats.paths as f64 / out.seconds / 1e6,
        out.image.mean()
    );
    if out.stats.invalid > 0 {
        eprintln!(
            "warning: {} NaN/infinite samples were dropped",
            out.stats.invalid
        );
    }
    for path in &args.out {
        if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
            std::fs::create_dir_all(dir)?;
        }
        out.image.write(path)?;
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}

/// Run `nis compare`.
pub fn run_compare(args: &CompareArgs) -> Result<(), Box<dyn std::error::Error>> {
    let image = Image::read_exr(&args.image)?;
    let reference = Image::read_exr(&args.reference)?;
    let e = compare(&image, &reference)?;
    println!("MAPE    {:.6}", e.mape);
    println!("relMSE  {:.6}", e.relmse);
    println!(
        "mean    {:.6} (reference {:.6}, ratio {:.5})",
        e.mean,
        e.reference_mean,
        e.mean / e.reference_mean
    );
    if args.max_error.is_nan() || args.max_error <= 0.0 {
        return Err("--max-error must be positive".into());
    }
    let map_path = args
        .error_map
        .clone()
        .unwrap_or_else(|| args.image.with_extension("").with_extension("error.png"));
    error_map(&image, &reference, args.max_error)?.write(&map_path)?;
    eprintln!(
        "wrote {} (relative error, 0 to {} in false colour)",
        map_path.display(),
        args.max_error
    );
    Ok(())
}
