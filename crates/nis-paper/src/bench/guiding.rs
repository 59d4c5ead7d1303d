//! `nis bench guiding`: every path-guiding method against a high-sample path-traced reference,
//! at equal samples per pixel and at equal time, as in the paper's Figure 5: MAPE and relMSE,
//! montages of central crops with error maps, a table in `docs/results/guiding.md`.
//!
//! Equal time is one wall-clock budget `T` per scene for every method: the time unguided path
//! tracing takes for [`Settings::equal_time_spp`] samples per pixel (or `--seconds`). Each
//! method also renders at `T/2`, `T/4`, …, so its error-vs-time curve (MAPE against the wall
//! seconds it took, a PNG plot) shows where one method overtakes another, and the table gives
//! the time each method needs to reach one MAPE (interpolated on its curve).

use std::path::PathBuf;

use nis_render::compare::{compare, error_map, ImageErrors};
use nis_render::film::Image;
use nis_render::geometry::Rgb;
use nis_render::guiding::factory::GuideSpec;
use nis_render::path_tracer::{PathTracer, Strategy};
use nis_render::render::{Budget, RenderOptions, RenderOutput, Schedule};
use nis_render::scene::Scene;

use crate::error::{Error, Result};
use crate::image::figure::{error_time, png_bytes, ErrorTimePanel};
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

/// The cached reference of `name`, rendered when missing.
fn reference(
    name: &str,
    scene: &Scene,
    path_tracer: &PathTracer,
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
        path_tracer: *path_tracer,
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
    check(args)?;
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
    let methods: Vec<(String, GuideSpec)> = methods.into_iter().zip(specs).collect();
    create_dir(&args.out)?;
    create_dir(&args.img)?;
    let mut table = String::from(
        "| scene | method | MAPE | relMSE | seconds | equal time (s) | spp | MAPE | relMSE | seconds to MAPE |\n|---|---|---|---|---|---|---|---|---|---|\n",
    );
    let mut figures = String::new();
    let mut panels: Vec<ErrorTimePanel> = Vec::new();
    for name in &scenes {
        let params = [("res".to_string(), args.res.to_string())];
        let scene = nis_render::scenes::load_with(name, &params)?;
        let path_tracer = PathTracer::from_scene(&scene, Strategy::Mis);
        let reference = reference(name, &scene, &path_tracer, args, io)?;
        let bench = SceneBench {
            name,
            scene: &scene,
            reference: &reference,
            path_tracer,
            args,
        };
        let equal_spp = bench.equal_samples(&methods, io)?;
        let (seconds, equal_time, curves) = bench.equal_time(&methods, io)?;
        table.push_str(&table_rows(
            name,
            seconds,
            args.target_mape,
            &equal_spp,
            &equal_time,
            &curves,
        ));
        panels.push((name.clone(), seconds, curves));
        let file = format!("guiding-{name}.png");
        montage(&reference, &equal_spp)?.write(&args.img.join(&file))?;
        let names: Vec<&str> = methods.iter().map(|(m, _)| m.as_str()).collect();
        figures.push_str(&format!(
            "**{name}** (central crops: reference, then {} at equal spp, all at one exposure; their relative error maps below, 0 to 1 in false colour):\n\n![{name}]({}/{file})\n\n",
            names.join(", "),
            report::relative_to(&args.docs, &args.img)
        ));
    }
    let plot = "guiding-error-time.png";
    let figure = error_time("MAPE against wall-clock time", &panels)?;
    report::write_file(&args.img.join(plot), &png_bytes(&figure)?)?;
    let body = section(args, &table, plot, &figures);
    report::write_section(&args.docs, "guiding", "Path guiding", &body)?;
    Ok(body)
}

