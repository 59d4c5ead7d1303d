//! `nis density` (train, sample, interpolate) and `nis bench density`: the paper's density
//! estimation experiment (Müller et al. 2019, Sec. 5.1, Figure 4) on real digit images. All logic
//! is in `nis_paper::density` and `nis_paper::data`; this file parses, shows progress and writes files.

use std::path::{Path, PathBuf};

use indicatif::{ProgressBar, ProgressStyle};
use nis_paper::data::{Dataset, Images};
use nis_paper::density::figure::{self, default_scale, manifold_png};
use nis_paper::density::train::{Progress, CHECKPOINT, HISTORY};
use nis_paper::density::{DensityConfig, Session};

use crate::fit_image::Coupling;

#[derive(clap::Subcommand)]
pub enum DensityCommand {
    /// Train a flow on an image set; shows train and validation bits/dim after every epoch.
    ///
    /// Example: nis density train --dataset digits --coupling pq --epochs 50 --out out/digits-pq
    Train(TrainArgs),
    /// A grid of samples from a trained model (PNG).
    ///
    /// Example: nis density sample out/digits-pq --n 64 --out out/digits-pq/samples.png
    Sample(SampleArgs),
    /// The paper's manifold: 4 validation images in the corners, latents interpolated between.
    ///
    /// Example: nis density interpolate out/digits-pq --side 8 --out out/digits-pq/manifold.png
    Interpolate(InterpolateArgs),
}

#[derive(clap::Args)]
#[command(
    after_help = "Writes into --out: checkpoint.safetensors (after every epoch, atomically) \
    and history.json. Run scripts/setup/fetch-data.sh first to get the images into data/.\n\n\
    bits/dim = (E[−ln q(y)] + D·ln L)/(D·ln 2) for images dequantised to y = (x + u)/L."
)]
pub struct TrainArgs {
    /// The image set: digits (8×8, 17 levels) or mnist (28×28, 256 levels).
    #[arg(long, default_value = "digits")]
    dataset: String,
    /// Architecture: mlp (coupling flow with MLP conditioners on the flat image) or multiscale
    /// (RealNVP: checkerboard and channel masks, squeezes, convolutional residual conditioners).
    #[arg(long, default_value = "mlp")]
    arch: String,
    /// Multi-scale: number of squeezes.
    #[arg(long)]
    scales: Option<usize>,
    /// Multi-scale: channels of the convolutional conditioners.
    #[arg(long)]
    features: Option<usize>,
    /// Multi-scale: residual blocks per conditioner.
    #[arg(long)]
    blocks: Option<usize>,
    /// Coupling transform.
    #[arg(long, value_enum, default_value = "pq")]
    coupling: Coupling,
    /// Bins K of spline couplings (the paper: 4).
    #[arg(long, default_value_t = 4)]
    bins: usize,
    /// Epochs to train to (a resumed run continues up to this count).
    #[arg(long, default_value_t = 20)]
    epochs: usize,
    /// Stop once the training time reaches this many minutes (evaluation not counted).
    #[arg(long)]
    minutes: Option<f64>,
    /// Continue from the checkpoint in --out.
    #[arg(long)]
    resume: bool,
    /// Coupling layers (default: dataset-dependent; 0 = all binary masks).
    #[arg(long)]
    couplings: Option<usize>,
    /// Hidden layers of each conditioner.
    #[arg(long)]
    hidden_layers: Option<usize>,
    /// Width of each hidden layer.
    #[arg(long)]
    hidden_width: Option<usize>,
    /// One-blob bins per conditioner input.
    #[arg(long)]
    blob_bins: Option<usize>,
    /// Images per step.
    #[arg(long)]
    batch: Option<usize>,
    /// Adam learning rate.
    #[arg(long, default_value_t = 1e-3)]
    learning_rate: f32,
    /// Seed of weights, batch order and noise.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Directory with the data files.
    #[arg(long, default_value = "data")]
    data: PathBuf,
    /// Output directory.
    #[arg(long, default_value = "out/density")]
    out: PathBuf,
}

#[derive(clap::Args)]
pub struct SampleArgs {
    /// A training directory (or its checkpoint file).
    model: PathBuf,
    /// Number of samples.
    #[arg(long, default_value_t = 64)]
    n: usize,
    /// Samples per row.
    #[arg(long, default_value_t = 8)]
    cols: usize,
    /// Screen pixels per image pixel.
    #[arg(long)]
    scale: Option<usize>,
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Output PNG.
    #[arg(long, default_value = "samples.png")]
    out: PathBuf,
}

