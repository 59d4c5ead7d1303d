//! `nis bench guiding`: every path-guiding method against a high-sample path-traced reference,
//! at equal samples per pixel and at equal time, as in the paper's Figure 5: MAPE and relMSE,
//! montages of central crops with error maps, a table in `docs/REPRODUCTION.md`.

use std::path::PathBuf;

use nis_render::compare::{compare, error_map, ImageErrors};
use nis_render::film::Image;
use nis_render::geometry::Rgb;
use nis_render::guiding::spec::GuideSpec;
use nis_render::integrator::{Integrator, Strategy};
use nis_render::render::{Budget, RenderOptions, RenderOutput, Schedule};
use nis_render::scene::Scene;

use crate::error::{Error, Result};
use crate::report::{self, create_dir};

/// Salt of the reference renders' seed: the reference must not share its random streams with
/// the renders it judges (equal streams would correlate their errors).
pub const REFERENCE_SEED_SALT: u64 = 0x0005_eed0_f4ef;

/// Settings of the comparison.
#[derive(Clone, Debug)]
pub struct Settings {
    /// Built-in scenes to render (empty: all).
    pub scenes: Vec<String>,
    /// Samples per pixel of every method at equal samples (training included).
    pub spp: u32,
    /// Image side in pixels.
    pub res: u32,
    /// Samples per pixel of the cached path-traced reference.
    pub reference_spp: u32,
    /// Seconds per method at equal time (default: what nis-kl took at equal samples).
    pub seconds: Option<f64>,
    /// Methods by [`GuideSpec`] name (empty: all).
    pub methods: Vec<String>,
    /// Seed of the renders (the reference salts it with [`REFERENCE_SEED_SALT`]).
    pub seed: u64,
    /// Folder for renders, error maps and cached references.
    pub out: PathBuf,
    /// Markdown file the table goes to (section "guiding").
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

/// The cached reference of `name`, rendered when missing.
fn reference(
    name: &str,
    scene: &Scene,
    integrator: &Integrator,
    args: &Settings,
    io: &mut Io<'_>,
) -> Result<Image> {
    let path = args
        .out
        .join("reference")
        .join(format!("{name}-{}-{}spp.exr", args.res, args.reference_spp));
    if path.is_file() {
        (io.log)(&format!("{name}: reference {}", path.display()));
        return Ok(Image::read_exr(&path)?);
    }
    let options = RenderOptions {
        integrator: *integrator,
        budget: Budget::Samples(args.reference_spp),
        seed: args.seed ^ REFERENCE_SEED_SALT,
        schedule: Schedule::Plain,
    };
    let label = format!("{name}: reference, {} spp", args.reference_spp);
    let out = (io.render)(scene, &options, &GuideSpec::None, &label)?;
    create_dir(path.parent().expect("has a parent"))?;
    out.image.write(&path)?;
    (io.log)(&format!(
        "{name}: reference in {:.1} s -> {}",
        out.seconds,
        path.display()
    ));
    Ok(out.image)
}

/// Crops of the renders in a row over crops of their error maps in a row below, with the
/// reference at the left: the central quarter of the image (half its width and height), as
/// the paper's Figure 5 shows crops. The renders share one exposure that brings the
/// reference's mean to 0.25, so dark scenes show.
fn montage(reference: &Image, runs: &[Run]) -> Result<Image> {
    let (cw, ch) = (reference.width.div_ceil(2), reference.height.div_ceil(2));
    let (x0, y0) = ((reference.width - cw) / 2, (reference.height - ch) / 2);
    let exposure = if reference.mean() > 0.0 {
        (0.25 / reference.mean()) as f32
    } else {
        1.0
    };
    let cols = runs.len() as u32 + 1;
    let mut m = Image {
        width: cw * cols,
        height: 2 * ch,
        pixels: vec![Rgb::ZERO; (cw * cols * 2 * ch) as usize],
    };
    let mut put = |col: u32, row: u32, img: &Image, scale: f32| {
        for y in 0..ch {
            for x in 0..cw {
                m.pixels[((row * ch + y) * cw * cols + col * cw + x) as usize] =
                    img.get(x0 + x, y0 + y) * scale;
            }
        }
    };
    put(0, 0, reference, exposure);
    for (i, r) in runs.iter().enumerate() {
        put(i as u32 + 1, 0, &r.output.image, exposure);
        put(
            i as u32 + 1,
            1,
            &error_map(&r.output.image, reference, 1.0)?,
            1.0,
        );
    }
    Ok(m)
}

/// Runs the comparison: `io.render` renders one scene with one guide (the caller shows its
/// progress), `io.log` sees a line per render. Writes renders and references into `args.out`,
/// montages into `args.img` and the section "guiding" of `args.docs`; returns its Markdown.
pub fn run(args: &Settings, io: &mut Io<'_>) -> Result<String> {
    if args.spp == 0 || args.res == 0 || args.reference_spp == 0 {
        return Err(Error::Config(
            "samples per pixel, resolution and reference samples must be positive".into(),
        ));
    }
    let scenes: Vec<String> = if args.scenes.is_empty() {
        nis_render::scenes::names().map(String::from).collect()
    } else {
        args.scenes.clone()
    };
    let methods: Vec<String> = if args.methods.is_empty() {
        GuideSpec::NAMES.iter().map(|s| s.to_string()).collect()
    } else {
        args.methods.clone()
    };
    let specs = methods
        .iter()
        .map(|m| GuideSpec::parse(m, None, args.seed))
        .collect::<std::result::Result<Vec<_>, _>>()?;
    create_dir(&args.out)?;
    create_dir(&args.img)?;
    let mut table = String::from(
        "| scene | method | MAPE | relMSE | seconds | equal-time spp | MAPE | relMSE |\n|---|---|---|---|---|---|---|---|\n",
    );
    let mut figures = String::new();
    for name in &scenes {
        let params = [("res".to_string(), args.res.to_string())];
        let scene = nis_render::scenes::load_with(name, &params)?;
        let integrator = Integrator::from_scene(&scene, Strategy::Mis);
        let reference = reference(name, &scene, &integrator, args, io)?;
        let options = |budget| RenderOptions {
            integrator,
            budget,
            seed: args.seed,
            schedule: Schedule::Plain,
        };
        let mut equal_spp = Vec::new();
        for (method, spec) in methods.iter().zip(&specs) {
            let label = format!("{name}: {method}, {} spp", args.spp);
            let output = (io.render)(&scene, &options(Budget::Samples(args.spp)), spec, &label)?;
            let errors = compare(&output.image, &reference)?;
            (io.log)(&format!(
                "{name:>16} {method:>8} {:>4} spp  MAPE {:.4}  relMSE {:.4}  {:.2} s",
                output.spp, errors.mape, errors.relmse, output.seconds
            ));
            output.image.write(
                &args
                    .out
                    .join(format!("{name}-{method}-{}spp.exr", args.spp)),
            )?;
            equal_spp.push(Run {
                method: method.clone(),
                errors,
                output,
            });
        }
        let seconds = args.seconds.unwrap_or_else(|| {
            equal_spp.iter().find(|r| r.method == "nis-kl").map_or_else(
                || {
                    equal_spp
                        .iter()
                        .map(|r| r.output.seconds)
                        .fold(0.0, f64::max)
                },
                |r| r.output.seconds,
            )
        });
        let mut equal_time = Vec::new();
        for (method, spec) in methods.iter().zip(&specs) {
            let label = format!("{name}: {method}, {seconds:.1} s");
            let output = (io.render)(&scene, &options(Budget::Seconds(seconds)), spec, &label)?;
            let errors = compare(&output.image, &reference)?;
            (io.log)(&format!(
                "{name:>16} {method:>8} {:>4} spp  MAPE {:.4}  relMSE {:.4}  {:.2} s (equal time)",
                output.spp, errors.mape, errors.relmse, output.seconds
            ));
            equal_time.push(Run {
                method: method.clone(),
                errors,
                output,
            });
        }
        let best = |runs: &[Run], key: fn(&ImageErrors) -> f64| {
            runs.iter()
                .map(|r| key(&r.errors))
                .fold(f64::INFINITY, f64::min)
        };
        let bold = |v: f64, best: f64| {
            if v == best {
                format!("**{v:.4}**")
            } else {
                format!("{v:.4}")
            }
        };
        let (b1, b2) = (best(&equal_spp, |e| e.mape), best(&equal_spp, |e| e.relmse));
        let (b3, b4) = (
            best(&equal_time, |e| e.mape),
            best(&equal_time, |e| e.relmse),
        );
        for (a, t) in equal_spp.iter().zip(&equal_time) {
            table.push_str(&format!(
                "| {name} | {} | {} | {} | {:.1} | {} | {} | {} |\n",
                a.method,
                bold(a.errors.mape, b1),
                bold(a.errors.relmse, b2),
                a.output.seconds,
                t.output.spp,
                bold(t.errors.mape, b3),
                bold(t.errors.relmse, b4),
            ));
        }
        let file = format!("guiding-{name}.png");
        montage(&reference, &equal_spp)?.write(&args.img.join(&file))?;
        figures.push_str(&format!(
            "**{name}** (central crops: reference, then {} at equal spp, all at one exposure; their relative error maps below, 0 to 1 in false colour):\n\n![{name}]({}/{file})\n\n",
            methods.join(", "),
            report::relative_to(&args.docs, &args.img)
        ));
    }
    let body = format!(
        "Reproduce: `nis bench guiding --spp {spp} --res {res} --reference-spp {rspp}`. \
         Every method renders {res}×{res} pixels with {spp} samples per pixel in total \
         (guided methods spend up to half of them on training passes of 1, 2, 4, … spp, and \
         the passes are combined by inverse variance), then again for the same wall time \
         (the time NIS-KL took at equal samples, unless `--seconds` is given). Errors are \
         against a path-traced reference of {rspp} spp (other seed). MAPE and relMSE with \
         ε = 0.01; best per column in bold.\n\n{table}\n{figures}",
        spp = args.spp,
        res = args.res,
        rspp = args.reference_spp,
    );
    report::write_section(&args.docs, "guiding", "Path guiding", &body)?;
    Ok(body)
}