/// An error for settings that cannot make a comparison.
fn check(args: &Settings) -> Result<()> {
    if args.spp == 0 || args.res == 0 || args.reference_spp == 0 || args.equal_time_spp == 0 {
        return Err(Error::Config(
            "samples per pixel, resolution, reference and equal-time samples must be positive"
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

/// One scene's renders: its reference and the renders' settings.
struct SceneBench<'a> {
    name: &'a str,
    scene: &'a Scene,
    reference: &'a Image,
    path_tracer: PathTracer,
    args: &'a Settings,
}

/// An error-vs-time curve: a method and its (seconds, MAPE) points.
type Curve = (String, Vec<(f64, f64)>);

impl SceneBench<'_> {
    fn options(&self, budget: Budget) -> RenderOptions {
        RenderOptions {
            path_tracer: self.path_tracer,
            budget,
            seed: self.args.seed,
            schedule: Schedule::Plain,
        }
    }

    /// Every method at the same samples per pixel; the renders are written to `args.out`.
    fn equal_samples(&self, methods: &[(String, GuideSpec)], io: &mut Io<'_>) -> Result<Vec<Run>> {
        let (name, args) = (self.name, self.args);
        let mut runs = Vec::new();
        for (method, spec) in methods {
            let label = format!("{name}: {method}, {} spp", args.spp);
            let options = self.options(Budget::Samples(args.spp));
            let output = (io.render)(self.scene, &options, spec, &label)?;
            let errors = compare(&output.image, self.reference)?;
            (io.log)(&format!(
                "{name:>16} {method:>8} {:>4} spp  MAPE {:.4}  relMSE {:.4}  {:.2} s",
                output.spp, errors.mape, errors.relmse, output.seconds
            ));
            output.image.write(
                &args
                    .out
                    .join(format!("{name}-{method}-{}spp.exr", args.spp)),
            )?;
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
                let label = format!("{name}: none, {} spp (budget)", args.equal_time_spp);
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
                        let label = format!("{name}: {method}, {budget:.2} s");
                        let options = self.options(Budget::Seconds(budget));
                        (io.render)(self.scene, &options, spec, &label)?
                    }
                };
                let errors = compare(&output.image, self.reference)?;
                (io.log)(&format!(
                    "{name:>16} {method:>8} {:>4} spp  MAPE {:.4}  relMSE {:.4}  {:.2} s (budget {budget:.2} s)",
                    output.spp, errors.mape, errors.relmse, output.seconds
                ));
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

/// The table's rows of one scene: every method at equal samples and at equal time (best per
/// column in bold), and the seconds each needs to reach the target MAPE (`target_mape`, or path
/// tracing's at the budget, or the best method's without it).
fn table_rows(
    name: &str,
    seconds: f64,
    target_mape: Option<f64>,
    equal_spp: &[Run],
    equal_time: &[Run],
    curves: &[Curve],
) -> String {
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
    // Path tracing's MAPE at the budget, or the best method's when it did not run.
    let target = target_mape.unwrap_or_else(|| {
        equal_time
            .iter()
            .find(|r| r.method == "none")
            .map_or_else(|| best(equal_time, |e| e.mape), |r| r.errors.mape)
    });
    let (b1, b2) = (best(equal_spp, |e| e.mape), best(equal_spp, |e| e.relmse));
    let (b3, b4) = (best(equal_time, |e| e.mape), best(equal_time, |e| e.relmse));
    let mut rows = String::new();
    for ((a, t), (_, curve)) in equal_spp.iter().zip(equal_time).zip(curves) {
        let reach = time_to_reach(curve, target).map_or_else(|| "–".into(), |r| r.to_string());
        rows.push_str(&format!(
            "| {name} | {} | {} | {} | {:.1} | {seconds:.1} | {} | {} | {} | {target:.4} in {reach} |\n",
            a.method,
            bold(a.errors.mape, b1),
            bold(a.errors.relmse, b2),
            a.output.seconds,
            t.output.spp,
            bold(t.errors.mape, b3),
            bold(t.errors.relmse, b4),
        ));
    }
    rows
}

/// The section's text: how the comparison is run, the table, the error-vs-time plot `plot` and
/// the montages `figures`.
fn section(args: &Settings, table: &str, plot: &str, figures: &str) -> String {
    let budget = match args.seconds {
        Some(s) => format!("{s} s (`--seconds`)"),
        None => format!(
            "the time unguided path tracing takes for {} spp",
            args.equal_time_spp
        ),
    };
    format!(
        "Reproduce: `nis bench guiding --spp {spp} --res {res} --reference-spp {rspp} \
         --equal-time-spp {etspp} --curve-points {points}`. \
         Every method renders {res}×{res} pixels with {spp} samples per pixel in total \
         (guided methods spend up to half of them on training passes of 1, 2, 4, … spp, and \
         the passes are combined by inverse variance). At equal time every method gets one \
         wall-clock budget per scene, {budget}, and also half, a quarter, … of it \
         ({points} budgets): the curves below plot MAPE against the seconds each render took, \
         and the last column gives the seconds each method needs to reach the MAPE shown \
         (path tracing's at the budget, or the best method's without it, unless `--target-mape` \
         is given; interpolated on the \
         curve as a power law, `≤` / `>` when reached at its first point / not within it). \
         Errors are against a path-traced reference of {rspp} spp (other seed). MAPE and \
         relMSE with ε = 0.01; best per column in bold.\n\n{table}\n\
         ![MAPE against wall-clock time]({img}/{plot})\n\n{figures}",
        spp = args.spp,
        res = args.res,
        rspp = args.reference_spp,
        etspp = args.equal_time_spp,
        points = args.curve_points,
        img = report::relative_to(&args.docs, &args.img),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

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