#[derive(clap::Args)]
pub struct InterpolateArgs {
    /// A training directory (or its checkpoint file).
    model: PathBuf,
    /// Images per side of the manifold.
    #[arg(long, default_value_t = 8)]
    side: usize,
    /// Index of the first of the four validation images in the corners.
    #[arg(long, default_value_t = 0)]
    first: usize,
    /// Screen pixels per image pixel.
    #[arg(long)]
    scale: Option<usize>,
    /// Directory with the data files.
    #[arg(long, default_value = "data")]
    data: PathBuf,
    /// Output PNG.
    #[arg(long, default_value = "manifold.png")]
    out: PathBuf,
}

type Res<T = ()> = Result<T, Box<dyn std::error::Error>>;

pub fn run(cmd: &DensityCommand) -> Res {
    match cmd {
        DensityCommand::Train(a) => train(a),
        DensityCommand::Sample(a) => sample(a),
        DensityCommand::Interpolate(a) => interpolate(a),
    }
}

fn checkpoint_path(p: &Path) -> PathBuf {
    if p.is_dir() {
        p.join(CHECKPOINT)
    } else {
        p.to_path_buf()
    }
}

/// Trains `session` with a progress bar; writes the checkpoint and history into `out`.
fn train_with_bar(
    session: &mut Session,
    train: &Images,
    valid: &Images,
    epochs: usize,
    max_seconds: Option<f64>,
    out: &Path,
) -> nis_paper::Result<()> {
    nis_paper::report::create_dir(out)?;
    let label = format!(
        "{} {}",
        session.config().dataset.name(),
        session.config().model.label()
    );
    let pb = ProgressBar::new(0).with_style(
        ProgressStyle::with_template("{prefix:>16} epoch {msg}").expect("a valid template"),
    );
    pb.set_prefix(label);
    let mut last = String::from("train –  valid –");
    let ckpt = out.join(CHECKPOINT);
    session.run(
        train,
        valid,
        epochs,
        max_seconds,
        Some(&ckpt),
        &mut |p| match p {
            Progress::Step {
                epoch,
                step,
                steps_per_epoch,
                batch_bpd,
            } => pb.set_message(format!(
                "{}/{epochs} step {step}/{steps_per_epoch}  batch {batch_bpd:.3}  {last} bits/dim",
                epoch + 1
            )),
            Progress::Epoch(s) => {
                last = format!("train {:.3}  valid {:.3}", s.train_bpd, s.valid_bpd);
                let line = format!(
                    "epoch {:>6.2}  steps {:>6}  {:>7.1} s  train {:.4}  valid {:.4} bits/dim",
                    s.epochs, s.steps, s.seconds, s.train_bpd, s.valid_bpd
                );
                if pb.is_hidden() {
                    eprintln!("{line}");
                } else {
                    pb.println(line);
                }
            }
        },
    )?;
    pb.finish_and_clear();
    session.write_history(&out.join(HISTORY))
}

fn train(a: &TrainArgs) -> Res {
    let dataset: Dataset = a.dataset.parse()?;
    let ckpt = a.out.join(CHECKPOINT);
    let mut session = if a.resume {
        let s = Session::load(&ckpt)?;
        if s.config().dataset != dataset {
            return Err(format!(
                "{} holds a {} model, not {}",
                ckpt.display(),
                s.config().dataset.name(),
                dataset.name()
            )
            .into());
        }
        println!(
            "resuming {} after epoch {} ({} steps)",
            ckpt.display(),
            s.epoch(),
            s.steps()
        );
        s
    } else {
        let mut c = DensityConfig::defaults(dataset, a.arch.parse()?, a.coupling.transform(a.bins));
        let m = &mut c.model;
        m.scales = a.scales.unwrap_or(m.scales);
        m.features = a.features.unwrap_or(m.features);
        m.blocks = a.blocks.unwrap_or(m.blocks);
        m.couplings = a.couplings.unwrap_or(m.couplings);
        m.hidden_layers = a.hidden_layers.unwrap_or(m.hidden_layers);
        m.hidden_width = a.hidden_width.unwrap_or(m.hidden_width);
        m.blob_bins = a.blob_bins.unwrap_or(m.blob_bins);
        m.seed = a.seed;
        c.batch = a.batch.unwrap_or(c.batch);
        c.learning_rate = a.learning_rate;
        c.seed = a.seed;
        Session::new(c)?
    };
    let (train, valid) = dataset.load_split(&a.data)?;
    println!(
        "{}: {} training and {} validation images of {}×{}, {} levels; {} with {} parameters",
        dataset.name(),
        train.len(),
        valid.len(),
        train.width,
        train.height,
        train.levels,
        session.config().model.label(),
        session.model().param_count()
    );
    let max_seconds = a.minutes.map(|m| m * 60.0 + session.seconds());
    train_with_bar(&mut session, &train, &valid, a.epochs, max_seconds, &a.out)?;
    if let Some(s) = session.history().last() {
        println!(
            "after {:.2} epochs ({:.1} min): train {:.4}, validation {:.4} bits/dim; wrote {}",
            s.epochs,
            s.seconds / 60.0,
            s.train_bpd,
            s.valid_bpd,
            ckpt.display()
        );
    }
    Ok(())
}

