//! `nis fit-image` and `nis bench fit-image`: the paper's 2-D experiment (Müller et al. 2019,
//! section 2.3, Figure 3). Fits a flow to an image (or a built-in pattern) and writes the
//! learned density, the learning curves and a JSON summary; the benchmark compares the coupling
//! transforms on every built-in target. All logic is in `nis_paper::image`; this file parses, shows
//! progress and writes files.

use std::path::{Path, PathBuf};

use indicatif::{ProgressBar, ProgressStyle};
use nis::flow::FlowConfig;
use nis::TransformKind;
use nis_paper::image::figure;
use nis_paper::image::{CurvePoint, Fit, FitConfig, Grid, Sampling, Target};
use serde::Serialize;

/// The coupling transform, as named on the command line.
#[derive(Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Coupling {
    /// Piecewise-quadratic (the paper's best).
    Pq,
    /// Piecewise-linear.
    Pl,
    /// Rational-quadratic (Durkan et al. 2019).
    Rq,
    /// Affine (RealNVP), the baseline.
    Affine,
}

impl Coupling {
    pub fn transform(self, bins: usize) -> TransformKind {
        match self {
            Coupling::Pq => TransformKind::Quadratic { bins },
            Coupling::Pl => TransformKind::Linear { bins },
            Coupling::Rq => TransformKind::RationalQuadratic { bins },
            Coupling::Affine => TransformKind::Affine,
        }
    }
}

#[derive(clap::Args)]
#[command(after_help = "Examples:\n  \
    nis fit-image --target rings --coupling pq --layers 2 --out out/rings-pq\n  \
    nis fit-image photo.png --coupling affine --layers 16 --steps 2000 --out out/photo\n\n\
    Writes into the --out directory: density.png (target | learned), curves.png (KL and variance against \
    step) and summary.json.")]
pub struct FitImageArgs {
    /// A PNG or JPEG file: its luminance is the target density. Leave out to use --target.
    image: Option<PathBuf>,
    /// A built-in target instead of a file: rings, checkerboard, glyphs or landscape.
    #[arg(long, conflicts_with = "image")]
    target: Option<String>,
    /// Coupling transform.
    #[arg(long, value_enum, default_value = "pq")]
    coupling: Coupling,
    /// Number of coupling layers L.
    #[arg(long, default_value_t = 2)]
    layers: usize,
    /// Bins K of the spline couplings (ignored by affine).
    #[arg(long, default_value_t = 32)]
    bins: usize,
    /// Training steps.
    #[arg(long, default_value_t = 1000)]
    steps: usize,
    /// Training points per step.
    #[arg(long, default_value_t = 4096)]
    batch: usize,
    /// Training points drawn uniformly (the paper's Figure 3) or from the flow itself.
    #[arg(long, default_value = "uniform")]
    sampling: Sampling,
    /// Adam learning rate.
    #[arg(long, default_value_t = 5e-3)]
    learning_rate: f32,
    /// Hidden layers of each coupling's MLP.
    #[arg(long, default_value_t = 3)]
    hidden_layers: usize,
    /// Width of each hidden layer.
    #[arg(long, default_value_t = 64)]
    hidden_width: usize,
    /// Pixels per side of a built-in target (and of its metric grid).
    #[arg(long, default_value_t = 256)]
    resolution: usize,
    /// Record the exact grid KL and variance every this many steps.
    #[arg(long, default_value_t = 25)]
    eval_every: usize,
    /// Random seed (weights and training points).
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Output directory.
    #[arg(long, default_value = "out/fit-image")]
    out: PathBuf,
}

/// The JSON written next to the figures.
#[derive(Serialize)]
struct Report<'a> {
    #[serde(flatten)]
    summary: &'a nis_paper::image::FitSummary,
    config: &'a FitConfig,
    curve: &'a [CurvePoint],
}

fn load_target(args: &FitImageArgs) -> Result<Target, Box<dyn std::error::Error>> {
    match (&args.image, &args.target) {
        (Some(path), _) => Ok(Target::from_path(path)?),
        (None, Some(name)) => Ok(Target::builtin(name.parse()?, args.resolution)?),
        (None, None) => Err("give an image file or --target NAME \
             (rings, checkerboard, glyphs, landscape); see nis fit-image --help"
            .into()),
    }
}

fn bar(len: usize, prefix: String) -> Result<ProgressBar, Box<dyn std::error::Error>> {
    Ok(ProgressBar::new(len as u64)
        .with_style(ProgressStyle::with_template(
            "{prefix:>24} {bar:30} {pos}/{len} steps {elapsed}  {msg}",
        )?)
        .with_prefix(prefix))
}

