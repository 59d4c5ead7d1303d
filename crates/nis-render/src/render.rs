//! The render loop: tiles of the image traced in parallel, pass after pass, until a sample
//! count or a time budget is reached.
//!
//! Every sample has its own random stream, seeded from `(seed, pixel, sample index)` by the
//! SplitMix64 finaliser ([`splitmix64`], Steele et al. 2014), so an image depends only on the seed and the
//! sample count, never on the number of threads or on how samples are split into passes.
//! Pixels use a box filter: a sample lands uniformly in its pixel and counts only there.

use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

use rand_pcg::Pcg32;
use rayon::prelude::*;

use crate::film::Image;
use crate::geometry::{luminance, Rgb};
use crate::guiding::Guide;
use crate::integrator::{uniform, Integrator, PathStats};
use crate::sampling::splitmix64;
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
    /// Of those, samples per pixel spent on training a guide (not in the image).
    pub training_spp: u32,
    /// Ray and path counts.
    pub stats: PathStats,
    /// Wall-clock seconds spent tracing.
    pub seconds: f64,
}

/// Side of the square tiles that threads take one at a time.
pub const TILE_SIZE: u32 = 16;

/// The random stream of sample `sample` of pixel `pixel`.
pub fn sample_rng(seed: u64, pixel: u64, sample: u64) -> Pcg32 {
    let state = splitmix64(splitmix64(splitmix64(seed) ^ pixel) ^ sample);
    Pcg32::new(state, splitmix64(state) | 1)
}

/// Render `scene` with `integrator`, guided by `guide`. `progress` is called with the fraction
/// done after every tile.
pub fn render<G: Guide + ?Sized>(
    scene: &Scene,
    integrator: &Integrator,
    budget: Budget,
    seed: u64,
    guide: &mut G,
    progress: &(dyn Fn(f64) + Sync),
) -> RenderOutput {
    let (w, h) = (scene.camera.width(), scene.camera.height());
    let mut sums = vec![[0.0f64; 4]; w as usize * h as usize];
    let mut stats = PathStats::default();
    let start = Instant::now();
    let spp = render_passes(
        scene, integrator, budget, seed, 0, guide, true, &mut sums, &mut stats, start, progress,
    );
    RenderOutput {
        image: average(w, h, &sums, spp),
        spp,
        training_spp: 0,
        stats,
        seconds: start.elapsed().as_secs_f64(),
    }
}

/// Adds the passes of `budget` to `sums`, from sample index `first` on: one pass of `n` spp,
/// or one-spp passes until `t` seconds after `start`. With `hooks`, the guide's iteration
/// hooks run around every pass. `progress` gets the fraction of the passes done (of the time,
/// for a time budget). Returns the samples per pixel added.
#[allow(clippy::too_many_arguments)]
fn render_passes<G: Guide + ?Sized>(
    scene: &Scene,
    integrator: &Integrator,
    budget: Budget,
    seed: u64,
    first: u32,
    guide: &mut G,
    hooks: bool,
    sums: &mut [[f64; 4]],
    stats: &mut PathStats,
    start: Instant,
    progress: &(dyn Fn(f64) + Sync),
) -> u32 {
    let mut spp = 0u32;
    let mut iteration = 0usize;
    loop {
        let count = match budget {
            Budget::Samples(n) => n,
            Budget::Seconds(_) => 1,
        };
        if hooks {
            guide.begin_iteration(iteration);
        }
        let pass_stats = render_pass(
            scene,
            integrator,
            seed,
            first + spp,
            count,
            &*guide,
            sums,
            &|f| match budget {
                Budget::Samples(_) => progress(f),
                Budget::Seconds(t) => progress((start.elapsed().as_secs_f64() / t).min(1.0)),
            },
        );
        if hooks {
            guide.end_iteration(iteration);
        }
        stats.merge(&pass_stats);
        spp += count;
        iteration += 1;
        match budget {
            Budget::Samples(_) => break,
            Budget::Seconds(t) if start.elapsed().as_secs_f64() >= t => break,
            Budget::Seconds(_) => {}
        }
    }
    spp
}

/// The passes of a guided render of `spp` samples per pixel: training passes of 1, 2, 4, …
/// spp, as many as fit into half of the budget, then one final pass with the rest (at least
/// half). This is Practical Path Guiding's schedule (Müller et al. 2017, §5.3): every
/// training pass doubles the data the next distribution is learned from.
pub fn training_schedule(spp: u32) -> (Vec<u32>, u32) {
    let mut passes = Vec::new();
    let mut used = 0u32;
    let mut next = 1u32;
    while used + next <= spp / 2 {
        passes.push(next);
        used += next;
        next *= 2;
    }
    (passes, spp - used)
}

