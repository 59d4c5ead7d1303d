//! The render loop: tiles of the image traced in parallel, pass after pass, until a sample
//! count or a time budget is reached, with a guide learning between passes.
//!
//! Every sample has its own random stream, seeded from `(seed, pixel, sample index)` by the
//! SplitMix64 finaliser ([`splitmix64`], Steele et al. 2014), so an image depends only on the
//! seed and the sample count, never on the number of threads or on how samples are split into
//! passes. A sample counts in its own pixel only: its position is drawn from the scene's
//! reconstruction filter around the pixel, with the filter's weight (`filter.rs`; a box filter
//! lands uniformly in the pixel).
//!
//! Across processes (MPI ranks, [`render_across`]) the waves of every pass's first sample slice
//! are dealt out to the ranks in turn, and each rank traces its tiles in every slice; the pixel sums are then summed over the ranks — each pixel's from the one rank
//! that traced it plus zeros, so the image is bit-identical to the single-process one — and a
//! learning guide gets the statistics of all ranks, in rank order, so every rank applies the same
//! update and holds the same guide.
//!
//! [`render`] is the one entry point; [`RenderOptions::schedule`] says whether the guide trains
//! in passes of its own first ([`schedule`], whose passes are then combined by inverse variance,
//! [`mod@combine`]) or learns, if it wants to, after every pass of a plain render.

use std::ops::Range;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

use glam::Vec2;
use nis::comm::Comm;
use rand_pcg::Pcg32;
use rayon::prelude::*;

use crate::film::Image;
use crate::geometry::Rgb;
use crate::guiding::factory::AnyGuide;
use crate::guiding::{Guide, GuideStatistics};
use crate::path_tracer::{uniform, PathStats, PathTracer, Wavefront};
use crate::sampling::splitmix64;
use crate::scene::Scene;

pub mod combine;
pub mod schedule;

use combine::{average, combine, PassSums, PixelSum};
use schedule::TrainingPasses;
pub use schedule::{training_schedule, TrainingSchedule};

/// How long to render.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Budget {
    /// Exactly this many samples per pixel (in one pass, unless a guide trains first).
    Samples(u32),
    /// Passes until this many seconds have passed (at least one): a learning guide's are of
    /// one sample, the others each take about half of the time left ([`schedule`]).
    Seconds(f64),
}

/// How the passes of a render are arranged.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Schedule {
    /// The whole budget renders the image: one pass of `n` samples per pixel, or passes until
    /// the time is up, all averaged. A guide that wants records learns from every
    /// pass after it ends (so several renders can train it).
    #[default]
    Plain,
    /// A guided render: training passes ([`schedule`]) while the guide learns after each, then
    /// the guide stops learning ([`Guide::end_training`]) for a final phase with the rest of the
    /// budget. Every pass is an unbiased image whatever the guide had learned by then; the
    /// result combines them by inverse variance ([`mod@combine`]), so the training passes are not
    /// wasted.
    Training,
}

/// Everything a render is asked for, besides the scene, the guide and progress reports.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RenderOptions {
    /// The path tracer's settings.
    pub path_tracer: PathTracer,
    /// How long to render; samples per pixel count all passes, training included.
    pub budget: Budget,
    /// Seed of every sample's random stream.
    pub seed: u64,
    /// Plain, or training passes first.
    pub schedule: Schedule,
}

/// A finished render.
#[derive(Clone, Debug)]
pub struct RenderOutput {
    /// Mean of the samples of each pixel (for a training schedule, the inverse-variance
    /// combination of the passes).
    pub image: Image,
    /// Samples per pixel taken.
    pub spp: u32,
    /// Of those, samples per pixel of the training passes.
    pub training_spp: u32,
    /// Ray and path counts.
    pub stats: PathStats,
    /// Wall-clock seconds spent tracing.
    pub seconds: f64,
}

/// Side of the square tiles that threads take one at a time.
pub const TILE_SIZE: u32 = 16;

/// Paths a wave traces together, at least (whole tiles are never split across waves; a tile's
/// samples are, once one tile alone has more paths than this).
pub const WAVE_PATHS: usize = 4096;

/// Samples per pixel a wave traces at most: a pass of more spp runs as consecutive slices of
/// this many, so the paths in flight (rays, random streams, radiance) and with them the memory
/// stay bounded whatever the sample count.
const WAVE_SPP: u32 = (WAVE_PATHS / (TILE_SIZE * TILE_SIZE) as usize) as u32;

