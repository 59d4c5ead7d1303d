//! `nis bench fit-image`: the paper's Figure 3 (Müller et al. 2019, Sec. 2.3). Affine couplings
//! with L = 2 and L = 16 against piecewise-linear, piecewise-quadratic and rational-quadratic
//! couplings with L = 2 (32 bins), the same MLP, steps and training points, on every built-in
//! 2-D target; a montage, learning curves, results.json and a table with the paper's check.

use std::path::PathBuf;

use nis::flow::FlowConfig;
use nis::TransformKind;

use crate::error::Result;
use crate::image::figure::{self, MontageRow};
use crate::image::{Builtin, Fit, FitConfig, FitSummary, Grid, Target};
use crate::report::{self, write_file};

/// Settings of the benchmark.
#[derive(Clone, Debug)]
pub struct Settings {
    /// Training steps of every model.
    pub steps: usize,
    /// Training points per step (the same points for every model).
    pub batch: usize,
    /// Pixels per side of the built-in targets (and of the metric grids).
    pub resolution: usize,
    /// Adam learning rate of every model.
    pub learning_rate: f32,
    /// Random seed (weights and training points).
    pub seed: u64,
    /// Directory for the montage, the curves and results.json.
    pub out: PathBuf,
    /// Markdown file the table goes to (section "fit-image").
    pub docs: PathBuf,
    /// Directory for the figures the Markdown file shows.
    pub docs_images: PathBuf,
}

/// File names of the figures in `docs_images`.
const DOCS_MONTAGE: &str = "fit-image-montage.png";
const DOCS_CURVES: &str = "fit-image-curves.png";

/// The models of the paper's comparison: same MLP, same steps, same samples.
pub fn models() -> Vec<(TransformKind, usize)> {
    vec![
        (TransformKind::Affine, 2),
        (TransformKind::Affine, 16),
        (TransformKind::Linear { bins: 32 }, 2),
        (TransformKind::Quadratic { bins: 32 }, 2),
        (TransformKind::RationalQuadratic { bins: 32 }, 2),
    ]
}

/// Runs the benchmark: `fit` trains one model on one target (the caller shows its progress),
/// `log` sees a line per model. Returns the Markdown written to `settings.docs`.
pub fn run(
    settings: &Settings,
    fit: &mut dyn FnMut(&Target, &Grid, &FitConfig) -> Result<Fit>,
    log: &mut dyn FnMut(&str),
) -> Result<String> {
    let args = settings;
    let mut rows = Vec::new();
    let mut summaries = Vec::new();
    let mut models = Vec::new();
    for which in Builtin::ALL {
        let target = Target::builtin(which, args.resolution)?;
        let grid = Grid::for_target(&target)?;
        let mut row = MontageRow {
            name: target.name().to_string(),
            size: grid.size(),
            p: grid.p().to_vec(),
            q: Vec::new(),
        };
        let mut series = Vec::new();
        models.clear();
        for (transform, couplings) in self::models() {
            let config = FitConfig {
                flow: FlowConfig {
                    transform,
                    couplings,
                    seed: args.seed,
                    ..FlowConfig::new(2)
                },
                steps: args.steps,
                batch: args.batch,
                learning_rate: args.learning_rate,
                seed: args.seed,
                ..FitConfig::default()
            };
            let fit = fit(&target, &grid, &config)?;
            let s = &fit.summary;
            log(&format!(
                "{:>13} {:>12} {:>7} params  KL {:.5}  var {:.5}  {:.1} s",
                s.target, s.model, s.param_count, s.final_kl, s.final_rel_var, s.seconds
            ));
            row.q.push(grid.q(&fit.flow)?);
            models.push(s.model.clone());
            series.push((s.model.clone(), fit.curve.clone()));
            summaries.push(fit.summary);
        }
        let curves = figure::png_bytes(&figure::curves(target.name(), &series)?)?;
        write_file(
            &args.out.join(format!("curves-{}.png", target.name())),
            &curves,
        )?;
        if rows.is_empty() {
            write_file(&args.docs_images.join(DOCS_CURVES), &curves)?;
        }
        rows.push(row);
    }
    let montage = figure::png_bytes(&figure::montage(&models, &rows, 192)?)?;
    write_file(&args.out.join("montage.png"), &montage)?;
    // A smaller copy for the repository (kept under ~300 KB).
    let small = figure::png_bytes(&figure::montage(&models, &rows, 100)?)?;
    write_file(&args.docs_images.join(DOCS_MONTAGE), &small)?;
    let json = serde_json::to_string_pretty(&summaries).expect("summaries serialise");
    write_file(&args.out.join("results.json"), json.as_bytes())?;
    let body = markdown(args, &summaries);
    report::write_section(
        &args.docs,
        "fit-image",
        "2-D image targets (paper Figure 3)",
        &body,
    )?;
    Ok(body)
}

/// The table of the benchmark, one row per target and model.
fn markdown(args: &Settings, summaries: &[FitSummary]) -> String {
    let images = report::relative_to(&args.docs, &args.docs_images);
    let mut t = format!(
        "Reproduce: `nis bench fit-image --steps {} --batch {} --resolution {} --learning-rate {} \
         --seed {}`.\n\n\
         Every model: MLP 3×64 (ReLU), one-blob 32, Adam (learning rate {}), KL gradient on \
         the same {} uniform points per step, {} steps. KL and variance are exact on the \
         {}² pixel grid.\n\n\
         ![montage]({images}/{DOCS_MONTAGE})\n\n\
         ![curves]({images}/{DOCS_CURVES})\n\n\
         | target | model | parameters | KL (nats) | Var(f/q)/F² | seconds |\n\
         |---|---|---:|---:|---:|---:|\n",
        args.steps,
        args.batch,
        args.resolution,
        args.learning_rate,
        args.seed,
        args.learning_rate,
        args.batch,
        args.steps,
        args.resolution,
    );
    for s in summaries {
        t.push_str(&format!(
            "| {} | {} | {} | {:.4} | {:.4} | {:.2} |\n",
            s.target, s.model, s.param_count, s.final_kl, s.final_rel_var, s.seconds
        ));
    }
    t.push_str(&paper_check(summaries));
    t
}

/// The paper's claim, checked per target: PL-32 and PQ-32 with L = 2 reach a lower KL than
/// affine couplings with L = 16.
fn paper_check(summaries: &[FitSummary]) -> String {
    let kl = |target: &str, model: &str| {
        summaries
            .iter()
            .find(|s| s.target == target && s.model == model)
            .map(|s| s.final_kl)
    };
    let mut targets: Vec<&str> = summaries.iter().map(|s| s.target.as_str()).collect();
    targets.dedup();
    let mut lines = String::from("\nPaper check (lower KL than affine L=16):\n\n");
    for target in targets {
        let Some(affine) = kl(target, "affine L=16") else {
            continue;
        };
        let verdict = |model: &str| match kl(target, model) {
            Some(k) if k < affine => format!("{model} yes ({:.1}× lower)", affine / k),
            Some(_) => format!("{model} **no**"),
            None => format!("{model} not run"),
        };
        lines.push_str(&format!(
            "* {target}: {}, {}\n",
            verdict("pl32 L=2"),
            verdict("pq32 L=2")
        ));
    }
    lines
}