/// A guided render: the guide learns during training passes (see [`training_schedule`]; with
/// a time budget, doubling passes for the first half of the time), then stops learning for a
/// final phase. Every pass is an unbiased image whatever the guide had learned by then; the
/// result combines them by inverse variance ([`combine`]'s rule), so the training passes are
/// not wasted. `spp` counts all passes.
pub fn render_guided<G: Guide + ?Sized>(
    scene: &Scene,
    integrator: &Integrator,
    budget: Budget,
    seed: u64,
    guide: &mut G,
    progress: &(dyn Fn(f64) + Sync),
) -> RenderOutput {
    let (w, h) = (scene.camera.width(), scene.camera.height());
    let start = Instant::now();
    let mut stats = PathStats::default();
    let mut spp = 0u32;
    // Every pass's pixel sums, kept for the final combination.
    let mut passes: Vec<Pass> = Vec::new();
    let schedule = match budget {
        Budget::Samples(n) => training_schedule(n).0,
        Budget::Seconds(_) => Vec::new(),
    };
    // The next training pass's samples per pixel, or `None` when training is over.
    let next_pass = |iteration: usize, spp: u32| match budget {
        Budget::Samples(_) => schedule.get(iteration).copied(),
        Budget::Seconds(t) => {
            // Doubling passes while the next one ends within half of the time.
            let count = 1u32 << iteration.min(31);
            let elapsed = start.elapsed().as_secs_f64();
            let estimate = elapsed / f64::from(spp.max(1)) * f64::from(count);
            (iteration == 0 || elapsed + estimate <= t / 2.0).then_some(count)
        }
    };
    let overall = |done: u32, f: f64, count: u32| match budget {
        Budget::Samples(n) => progress((f64::from(done) + f * f64::from(count)) / f64::from(n)),
        Budget::Seconds(t) => progress((start.elapsed().as_secs_f64() / t).min(1.0)),
    };
    let mut iteration = 0usize;
    while let Some(count) = next_pass(iteration, spp) {
        guide.begin_iteration(iteration);
        let mut sums = vec![[0.0f64; 4]; w as usize * h as usize];
        let s = render_pass(
            scene,
            integrator,
            seed,
            spp,
            count,
            &*guide,
            &mut sums,
            &|f| overall(spp, f, count),
        );
        passes.push((count, sums));
        guide.end_iteration(iteration);
        stats.merge(&s);
        spp += count;
        iteration += 1;
    }
    guide.end_training();
    let training_spp = spp;
    let rest = match budget {
        Budget::Samples(n) => Budget::Samples(n - training_spp),
        seconds => seconds,
    };
    let mut sums = vec![[0.0f64; 4]; w as usize * h as usize];
    let final_spp = render_passes(
        scene,
        integrator,
        rest,
        seed,
        training_spp,
        guide,
        false,
        &mut sums,
        &mut stats,
        start,
        &|f| match rest {
            Budget::Samples(n) => overall(training_spp, f, n),
            Budget::Seconds(_) => progress(f),
        },
    );
    passes.push((final_spp, sums));
    RenderOutput {
        image: combine(w, h, &passes),
        spp: training_spp + final_spp,
        training_spp,
        stats,
        seconds: start.elapsed().as_secs_f64(),
    }
}

/// A pass's samples per pixel and pixel sums.
type Pass = (u32, Vec<[f64; 4]>);

/// Variance of a pass's pixel means, averaged over the image (of the luminance; `None` for
/// a pass of one sample, whose pixels give no variance estimate).
fn pass_variance(spp: u32, sums: &[[f64; 4]]) -> Option<f64> {
    if spp < 2 || sums.is_empty() {
        return None;
    }
    let n = f64::from(spp);
    let total: f64 = sums
        .iter()
        .map(|s| {
            let mean = f64::from(luminance(Rgb::new(s[0] as f32, s[1] as f32, s[2] as f32))) / n;
            ((s[3] / n - mean * mean) * n / (n - 1.0)).max(0.0) / n
        })
        .sum();
    Some(total / sums.len() as f64)
}