/// Waves rendered in parallel before their guide statistics are merged, in wave order.
const WAVES_PER_GROUP: usize = 16;

/// The random stream of sample `sample` of pixel `pixel`.
pub fn sample_rng(seed: u64, pixel: u64, sample: u64) -> Pcg32 {
    let state = splitmix64(splitmix64(splitmix64(seed) ^ pixel) ^ sample);
    Pcg32::new(state, splitmix64(state) | 1)
}

/// Render `scene` as `options` say, guided by `guide`. `progress` is called with the fraction
/// done after every wave of paths.
///
/// ```
/// use nis_render::path_tracer::{PathTracer, Strategy};
/// use nis_render::render::{render, Budget, RenderOptions, Schedule};
/// let mut scene = nis_render::scenes::load("cornell-box").unwrap();
/// scene.camera.set_resolution(8, 8);
/// let options = RenderOptions {
///     path_tracer: PathTracer::from_scene(&scene, Strategy::Mis),
///     budget: Budget::Samples(4),
///     seed: 1,
///     schedule: Schedule::Training,
/// };
/// let out = render(&scene, &options, &mut nis_render::guiding::NoGuide, &|_| {});
/// assert_eq!((out.spp, out.training_spp), (4, 1));
/// ```
pub fn render<G: Guide + ?Sized>(
    scene: &Scene,
    options: &RenderOptions,
    guide: &mut G,
    progress: &(dyn Fn(f64) + Sync),
) -> RenderOutput {
    render_across(scene, options, guide, &Comm::default(), progress)
}

/// [`render_across`] with a guide of any method ([`crate::guiding::factory::GuideSpec::build`]).
pub fn render_any(
    scene: &Scene,
    options: &RenderOptions,
    guide: &mut AnyGuide,
    comm: &Comm,
    progress: &(dyn Fn(f64) + Sync),
) -> RenderOutput {
    match guide {
        AnyGuide::None(g) => render_across(scene, options, g, comm, progress),
        AnyGuide::Ppg(g) => render_across(scene, options, g, comm, progress),
        AnyGuide::Gmm(g) => render_across(scene, options, g, comm, progress),
        AnyGuide::Neural(g) => render_across(scene, options, &mut **g, comm, progress),
    }
}

/// [`render`] split over the ranks of `comm` (see the module documentation): every rank calls it
/// with the same arguments and gets the whole image (and the same trained guide). A time budget
/// ends when rank 0's clock says so.
pub fn render_across<G: Guide + ?Sized>(
    scene: &Scene,
    options: &RenderOptions,
    guide: &mut G,
    comm: &Comm,
    progress: &(dyn Fn(f64) + Sync),
) -> RenderOutput {
    let mut renderer = Renderer {
        scene,
        options,
        comm,
        start: Instant::now(),
        stats: PathStats::default(),
    };
    let (w, h) = (scene.camera.width(), scene.camera.height());
    let (image, spp, training_spp) = match options.schedule {
        Schedule::Plain => {
            let mut sums = vec![PixelSum::default(); w as usize * h as usize];
            let spp = renderer.passes(guide, options.budget, 0, true, &mut sums, progress);
            (average(w, h, &sums, spp), spp, 0)
        }
        Schedule::Training => renderer.train_then_render(guide, progress),
    };
    RenderOutput {
        image,
        spp,
        training_spp,
        stats: renderer.stats,
        seconds: renderer.start.elapsed().as_secs_f64(),
    }
}

/// One render in progress: what its passes share, and its counters.
struct Renderer<'a> {
    scene: &'a Scene,
    options: &'a RenderOptions,
    comm: &'a Comm,
    start: Instant,
    stats: PathStats,
}

/// The paths a wave traces: these samples of every pixel of these tiles.
struct Wave<'a> {
    samples: Range<u32>,
    tiles: &'a [(u32, u32)],
}

/// What one wave of paths produced.
struct WaveResult<S> {
    /// Pixel index and the sums of its samples.
    pixels: Vec<(usize, PixelSum)>,
    stats: PathStats,
    /// The guide's statistics of the wave's records.
    statistics: S,
}

