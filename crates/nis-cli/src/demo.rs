//! `nis demo`: trains a flow on a built-in two-Gaussian target in 2-D and prints how much the
//! variance of the importance-sampling estimate drops compared with uniform sampling.

use indicatif::{ProgressBar, ProgressStyle};
use nis::flow::{Flow, FlowConfig};
use nis::loss::Loss;
use nis::nn::AdamConfig;
use nis::train::Trainer;
use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;

#[derive(clap::Args)]
pub struct DemoArgs {
    /// Training steps.
    #[arg(long, default_value_t = 300)]
    steps: usize,
    /// Samples per step.
    #[arg(long, default_value_t = 4096)]
    batch: usize,
    /// Loss: kl or chi2.
    #[arg(long, default_value = "kl")]
    loss: Loss,
    /// Random seed.
    #[arg(long, default_value_t = 0)]
    seed: u64,
}

fn target(p: &[f32]) -> f64 {
    let g = |cx: f64, cy: f64, s: f64| {
        let (dx, dy) = (p[0] as f64 - cx, p[1] as f64 - cy);
        (-(dx * dx + dy * dy) / (2.0 * s * s)).exp()
    };
    g(0.3, 0.3, 0.05) + 0.5 * g(0.7, 0.65, 0.08)
}

fn estimate(flow: &Flow, n: usize, rng: &mut Pcg64Mcg) -> Result<(f64, f64), nis::Error> {
    let s = flow.sample(n, None, rng)?;
    let w: Vec<f64> =
        s.x.chunks(2)
            .zip(&s.log_q)
            .map(|(p, l)| target(p) * (-l).exp())
            .collect();
    let mean = w.iter().sum::<f64>() / n as f64;
    let var = w.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1) as f64;
    Ok((mean, var / (mean * mean)))
}

pub fn run(args: &DemoArgs) -> Result<(), Box<dyn std::error::Error>> {
    let flow = Flow::new(FlowConfig {
        seed: args.seed,
        ..FlowConfig::new(2)
    })?;
    let mut rng = Pcg64Mcg::seed_from_u64(args.seed);
    let (f0, v0) = estimate(&flow, 100_000, &mut rng)?;
    let adam = AdamConfig {
        learning_rate: 5e-3,
        ..Default::default()
    };
    let mut trainer = Trainer::new(flow, args.loss, adam)?;
    let bar = ProgressBar::new(args.steps as u64).with_style(ProgressStyle::with_template(
        "{bar:40} {pos}/{len} steps  {msg}",
    )?);
    for _ in 0..args.steps {
        let s = trainer
            .flow()
            .sample_for_training(args.batch, None, &mut rng)?;
        let f: Vec<f64> = s.x.chunks(2).map(target).collect();
        let st = trainer.step_on_policy(&s, &f)?;
        bar.set_message(format!("batch rel. variance {:.4}", st.rel_var));
        bar.inc(1);
    }
    bar.finish_and_clear();
    let (f1, v1) = estimate(trainer.flow(), 100_000, &mut rng)?;
    let exact = 2.0 * std::f64::consts::PI * (0.05f64 * 0.05 + 0.5 * 0.08 * 0.08);
    println!(
        "two Gaussians in 2-D, exact integral {exact:.6} (up to the tails outside the square)"
    );
    println!("uniform sampling : estimate {f0:.6}, relative variance {v0:.4}");
    println!("trained flow     : estimate {f1:.6}, relative variance {v1:.4}");
    println!("variance reduction: {:.1}x", v0 / v1);
    Ok(())
}
