//! Renders a built-in scene with the neural guide and prints what every training phase did:
//! records with non-zero `F`, Adam steps, the loss, the mean selection probability and the
//! share of the flow's mass below the surface (docs/results/guiding.md).
//!
//! ```text
//! cargo run --release -p nis-render --example guide_history -- cornell-indirect 128 64 0 '{"frame": "local"}'
//! ```
//!
//! (scene, resolution, samples per pixel, seed, and the guide's settings as for
//! `nis render --guide-config`).

use nis_render::guiding::neural::{NisGuide, NisGuideConfig};
use nis_render::path_tracer::{PathTracer, Strategy};
use nis_render::render::{render, Budget, RenderOptions, Schedule};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let arg = |i: usize, default: &str| args.get(i).cloned().unwrap_or_else(|| default.into());
    let name = arg(0, "cornell-indirect");
    let res = arg(1, "128");
    let spp: u32 = arg(2, "64").parse()?;
    let seed: u64 = arg(3, "0").parse()?;
    let scene = nis_render::scenes::load_with(&name, &[("res".to_string(), res)])?;
    let config: NisGuideConfig = serde_json::from_str(&arg(4, "{}"))?;
    let config = NisGuideConfig { seed, ..config };
    let mut guide = NisGuide::new(scene.bounds(), config)?;
    let options = RenderOptions {
        path_tracer: PathTracer::from_scene(&scene, Strategy::Mis),
        budget: Budget::Samples(spp),
        seed,
        schedule: Schedule::Training,
    };
    let out = render(&scene, &options, &mut guide, &|_| {});
    println!("{name}: {} spp, {:.1} s", out.spp, out.seconds);
    println!("phase | records F>0 | steps | loss | mean c | best constant c | mass below | s");
    for (i, h) in guide.history().iter().enumerate() {
        println!(
            "{i} | {} | {} | {:.3} | {:.3} | {:.3} | {:.3} | {:.2}",
            h.new_records,
            h.steps,
            h.loss,
            h.mean_selection,
            h.best_constant_selection,
            h.below_surface,
            h.seconds
        );
    }
    Ok(())
}