impl Renderer<'_> {
    /// The passes of [`Schedule::Training`]: training passes, then the final phase. Returns the
    /// image, the samples per pixel and those of training.
    fn train_then_render<G: Guide + ?Sized>(
        &mut self,
        guide: &mut G,
        progress: &(dyn Fn(f64) + Sync),
    ) -> (Image, u32, u32) {
        let (w, h) = (self.scene.camera.width(), self.scene.camera.height());
        let budget = self.options.budget;
        let start = self.start;
        let overall = |done: u32, f: f64, count: u32| match budget {
            Budget::Samples(n) => progress((f64::from(done) + f * f64::from(count)) / f64::from(n)),
            Budget::Seconds(t) => progress((start.elapsed().as_secs_f64() / t).min(1.0)),
        };
        // Every pass's pixel sums, kept for the final combination.
        let mut passes: Vec<PassSums> = Vec::new();
        let training = TrainingPasses::new(budget, start);
        let mut spp = 0u32;
        while let Some(count) = self.rank0_decides(training.next(passes.len(), spp)) {
            let mut sums = vec![PixelSum::default(); w as usize * h as usize];
            let done = spp;
            self.pass(guide, spp..spp + count, true, &mut sums, &|f| {
                overall(done, f, count)
            });
            passes.push(PassSums {
                spp: count,
                pixels: sums,
            });
            spp += count;
        }
        guide.end_training();
        let training_spp = spp;
        let rest = match budget {
            Budget::Samples(n) => Budget::Samples(n - training_spp),
            seconds => seconds,
        };
        let mut sums = vec![PixelSum::default(); w as usize * h as usize];
        let final_spp = self.passes(
            guide,
            rest,
            training_spp,
            false,
            &mut sums,
            &|f| match rest {
                Budget::Samples(n) => overall(training_spp, f, n),
                Budget::Seconds(_) => progress(f),
            },
        );
        passes.push(PassSums {
            spp: final_spp,
            pixels: sums,
        });
        (
            combine(w, h, &passes),
            training_spp + final_spp,
            training_spp,
        )
    }

    /// Adds the passes of `budget` to `sums`, from sample index `first` on: one pass of `n` spp,
    /// or passes until the time is up (of one spp for a guide that learns, else sized by
    /// [`schedule::rendering_pass_spp`]). With `learn`, a guide that wants records learns after
    /// every pass.
    /// `progress` gets the fraction of the passes done (of the time, for a time budget).
    /// Returns the samples per pixel added.
    fn passes<G: Guide + ?Sized>(
        &mut self,
        guide: &mut G,
        budget: Budget,
        first: u32,
        learn: bool,
        sums: &mut [PixelSum],
        progress: &(dyn Fn(f64) + Sync),
    ) -> u32 {
        let start = self.start;
        let phase = Instant::now();
        let learning = learn && guide.wants_records();
        let mut spp = 0u32;
        loop {
            let count = match budget {
                Budget::Samples(n) => n,
                Budget::Seconds(_) if learning => 1,
                Budget::Seconds(t) => {
                    let left = t - start.elapsed().as_secs_f64();
                    let mine =
                        schedule::rendering_pass_spp(spp, phase.elapsed().as_secs_f64(), left);
                    self.rank0_decides(Some(mine)).unwrap_or(1)
                }
            };
            let samples = first + spp..first + spp + count;
            self.pass(guide, samples, learn, sums, &|f| match budget {
                Budget::Samples(_) => progress(f),
                Budget::Seconds(t) => progress((start.elapsed().as_secs_f64() / t).min(1.0)),
            });
            spp += count;
            match budget {
                Budget::Samples(_) => break,
                Budget::Seconds(t) if self.time_is_up(t) => break,
                Budget::Seconds(_) => {}
            }
        }
        spp
    }

    /// Rank 0's `choice` on every rank (a time budget's passes follow rank 0's clock).
    fn rank0_decides(&self, choice: Option<u32>) -> Option<u32> {
        if self.comm.size() == 1 {
            return choice;
        }
        // Only rank 0 adds a non-zero number: the sum is its choice, exactly.
        let mine = match choice {
            Some(n) if self.comm.is_root() => f64::from(n) + 1.0,
            _ => 0.0,
        };
        let sum = self.comm.sum(mine);
        if sum > 0.0 {
            Some(sum as u32 - 1)
        } else {
            None
        }
    }

    /// Whether `seconds` have passed since the start, by rank 0's clock (so that all ranks stop
    /// after the same pass).
    fn time_is_up(&self, seconds: f64) -> bool {
        let up = self.comm.is_root() && self.start.elapsed().as_secs_f64() >= seconds;
        self.comm.any(up)
    }

    /// Add the samples `samples` of every pixel to `sums`; with `learn`, a guide that wants
    /// records learns from the pass's paths once it is done.
    ///
    /// The samples are cut into slices of at most `WAVE_SPP` per pixel, and each slice's tiles
    /// into waves of at least [`WAVE_PATHS`] paths that the path tracer traces
    /// bounce by bounce (so a guide sees large batches); waves run in parallel, a group of them
    /// at a time, and accumulate their records into guide statistics of their own, which are
    /// merged in wave order, so training does not depend on the thread count.
    fn pass<G: Guide + ?Sized>(
        &mut self,
        guide: &mut G,
        samples: Range<u32>,
        learn: bool,
        sums: &mut [PixelSum],
        progress: &(dyn Fn(f64) + Sync),
    ) {
        let scene = self.scene;
        let (w, h) = (scene.camera.width(), scene.camera.height());
        let tiles: Vec<(u32, u32)> = (0..h.div_ceil(TILE_SIZE))
            .flat_map(|ty| {
                (0..w.div_ceil(TILE_SIZE)).map(move |tx| (tx * TILE_SIZE, ty * TILE_SIZE))
            })
            .collect();
        // Sample slices of at most WAVE_SPP, each cut into waves of whole tiles.
        let slices: Vec<Range<u32>> = samples
            .clone()
            .step_by(WAVE_SPP as usize)
            .map(|s| s..(s + WAVE_SPP).min(samples.end))
            .collect();
        let tiles_per_wave = |slice: &Range<u32>| {
            let tile_paths = (TILE_SIZE * TILE_SIZE) as usize * slice.len();
            WAVE_PATHS.div_ceil(tile_paths.max(1)).max(1)
        };
        // This rank's tiles: the first slice's waves dealt out to the ranks in turn, every
        // size-th from its rank on. A tile keeps its rank in every slice, so each pixel is traced
        // by one rank, its slices in order, as in one process.
        let (rank, size) = (self.comm.rank(), self.comm.size());
        let first = slices.first().map_or(1, tiles_per_wave);
        let tiles: Vec<(u32, u32)> = tiles
            .chunks(first)
            .skip(rank)
            .step_by(size)
            .flatten()
            .copied()
            .collect();
        let waves: Vec<Wave> = slices
            .iter()
            .flat_map(|slice| {
                tiles.chunks(tiles_per_wave(slice)).map(move |tiles| Wave {
                    samples: slice.clone(),
                    tiles,
                })
            })
            .collect();
        let done = AtomicU64::new(0);
        let n_waves = waves.len() as f64;
        let learn = learn && guide.wants_records();
        let mut statistics = G::Statistics::default();
        let shared: &G = guide;
        // This pass's pixel sums, summed over the ranks before they join `sums`.
        let mut pass_sums = vec![PixelSum::default(); sums.len()];
        let mut stats = PathStats::default();
        for group in waves.chunks(WAVES_PER_GROUP) {
            let results: Vec<WaveResult<G::Statistics>> = group
                .par_iter()
                .map(|wave| {
                    let result = self.wave(shared, wave.tiles, wave.samples.clone(), learn);
                    let d = done.fetch_add(1, Ordering::Relaxed) + 1;
                    progress(d as f64 / n_waves);
                    result
                })
                .collect();
            for result in results {
                stats.merge(&result.stats);
                for (i, v) in result.pixels {
                    pass_sums[i].merge(&v);
                }
                statistics.merge(result.statistics);
            }
        }
        self.stats.merge(&sum_stats(self.comm, stats));
        sum_pixels(self.comm, &mut pass_sums);
        for (s, p) in sums.iter_mut().zip(&pass_sums) {
            s.merge(p);
        }
        if learn {
            let statistics = gather_statistics(self.comm, statistics);
            // On one of the pool's threads (`rayon::scope` from outside the pool runs there),
            // as the NIS integrator trains: the neural guide's small steps would otherwise spend
            // much of their time handing their loops over to the pool (docs/results/guiding.md).
            rayon::scope(|_| guide.update(statistics));
        }
    }

    /// Trace the samples `samples` of every pixel of the tiles `wave`.
    fn wave<G: Guide + ?Sized>(
        &self,
        guide: &G,
        wave: &[(u32, u32)],
        samples: Range<u32>,
        learn: bool,
    ) -> WaveResult<G::Statistics> {
        let scene = self.scene;
        let (w, h) = (scene.camera.width(), scene.camera.height());
        let mut stats = PathStats::default();
        let mut pixels = Vec::new();
        let mut rays = Vec::new();
        let mut rngs = Vec::new();
        let mut weights = Vec::new();
        let filter = &scene.settings.filter;
        for &(x0, y0) in wave {
            for y in y0..(y0 + TILE_SIZE).min(h) {
                for x in x0..(x0 + TILE_SIZE).min(w) {
                    let pixel = u64::from(y) * u64::from(w) + u64::from(x);
                    pixels.push(pixel as usize);
                    for s in samples.clone() {
                        let mut rng = sample_rng(self.options.seed, pixel, u64::from(s));
                        let (dx, wx) = filter.sample(uniform(&mut rng));
                        let (dy, wy) = filter.sample(uniform(&mut rng));
                        // Only a thin lens draws its sample: other renders keep their streams.
                        let lens = if scene.camera.needs_lens() {
                            Vec2::new(uniform(&mut rng), uniform(&mut rng))
                        } else {
                            Vec2::ZERO
                        };
                        rays.push(scene.camera.ray(x as f32 + dx, y as f32 + dy, lens));
                        weights.push(wx * wy);
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
            let paths = Wavefront {
                rays,
                rngs,
                radiance,
            };
            let records = learn.then_some(&mut records);
            self.options
                .path_tracer
                .trace(scene, paths, guide, &mut stats, records);
        }
        stats.paths += rays.len() as u64;
        let per_pixel = samples.len().max(1);
        let pixels = pixels
            .iter()
            .zip(radiance.chunks(per_pixel).zip(weights.chunks(per_pixel)))
            .map(|(&pixel, (ls, ws))| {
                let mut sum = PixelSum::default();
                for (l, &w) in ls.iter().zip(ws) {
                    if l.is_finite() {
                        sum.add_sample(*l * w);
                    } else {
                        stats.invalid += 1;
                    }
                }
                (pixel, sum)
            })
            .collect();
        let mut statistics = G::Statistics::default();
        if !records.is_empty() {
            guide.accumulate(&records, &mut statistics);
        }
        WaveResult {
            pixels,
            stats,
            statistics,
        }
    }
}

/// Counters summed over the ranks (exact: they stay far below 2⁵³).
fn sum_stats(comm: &Comm, s: PathStats) -> PathStats {
    if comm.size() == 1 {
        return s;
    }
    let mut v = [s.rays, s.shadow_rays, s.paths, s.invalid].map(|c| c as f64);
    comm.sum_f64(&mut v);
    let [rays, shadow_rays, paths, invalid] = v.map(|c| c as u64);
    PathStats {
        rays,
        shadow_rays,
        paths,
        invalid,
    }
}

/// Pixel sums summed over the ranks. Each pixel was traced by one rank and is zero on the
/// others, and x + 0 = x, so the sums are exactly those of one process.
fn sum_pixels(comm: &Comm, sums: &mut [PixelSum]) {
    if comm.size() == 1 {
        return;
    }
    let mut flat: Vec<f64> = sums
        .iter()
        .flat_map(|s| [s.rgb[0], s.rgb[1], s.rgb[2], s.luminance_sq])
        .collect();
    comm.sum_f64(&mut flat);
    for (s, v) in sums.iter_mut().zip(flat.chunks_exact(4)) {
        *s = PixelSum {
            rgb: [v[0], v[1], v[2]],
            luminance_sq: v[3],
        };
    }
}

/// Every rank's guide statistics merged in rank order, on every rank.
fn gather_statistics<S: GuideStatistics>(comm: &Comm, statistics: S) -> S {
    if comm.size() == 1 {
        return statistics;
    }
    let mut all = S::default();
    for b in comm.all_gather_bytes(crate::guiding::to_bytes(&statistics)) {
        all.merge(
            crate::guiding::from_bytes(&b)
                .expect("every rank serialises its statistics with the same build"),
        );
    }
    all
}