fn sample(a: &SampleArgs) -> Res {
    let s = Session::load(&checkpoint_path(&a.model))?;
    let m = &s.config().model;
    let x = figure::samples(s.model(), a.n, a.seed)?;
    let levels = s.config().dataset.levels();
    let png = figure::grid_png(
        &x,
        m.width,
        m.height,
        levels,
        a.cols,
        a.scale.unwrap_or(default_scale(m.width)),
    )?;
    nis::io::write_atomic(&a.out, &png)?;
    println!("wrote {} ({} samples)", a.out.display(), a.n);
    Ok(())
}

fn interpolate(a: &InterpolateArgs) -> Res {
    let s = Session::load(&checkpoint_path(&a.model))?;
    let (_, valid) = s.config().dataset.load_split(&a.data)?;
    let scale = a.scale.unwrap_or(default_scale(valid.width));
    let png = manifold_png(s.model(), &valid, a.first, a.side, scale)?;
    nis::io::write_atomic(&a.out, &png)?;
    println!("wrote {}", a.out.display());
    Ok(())
}

/// Settings of `nis bench density`.
#[derive(clap::Args)]
pub struct BenchDensityArgs {
    /// Training minutes per model on the digits.
    #[arg(long, default_value_t = 2.0)]
    minutes_digits: f64,
    /// Training minutes per model on MNIST.
    #[arg(long, default_value_t = 4.0)]
    minutes_mnist: f64,
    /// Only this data set (digits or mnist).
    #[arg(long)]
    only: Option<String>,
    /// Architectures, comma-separated (mlp, multiscale).
    #[arg(long, default_value = "mlp,multiscale")]
    archs: String,
    /// Bins K of the piecewise-quadratic coupling.
    #[arg(long, default_value_t = 4)]
    bins: usize,
    /// Directory with the data files.
    #[arg(long, default_value = "data")]
    data: PathBuf,
    /// Directory for checkpoints and histories.
    #[arg(long, default_value = "out/bench-density")]
    out: PathBuf,
    /// Markdown file the table goes to (section "density").
    #[arg(long, default_value = "docs/results/paper.md")]
    docs: PathBuf,
    /// Directory for the sample and manifold PNGs the Markdown file shows.
    #[arg(long, default_value = "docs/img")]
    docs_images: PathBuf,
}

/// `nis bench density`: PQ against affine couplings at the same architecture and the same
/// training time, on both image sets.
pub fn run_bench(a: &BenchDensityArgs) -> Res {
    let settings = nis_paper::bench::density::Settings {
        minutes_digits: a.minutes_digits,
        minutes_mnist: a.minutes_mnist,
        only: a.only.as_deref().map(str::parse).transpose()?,
        archs: a
            .archs
            .split(',')
            .map(str::parse)
            .collect::<Result<_, _>>()?,
        bins: a.bins,
        data: a.data.clone(),
        out: a.out.clone(),
        docs: a.docs.clone(),
        docs_images: a.docs_images.clone(),
    };
    let body = nis_paper::bench::density::run(
        &settings,
        // Epochs far beyond what the time allows: the budget ends the run.
        &mut |session, train, valid, seconds, out| {
            train_with_bar(session, train, valid, 100_000, Some(seconds), out)
        },
        &mut |line| println!("{line}"),
    )?;
    println!("{body}");
    Ok(())
}
