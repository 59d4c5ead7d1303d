//! The render loop: tiles of the image traced in parallel, pass after pass, until a sample
//! count or a time budget is reached.
//!
//! Every sample has its own random stream, seeded from `(seed, pixel, sample index)` by the
//! SplitMix64 finaliser (Steele et al. 2014), so an image depends only on the seed and the
//! sample count, never on the number of threads or on how samples are split into passes.
//! Pixels use a box filter: a sample lands uniformly in its pixel and counts only there.

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

use rand_pcg::Pcg32;
use rayon::prelude::*;

use crate::film::Image;
use crate::geometry::Rgb;
use crate::guiding::Guide;
use crate::integrator::{uniform, Integrator, PathStats};
use crate::scene::Scene;

/// How long to render.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Budget {
    /// Exactly this many samples per pixel, in one pass.
    Samples(u32),
    /// One-sample passes until this many seconds have passed (at least one pass).
    Seconds(f64),
}

/// A finished render.
#[derive(Clone, Debug)]
pub struct RenderOutput {
    /// Mean of the samples of each pixel.
    pub image: Image,
    /// Samples per pixel taken.
    pub spp: u32,
    /// Ray and path counts.
    pub stats: PathStats,
    /// Wall-clock seconds spent tracing.
    pub seconds: f64,
}

/// Side of the square tiles that threads take one at a time.
pub const TILE_SIZE: u32 = 16;

fn splitmix64(mut x: u64) -> u64 {
    x = x.wrapping_add(0x9e37_79b9_7f4a_7c15);
    x = (x ^ (x >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    x ^ (x >> 31)
}

/// The random stream of sample `sample` of pixel `pixel`.
pub fn sample_rng(seed: u64, pixel: u64, sample: u64) -> Pcg32 {
    let state = splitmix64(splitmix64(splitmix64(seed) ^ pixel) ^ sample);
    Pcg32::new(state, splitmix64(state) | 1)
}

/// Render `scene` with `integrator`, guided by `guide`. `progress` is called with the fraction
/// done after every tile.
pub fn render<G: Guide>(
    scene: &Scene,
    integrator: &Integrator,
    budget: Budget,
    seed: u64,
    guide: &mut G,
    progress: &(dyn Fn(f64) + Sync),
) -> RenderOutput {
    let (w, h) = (scene.camera.width(), scene.camera.height());
    let mut sums = vec![[0.0f64; 3]; w as usize * h as usize];
    let mut stats = PathStats::default();
    let start = Instant::now();
    let mut spp = 0u32;
    let mut iteration = 0usize;
    loop {
        let pass_spp = match budget {
            Budget::Samples(n) => n,
            Budget::Seconds(_) => 1,
        };
        guide.begin_iteration(iteration);
        let pass_stats = render_pass(
            scene,
            integrator,
            seed,
            spp,
            pass_spp,
            &*guide,
            &mut sums,
            &|f| match budget {
                Budget::Samples(_) => progress(f),
                Budget::Seconds(t) => progress((start.elapsed().as_secs_f64() / t).min(1.0)),
            },
        );
        guide.end_iteration(iteration);
        stats.merge(&pass_stats);
        spp += pass_spp;
        iteration += 1;
        match budget {
            Budget::Samples(_) => break,
            Budget::Seconds(t) if start.elapsed().as_secs_f64() >= t => break,
            Budget::Seconds(_) => {}
        }
    }
    let inv = 1.0 / f64::from(spp.max(1));
    let image = Image {
        width: w,
        height: h,
        pixels: sums
            .iter()
            .map(|s| {
                Rgb::new(
                    (s[0] * inv) as f32,
                    (s[1] * inv) as f32,
                    (s[2] * inv) as f32,
                )
            })
            .collect(),
    };
    RenderOutput {
        image,
        spp,
        stats,
        seconds: start.elapsed().as_secs_f64(),
    }
}

/// Add samples `first_sample..first_sample + count` of every pixel to `sums`.
fn render_pass<G: Guide>(
    scene: &Scene,
    integrator: &Integrator,
    seed: u64,
    first_sample: u32,
    count: u32,
    guide: &G,
    sums: &mut [[f64; 3]],
    progress: &(dyn Fn(f64) + Sync),
) -> PathStats {
    let (w, h) = (scene.camera.width(), scene.camera.height());
    let tiles: Vec<(u32, u32)> = (0..h.div_ceil(TILE_SIZE))
        .flat_map(|ty| (0..w.div_ceil(TILE_SIZE)).map(move |tx| (tx * TILE_SIZE, ty * TILE_SIZE)))
        .collect();
    let done = AtomicU64::new(0);
    let n_tiles = tiles.len() as f64;
    let wants_records = guide.wants_records();
    let results: Vec<_> = tiles
        .par_iter()
        .map(|&(x0, y0)| {
            let mut stats = PathStats::default();
            let mut records = Vec::new();
            let mut out = Vec::new();
            for y in y0..(y0 + TILE_SIZE).min(h) {
                for x in x0..(x0 + TILE_SIZE).min(w) {
                    let pixel = u64::from(y) * u64::from(w) + u64::from(x);
                    let mut sum = [0.0f64; 3];
                    for s in first_sample..first_sample + count {
                        let mut rng = sample_rng(seed, pixel, u64::from(s));
                        let ray = scene
                            .camera
                            .ray(x as f32 + uniform(&mut rng), y as f32 + uniform(&mut rng));
                        let l = integrator.radiance(
                            scene,
                            ray,
                            &mut rng,
                            guide,
                            &mut stats,
                            wants_records.then_some(&mut records),
                        );
                        stats.paths += 1;
                        if l.is_finite() {
                            for c in 0..3 {
                                sum[c] += f64::from(l[c]);
                            }
                        } else {
                            stats.invalid += 1;
                        }
                    }
                    out.push((pixel as usize, sum));
                }
            }
            if wants_records && !records.is_empty() {
                guide.record(&records);
            }
            let d = done.fetch_add(1, Ordering::Relaxed) + 1;
            progress(d as f64 / n_tiles);
            (out, stats)
        })
        .collect();
    let mut stats = PathStats::default();
    for (out, s) in results {
        stats.merge(&s);
        for (i, v) in out {
            for c in 0..3 {
                sums[i][c] += v[c];
            }
        }
    }
    stats
}