/// The passes of a guided render combined with weights inversely proportional to their
/// image-averaged variance (as production path guiding does, Müller 2019, "Practical Path
/// Guiding in Production"): every pass is an unbiased image, so any fixed weights keep the
/// result unbiased, and weights estimated from whole images are near-constant. One-sample
/// passes (no variance estimate) are left out; when some pass has no noise at all (e.g. a
/// black image), the passes are pooled by sample count instead.
fn combine(width: u32, height: u32, passes: &[Pass]) -> Image {
    let estimates: Vec<(f64, &Pass)> = passes
        .iter()
        .filter_map(|p| pass_variance(p.0, &p.1).map(|v| (v, p)))
        .collect();
    let pool = |weights: Vec<(f64, &Pass)>| {
        let total: f64 = weights.iter().map(|w| w.0).sum();
        let mut pixels = vec![Rgb::ZERO; width as usize * height as usize];
        for (wt, (spp, sums)) in &weights {
            let scale = wt / total / f64::from(*spp);
            for (p, s) in pixels.iter_mut().zip(sums) {
                *p += Rgb::new(
                    (s[0] * scale) as f32,
                    (s[1] * scale) as f32,
                    (s[2] * scale) as f32,
                );
            }
        }
        Image {
            width,
            height,
            pixels,
        }
    };
    if !estimates.is_empty() && estimates.iter().all(|(v, _)| *v > 0.0 && v.is_finite()) {
        pool(estimates.into_iter().map(|(v, p)| (1.0 / v, p)).collect())
    } else {
        pool(passes.iter().map(|p| (f64::from(p.0), p)).collect())
    }
}

/// The image of pixel sums over `spp` samples each.
fn average(width: u32, height: u32, sums: &[[f64; 4]], spp: u32) -> Image {
    let inv = 1.0 / f64::from(spp.max(1));
    Image {
        width,
        height,
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
    }
}

/// Paths a wave traces together, at least (whole tiles are never split).
pub const WAVE_PATHS: usize = 4096;

/// Waves rendered in parallel before their guide records are handed over, in wave order.
const WAVES_PER_GROUP: usize = 16;

/// Add samples `first_sample..first_sample + count` of every pixel to `sums`: per pixel the
/// sums of the three channels and of the squared luminance (for variance estimates).
///
/// Tiles are grouped into waves of at least [`WAVE_PATHS`] paths that the integrator traces
/// bounce by bounce (so a guide sees large batches); waves run in parallel, a group of them at
/// a time, and their training records reach the guide in wave order, from this thread, so
/// training does not depend on the thread count.
#[allow(clippy::too_many_arguments)]
fn render_pass<G: Guide + ?Sized>(
    scene: &Scene,
    integrator: &Integrator,
    seed: u64,
    first_sample: u32,
    count: u32,
    guide: &G,
    sums: &mut [[f64; 4]],
    progress: &(dyn Fn(f64) + Sync),
) -> PathStats {
    let (w, h) = (scene.camera.width(), scene.camera.height());
    let tiles: Vec<(u32, u32)> = (0..h.div_ceil(TILE_SIZE))
        .flat_map(|ty| (0..w.div_ceil(TILE_SIZE)).map(move |tx| (tx * TILE_SIZE, ty * TILE_SIZE)))
        .collect();
    let tile_paths = (TILE_SIZE * TILE_SIZE) as usize * count as usize;
    let tiles_per_wave = WAVE_PATHS.div_ceil(tile_paths.max(1)).max(1);
    let waves: Vec<&[(u32, u32)]> = tiles.chunks(tiles_per_wave).collect();
    let done = AtomicU64::new(0);
    let n_waves = waves.len() as f64;
    let wants_records = guide.wants_records();
    let mut stats = PathStats::default();
    for group in waves.chunks(WAVES_PER_GROUP) {
        let results: Vec<_> = group
            .par_iter()
            .map(|wave| {
                let mut stats = PathStats::default();
                let mut pixels = Vec::new();
                let mut rays = Vec::new();
                let mut rngs = Vec::new();
                for &(x0, y0) in wave.iter() {
                    for y in y0..(y0 + TILE_SIZE).min(h) {
                        for x in x0..(x0 + TILE_SIZE).min(w) {
                            let pixel = u64::from(y) * u64::from(w) + u64::from(x);
                            pixels.push(pixel as usize);
                            for s in first_sample..first_sample + count {
                                let mut rng = sample_rng(seed, pixel, u64::from(s));
                                rays.push(scene.camera.ray(
                                    x as f32 + uniform(&mut rng),
                                    y as f32 + uniform(&mut rng),
                                ));
                                rngs.push(rng);
                            }
                        }
                    }
                }
                let mut radiance = vec![Rgb::ZERO; rays.len()];
                let mut records = Vec::new();
                let batch = guide.batch_paths().max(1);
                for ((rays, rngs), radiance) in rays
                    .chunks(batch)
                    .zip(rngs.chunks_mut(batch))
                    .zip(radiance.chunks_mut(batch))
                {
                    integrator.trace(
                        scene,
                        rays,
                        rngs,
                        guide,
                        &mut stats,
                        wants_records.then_some(&mut records),
                        radiance,
                    );
                }
                stats.paths += rays.len() as u64;
                let per_pixel = count as usize;
                let out: Vec<(usize, [f64; 4])> = pixels
                    .iter()
                    .zip(radiance.chunks(per_pixel.max(1)))
                    .map(|(&pixel, ls)| {
                        let mut sum = [0.0f64; 4];
                        for l in ls {
                            if l.is_finite() {
                                for c in 0..3 {
                                    sum[c] += f64::from(l[c]);
                                }
                                sum[3] += f64::from(luminance(*l)).powi(2);
                            } else {
                                stats.invalid += 1;
                            }
                        }
                        (pixel, sum)
                    })
                    .collect();
                let d = done.fetch_add(1, Ordering::Relaxed) + 1;
                progress(d as f64 / n_waves);
                (out, stats, records)
            })
            .collect();
        for (out, s, records) in results {
            stats.merge(&s);
            for (i, v) in out {
                for c in 0..4 {
                    sums[i][c] += v[c];
                }
            }
            if !records.is_empty() {
                guide.record(&records);
            }
        }
    }
    stats
}