/// Trains with a progress bar whose message shows the latest grid metrics.
fn fit_with_bar(target: &Target, grid: &Grid, config: &FitConfig) -> Result<Fit, nis_paper::Error> {
    let label = format!(
        "{} {}",
        target.name(),
        nis_paper::image::model_label(&config.flow)
    );
    let pb = bar(config.steps, label).unwrap_or_else(|_| ProgressBar::new(config.steps as u64));
    let fit = nis_paper::image::fit(target, grid, config, &mut |step, metrics| {
        pb.set_position(step as u64);
        if let Some(m) = metrics {
            pb.set_message(format!("KL {:.4}  var {:.4}", m.kl, m.rel_var));
        }
    })?;
    pb.finish_and_clear();
    Ok(fit)
}

fn write(path: &Path, bytes: &[u8]) -> Result<(), Box<dyn std::error::Error>> {
    nis::io::write_atomic(path, bytes)?;
    Ok(())
}

/// `nis fit-image`.
pub fn run(args: &FitImageArgs) -> Result<(), Box<dyn std::error::Error>> {
    if args.layers == 0 {
        return Err("--layers must be at least 1".into());
    }
    let target = load_target(args)?;
    let grid = Grid::for_target(&target)?;
    let config = FitConfig {
        flow: FlowConfig {
            transform: args.coupling.transform(args.bins),
            couplings: args.layers,
            hidden_layers: args.hidden_layers,
            hidden_width: args.hidden_width,
            seed: args.seed,
            ..FlowConfig::new(2)
        },
        steps: args.steps,
        batch: args.batch,
        learning_rate: args.learning_rate,
        sampling: args.sampling,
        eval_every: args.eval_every,
        seed: args.seed,
    };
    let fit = fit_with_bar(&target, &grid, &config)?;
    let (nx, ny) = grid.size();
    let q = grid.q(&fit.flow)?;
    std::fs::create_dir_all(&args.out)?;
    let s = &fit.summary;
    let density = figure::side_by_side(grid.p(), &q, nx, ny, &s.model)?;
    write(&args.out.join("density.png"), &figure::png_bytes(&density)?)?;
    let title = format!("{}: {}", s.target, s.model);
    let curves = figure::curves(&title, &[(s.model.clone(), fit.curve.clone())])?;
    write(&args.out.join("curves.png"), &figure::png_bytes(&curves)?)?;
    let report = Report {
        summary: s,
        config: &config,
        curve: &fit.curve,
    };
    write(
        &args.out.join("summary.json"),
        serde_json::to_string_pretty(&report)?.as_bytes(),
    )?;
    println!(
        "{} · {} ({} parameters): KL {:.5} nats, relative variance {:.5}, {:.1} s training",
        s.target, s.model, s.param_count, s.final_kl, s.final_rel_var, s.seconds
    );
    println!(
        "wrote {}/density.png, curves.png, summary.json",
        args.out.display()
    );
    Ok(())
}

/// Settings of `nis bench fit-image`.
#[derive(clap::Args)]
pub struct BenchFitImageArgs {
    /// Training steps of every model.
    #[arg(long, default_value_t = 400)]
    steps: usize,
    /// Training points per step (the same points for every model).
    #[arg(long, default_value_t = 2048)]
    batch: usize,
    /// Pixels per side of the built-in targets (and of the metric grids).
    #[arg(long, default_value_t = 128)]
    resolution: usize,
    /// Adam learning rate of every model.
    #[arg(long, default_value_t = 5e-3)]
    learning_rate: f32,
    /// Random seed (weights and training points).
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Directory for the montage, the curves and results.json.
    #[arg(long, default_value = "out/bench-fit-image")]
    out: PathBuf,
    /// Markdown file the table goes to (section "fit-image").
    #[arg(long, default_value = "docs/results/paper.md")]
    docs: PathBuf,
    /// Directory for the figures the Markdown file shows (a small montage and the first
    /// target's curves).
    #[arg(long, default_value = "docs/img")]
    docs_images: PathBuf,
}

/// `nis bench fit-image`.
pub fn run_bench(args: &BenchFitImageArgs) -> Result<(), Box<dyn std::error::Error>> {
    let settings = nis_paper::bench::fit_image::Settings {
        steps: args.steps,
        batch: args.batch,
        resolution: args.resolution,
        learning_rate: args.learning_rate,
        seed: args.seed,
        out: args.out.clone(),
        docs: args.docs.clone(),
        docs_images: args.docs_images.clone(),
    };
    nis_paper::bench::fit_image::run(&settings, &mut fit_with_bar, &mut |line| println!("{line}"))?;
    println!(
        "wrote the montage and curves to {} and {}, results.json, and the table in {}",
        args.docs_images.display(),
        args.out.display(),
        args.docs.display()
    );
    Ok(())
}
