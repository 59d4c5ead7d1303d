//! `nis bench guiding`: every path-guiding method against a high-sample reference, at equal
//! samples per pixel and at equal time, as in the paper's Figure 5 and Table 2.

use std::path::{Path, PathBuf};
use std::time::Duration;

use indicatif::{ProgressBar, ProgressStyle};
use nis_render::compare::{compare, error_map, ImageErrors};
use nis_render::film::Image;
use nis_render::geometry::Rgb;
use nis_render::integrator::{Integrator, Strategy};
use nis_render::render::{Budget, RenderOptions, RenderOutput, Schedule};
use nis_render::scene::Scene;

use crate::render::{render_with, GUIDES};

/// Compare the guiding methods on built-in scenes against a path-traced reference.
#[derive(Debug, clap::Args)]
#[command(after_help = "\
Example:
  nis bench guiding --scene two-rooms-door --spp 64 --res 128")]
pub struct BenchGuidingArgs {
    /// Built-in scenes to render (repeat; default: all four).
    #[arg(long)]
    pub scene: Vec<String>,

    /// Samples per pixel of every method in the equal-samples comparison (training included).
    #[arg(long, default_value_t = 64)]
    pub spp: u32,

    /// Image side in pixels.
    #[arg(long, default_value_t = 128)]
    pub res: u32,

    /// Samples per pixel of the path-traced reference (rendered once, cached in --out).
    #[arg(long, default_value_t = 4096)]
    pub reference_spp: u32,

    /// Seconds per method in the equal-time comparison (default: what nis-kl took at equal
    /// samples per pixel).
    #[arg(long)]
    pub seconds: Option<f64>,

    /// Methods (repeat; default: all).
    #[arg(long, value_parser = GUIDES)]
    pub method: Vec<String>,

    /// Random seed of the renders (the reference uses another).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,

    /// Folder for the renders, error maps and the cached references.
    #[arg(long, default_value = "out/guiding")]
    pub out: PathBuf,

    /// Markdown file the table goes to.
    #[arg(long, default_value = "docs/REPRODUCTION.md")]
    pub docs: PathBuf,

    /// Folder the montages go to (linked from --docs).
    #[arg(long, default_value = "docs/img")]
    pub img: PathBuf,
}

/// One method's result in one comparison.
struct Run {
    method: String,
    errors: ImageErrors,
    output: RenderOutput,
}

fn bar(message: String) -> Result<ProgressBar, Box<dyn std::error::Error>> {
    let bar = ProgressBar::new(1000);
    bar.set_style(ProgressStyle::with_template(
        "{msg:>36} [{elapsed_precise}] {wide_bar} {percent}%",
    )?);
    bar.set_message(message);
    bar.enable_steady_tick(Duration::from_millis(250));
    Ok(bar)
}

fn run_one(
    scene: &Scene,
    integrator: &Integrator,
    budget: Budget,
    seed: u64,
    method: &str,
    label: String,
) -> Result<RenderOutput, Box<dyn std::error::Error>> {
    let bar = bar(label)?;
    let options = RenderOptions {
        integrator: *integrator,
        budget,
        seed,
        schedule: Schedule::Plain,
    };
    let out = render_with(scene, &options, method, None, &|f| {
        bar.set_position((f * 1000.0) as u64)
    })?;
    bar.finish_and_clear();
    Ok(out)
}

/// The cached reference of `name`, rendered when missing.
fn reference(
    name: &str,
    scene: &Scene,
    integrator: &Integrator,
    args: &BenchGuidingArgs,
) -> Result<Image, Box<dyn std::error::Error>> {
    let path = args
        .out
        .join("reference")
        .join(format!("{name}-{}-{}spp.exr", args.res, args.reference_spp));
    if path.is_file() {
        eprintln!("{name}: reference {}", path.display());
        return Ok(Image::read_exr(&path)?);
    }
    let out = run_one(
        scene,
        integrator,
        Budget::Samples(args.reference_spp),
        args.seed ^ 0x0005_eed0_f4ef,
        "none",
        format!("{name}: reference, {} spp", args.reference_spp),
    )?;
    std::fs::create_dir_all(path.parent().expect("has a parent"))?;
    out.image.write(&path)?;
    eprintln!(
        "{name}: reference in {:.1} s -> {}",
        out.seconds,
        path.display()
    );
    Ok(out.image)
}

/// Crops of the renders in a row over crops of their error maps in a row below, with the
/// reference at the left: the central quarter of the image (half its width and height), as
/// the paper's Figure 5 shows crops. The renders share one exposure that brings the
/// reference's mean to 0.25, so dark scenes show.
fn montage(reference: &Image, runs: &[Run]) -> Result<Image, Box<dyn std::error::Error>> {
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

/// Run `nis bench guiding`.
pub fn run_bench(args: &BenchGuidingArgs) -> Result<(), Box<dyn std::error::Error>> {
    if args.spp == 0 || args.res == 0 || args.reference_spp == 0 {
        return Err("--spp, --res and --reference-spp must be positive".into());
    }
    let scenes: Vec<String> = if args.scene.is_empty() {
        nis_render::scenes::names().map(String::from).collect()
    } else {
        args.scene.clone()
    };
    let methods: Vec<String> = if args.method.is_empty() {
        GUIDES.iter().map(|s| s.to_string()).collect()
    } else {
        args.method.clone()
    };
    std::fs::create_dir_all(&args.out)?;
    std::fs::create_dir_all(&args.img)?;
    let mut table = String::from(
        "| scene | method | MAPE | relMSE | seconds | equal-time spp | MAPE | relMSE |\n|---|---|---|---|---|---|---|---|\n",
    );
    let mut figures = String::new();
    for name in &scenes {
        let params = [("res".to_string(), args.res.to_string())];
        let scene = nis_render::scenes::load_with(name, &params)?;
        let integrator = Integrator::from_scene(&scene, Strategy::Mis);
        let reference = reference(name, &scene, &integrator, args)?;
        let mut equal_spp = Vec::new();
        for method in &methods {
            let output = run_one(
                &scene,
                &integrator,
                Budget::Samples(args.spp),
                args.seed,
                method,
                format!("{name}: {method}, {} spp", args.spp),
            )?;
            let errors = compare(&output.image, &reference)?;
            println!(
                "{name:>16} {method:>8} {:>4} spp  MAPE {:.4}  relMSE {:.4}  {:.2} s",
                output.spp, errors.mape, errors.relmse, output.seconds
            );
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
        for method in &methods {
            let output = run_one(
                &scene,
                &integrator,
                Budget::Seconds(seconds),
                args.seed,
                method,
                format!("{name}: {method}, {seconds:.1} s"),
            )?;
            let errors = compare(&output.image, &reference)?;
            println!(
                "{name:>16} {method:>8} {:>4} spp  MAPE {:.4}  relMSE {:.4}  {:.2} s (equal time)",
                output.spp, errors.mape, errors.relmse, output.seconds
            );
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
            relative_img(&args.docs, &args.img)
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
    nis_paper::report::write_section(&args.docs, "guiding", "Path guiding", &body)?;
    eprintln!("wrote {} and {}", args.docs.display(), args.img.display());
    Ok(())
}

/// `img` as seen from the folder of `docs` (both relative to the working directory).
fn relative_img(docs: &Path, img: &Path) -> String {
    let docs_dir = docs.parent().unwrap_or(Path::new(""));
    match img.strip_prefix(docs_dir) {
        Ok(rel) => rel.display().to_string(),
        Err(_) => img.display().to_string(),
    }
}