#[cfg(test)]
mod tests {
    use super::{combine, pass_variance, training_schedule, Pass};

    /// A pass of `n` (even) grey samples per pixel, half `m − d` and half `m + d`, on 4 pixels.
    fn pass(n: u32, m: f64, d: f64) -> Pass {
        let (lo, hi) = (m - d, m + d);
        let sum = f64::from(n / 2) * (lo + hi);
        let sq = f64::from(n / 2) * (lo * lo + hi * hi);
        (n, vec![[sum, sum, sum, sq]; 4])
    }

    #[test]
    fn passes_are_combined_by_inverse_variance() {
        // Sample variance d²·n/(n − 1); variance of the pixel mean d²/(n − 1).
        let v = pass_variance(4, &pass(4, 1.0, 0.3).1).unwrap();
        assert!((v - 0.09 / 3.0).abs() < 1e-6, "{v}");
        assert_eq!(pass_variance(1, &pass(1, 1.0, 0.0).1), None);
        // Variances 0.09/3 = 0.03 and 0.36/3 = 0.12: weights 0.8 and 0.2.
        let img = combine(2, 2, &[pass(4, 1.0, 0.3), pass(4, 2.0, 0.6)]);
        for p in &img.pixels {
            assert!((p.x - 1.2).abs() < 1e-5, "{p:?}");
        }
        // A one-sample pass has no variance estimate and is left out.
        let img = combine(
            2,
            2,
            &[(1, vec![[9.0, 9.0, 9.0, 81.0]; 4]), pass(4, 1.0, 0.3)],
        );
        assert!((img.pixels[0].x - 1.0).abs() < 1e-6);
        // Noise-free passes (a black image) are pooled by sample count.
        let img = combine(2, 2, &[pass(2, 0.0, 0.0), pass(6, 0.0, 0.0)]);
        assert!(img.pixels.iter().all(|p| p.x == 0.0));
        let img = combine(2, 2, &[pass(2, 1.0, 0.0), pass(6, 3.0, 0.0)]);
        assert!((img.pixels[0].x - 2.5).abs() < 1e-6, "{:?}", img.pixels[0]);
    }

    #[test]
    fn training_takes_doubling_passes_within_half_of_the_budget() {
        assert_eq!(training_schedule(64), (vec![1, 2, 4, 8, 16], 33));
        assert_eq!(training_schedule(16), (vec![1, 2, 4], 9));
        assert_eq!(training_schedule(1), (vec![], 1));
        assert_eq!(training_schedule(2), (vec![1], 1));
        for spp in 1..300 {
            let (passes, rest) = training_schedule(spp);
            let used: u32 = passes.iter().sum();
            assert_eq!(used + rest, spp);
            assert!(rest >= used && rest >= 1, "spp {spp}");
            assert!(passes.iter().enumerate().all(|(i, &p)| p == 1 << i));
        }
    }
}
