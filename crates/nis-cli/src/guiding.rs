//! `nis bench guiding`: every path-guiding method against a high-sample reference, at equal
//! samples per pixel and at equal time, as in the paper's Figure 5 (the driver is
//! `nis_paper::bench::guiding`); this file parses and shows progress.

use std::path::PathBuf;
use std::time::Duration;

use indicatif::{ProgressBar, ProgressStyle};
use nis::comm::Comm;
use nis_paper::bench::guiding::{Io, Settings};
use nis_render::guiding::factory::GuideSpec;
use nis_render::render::RenderOptions;
use nis_render::scene::Scene;

use crate::render::GUIDES;

/// Compare the guiding methods on built-in scenes or scene files against a reference.
#[derive(Debug, clap::Args)]
#[command(after_help = "\
Examples:
  nis bench guiding --scene two-rooms-door --spp 64 --res 128
  nis bench guiding --scene data/scenes/ppg-lab/scenes/veach-bidir/scene.xml --res 128 --seeds 3
  nis bench guiding --scene cornell-box --res 32 --spp 16 --reference-spp 1024 --equal-time-spp 64 --curve-points 3")]
pub struct BenchGuidingArgs {
    /// Built-in scene names or Mitsuba scene files (repeat; default: the four built-in ones).
    #[arg(long)]
    pub scene: Vec<String>,

    /// Samples per pixel of every method in the equal-samples comparison (training included).
    #[arg(long, default_value_t = 64)]
    pub spp: u32,

    /// Longer side of the image in pixels (a scene file keeps its film's aspect ratio).
    #[arg(long, default_value_t = 128)]
    pub res: u32,

    /// Samples per pixel of the path-traced reference (rendered once, cached in --out).
    #[arg(long, default_value_t = 4096)]
    pub reference_spp: u32,

    /// Seconds per method in the equal-time comparison (default: what unguided path tracing
    /// takes for --equal-time-spp samples per pixel).
    #[arg(long)]
    pub seconds: Option<f64>,

    /// Samples per pixel of unguided path tracing whose wall time is the equal-time budget.
    #[arg(long, default_value_t = 512)]
    pub equal_time_spp: u32,

    /// Budgets on each method's error-vs-time curve: the equal-time budget, half of it, a
    /// quarter, … (this many in all).
    #[arg(long, default_value_t = 4)]
    pub curve_points: u32,

    /// The MAPE whose reach time the table gives (default: path tracing's at the equal-time
    /// budget, or the best method's when path tracing is not among the methods).
    #[arg(long)]
    pub target_mape: Option<f64>,

    /// Methods (repeat; default: all).
    #[arg(long, value_parser = GUIDES)]
    pub method: Vec<String>,

    /// Random seed of the first run (the reference uses another).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,

    /// Runs per scene and method, with seeds --seed, --seed + 1, …; the table gives the mean
    /// and the range.
    #[arg(long, default_value_t = 1)]
    pub seeds: u32,

    /// Leave out a scene file's shapes whose mesh files are missing (with a warning).
    #[arg(long)]
    pub drop_missing_meshes: bool,

    /// Folder for the renders, error maps and the cached references.
    #[arg(long, default_value = "out/guiding")]
    pub out: PathBuf,

    /// Markdown file the table goes to (its own section for scene files).
    #[arg(long, default_value = "docs/results/guiding.md")]
    pub docs: PathBuf,

    /// Folder the montages go to (linked from --docs).
    #[arg(long, default_value = "docs/img")]
    pub img: PathBuf,
}

fn bar(message: &str) -> ProgressBar {
    let bar = ProgressBar::new(1000);
    bar.set_style(
        ProgressStyle::with_template("{msg:>36} [{elapsed_precise}] {wide_bar} {percent}%")
            .expect("a valid template"),
    );
    bar.set_message(message.to_string());
    bar.enable_steady_tick(Duration::from_millis(250));
    bar
}

/// Run `nis bench guiding`.
pub fn run_bench(args: &BenchGuidingArgs) -> Result<(), Box<dyn std::error::Error>> {
    let settings = Settings {
        scenes: args.scene.clone(),
        spp: args.spp,
        res: args.res,
        reference_spp: args.reference_spp,
        seconds: args.seconds,
        equal_time_spp: args.equal_time_spp,
        curve_points: args.curve_points,
        target_mape: args.target_mape,
        methods: args.method.clone(),
        seed: args.seed,
        seeds: args.seeds,
        drop_missing_meshes: args.drop_missing_meshes,
        out: args.out.clone(),
        docs: args.docs.clone(),
        img: args.img.clone(),
    };
    let mut render = |scene: &Scene, options: &RenderOptions, spec: &GuideSpec, label: &str| {
        let bar = bar(label);
        let progress = |f: f64| bar.set_position((f * 1000.0) as u64);
        let out = crate::render::render_spec(scene, options, spec, &Comm::default(), &progress)?;
        bar.finish_and_clear();
        Ok(out)
    };
    let mut log = |line: &str| eprintln!("{line}");
    nis_paper::bench::guiding::run(
        &settings,
        &mut Io {
            render: &mut render,
            log: &mut log,
        },
    )?;
    eprintln!("wrote {} and {}", args.docs.display(), args.img.display());
    Ok(())
}
