//! The guiding comparison's report: per scene and method the mean over seeds of MAPE, relMSE
//! and the share of far-off pixels with their range, a verdict line against the issue's
//! targets, and the montages of central crops with their error maps.

use nis_render::compare::{error_map, FAR_OFF_ERROR};
use nis_render::film::Image;
use nis_render::geometry::Rgb;

use super::{time_to_reach, Run, SeedRuns, Settings};
use crate::error::Result;
use crate::image::figure::ErrorTimePanel;
use crate::report;

/// One scene's renders over all seeds.
pub(super) struct SceneResult {
    pub name: String,
    /// Width and height of its renders.
    pub size: (u32, u32),
    /// Where its reference comes from.
    pub reference: String,
    /// File name of its montage in `img`.
    pub montage: String,
    pub seeds: Vec<SeedRuns>,
}

/// Mean, least and largest of some values.
#[derive(Clone, Copy, Debug, PartialEq)]
struct Spread {
    mean: f64,
    min: f64,
    max: f64,
}

impl Spread {
    fn of(values: impl Iterator<Item = f64>) -> Spread {
        let v: Vec<f64> = values.collect();
        let n = v.len().max(1) as f64;
        Spread {
            mean: v.iter().sum::<f64>() / n,
            min: v.iter().copied().fold(f64::INFINITY, f64::min),
            max: v.iter().copied().fold(f64::NEG_INFINITY, f64::max),
        }
    }

    /// `mean (min–max)` with `digits` decimals, the mean in bold when it is `best`; the
    /// range only when there are several values.
    fn cell(&self, best: f64, digits: usize) -> String {
        let mean = if self.mean == best {
            format!("**{:.digits$}**", self.mean)
        } else {
            format!("{:.digits$}", self.mean)
        };
        if self.min < self.max {
            format!("{mean} ({:.digits$}–{:.digits$})", self.min, self.max)
        } else {
            mean
        }
    }
}

/// Which renders of a seed a statistic reads.
#[derive(Clone, Copy)]
enum Budget {
    EqualSamples,
    EqualTime,
}

impl SceneResult {
    fn runs(&self, budget: Budget) -> impl Iterator<Item = &[Run]> {
        self.seeds.iter().map(move |s| match budget {
            Budget::EqualSamples => s.equal_spp.as_slice(),
            Budget::EqualTime => s.equal_time.as_slice(),
        })
    }

    /// The spread over seeds of `key` for method number `m`.
    fn spread(&self, budget: Budget, m: usize, key: fn(&Run) -> f64) -> Spread {
        Spread::of(self.runs(budget).map(|runs| key(&runs[m])))
    }

    /// The method number `m`'s error-vs-time curve averaged over seeds, point by point.
    fn mean_curve(&self, m: usize) -> Vec<(f64, f64)> {
        let points = self.seeds[0].curves[m].1.len();
        let n = self.seeds.len() as f64;
        (0..points)
            .map(|i| {
                let sum = self.seeds.iter().fold((0.0, 0.0), |acc, s| {
                    let (t, e) = s.curves[m].1[i];
                    (acc.0 + t, acc.1 + e)
                });
                (sum.0 / n, sum.1 / n)
            })
            .collect()
    }

    fn budget(&self) -> Spread {
        Spread::of(self.seeds.iter().map(|s| s.seconds))
    }

    /// The scene's panel of the error-vs-time plot: the seeds' mean curves.
    pub fn panel(&self) -> ErrorTimePanel {
        let curves = self.seeds[0]
            .curves
            .iter()
            .enumerate()
            .map(|(m, (method, _))| (method.clone(), self.mean_curve(m)))
            .collect();
        (self.name.clone(), self.budget().mean, curves)
    }

    fn method_index(&self, method: &str) -> Option<usize> {
        self.seeds[0]
            .equal_spp
            .iter()
            .position(|r| r.method == method)
    }

    /// The least mean over methods of `key`.
    fn best(&self, budget: Budget, key: fn(&Run) -> f64) -> f64 {
        (0..self.seeds[0].equal_spp.len())
            .map(|m| self.spread(budget, m, key).mean)
            .fold(f64::INFINITY, f64::min)
    }

    /// The table's rows of this scene.
    fn rows(&self, target_mape: Option<f64>) -> String {
        let mape: fn(&Run) -> f64 = |r| r.errors.mape;
        let relmse: fn(&Run) -> f64 = |r| r.errors.relmse;
        let far: fn(&Run) -> f64 = |r| 1e3 * r.errors.far_off;
        let seconds: fn(&Run) -> f64 = |r| r.output.seconds;
        let spp: fn(&Run) -> f64 = |r| f64::from(r.output.spp);
        let (s, t) = (Budget::EqualSamples, Budget::EqualTime);
        // Path tracing's mean MAPE at the budget, or the best method's without it.
        let target = target_mape.unwrap_or_else(|| {
            self.method_index("none")
                .map_or_else(|| self.best(t, mape), |m| self.spread(t, m, mape).mean)
        });
        let budget = self.budget();
        let mut rows = String::new();
        for (m, run) in self.seeds[0].equal_spp.iter().enumerate() {
            let reach = time_to_reach(&self.mean_curve(m), target)
                .map_or_else(|| "–".into(), |r| r.to_string());
            rows.push_str(&format!(
                "| {} | {} | {} | {} | {} | {:.2} | {:.2} | {:.0} | {} | {} | {} | {target:.4} in {reach} |\n",
                self.name,
                run.method,
                self.spread(s, m, mape).cell(self.best(s, mape), 4),
                self.spread(s, m, relmse).cell(self.best(s, relmse), 4),
                self.spread(s, m, far).cell(self.best(s, far), 2),
                self.spread(s, m, seconds).mean,
                budget.mean,
                self.spread(t, m, spp).mean,
                self.spread(t, m, mape).cell(self.best(t, mape), 4),
                self.spread(t, m, relmse).cell(self.best(t, relmse), 4),
                self.spread(t, m, far).cell(self.best(t, far), 2),
            ));
        }
        rows
    }
}

/// How `method` fares against the others over the scenes, by the targets: lowest mean
/// MAPE and relMSE at equal samples, ahead of path tracing at equal time, its time per sample
/// against path tracing's. `None` when `method` or path tracing did not run.
fn verdict(method: &str, results: &[SceneResult]) -> Option<String> {
    let mape: fn(&Run) -> f64 = |r| r.errors.mape;
    let relmse: fn(&Run) -> f64 = |r| r.errors.relmse;
    let seconds: fn(&Run) -> f64 = |r| r.output.seconds;
    let (s, t) = (Budget::EqualSamples, Budget::EqualTime);
    let n = results.len();
    let (mut lowest_mape, mut lowest_relmse, mut ahead_mape, mut ahead_relmse) = (0, 0, 0, 0);
    let mut cost = Vec::new();
    for r in results {
        let (g, pt) = (r.method_index(method)?, r.method_index("none")?);
        lowest_mape += usize::from(r.spread(s, g, mape).mean == r.best(s, mape));
        lowest_relmse += usize::from(r.spread(s, g, relmse).mean == r.best(s, relmse));
        ahead_mape += usize::from(r.spread(t, g, mape).mean < r.spread(t, pt, mape).mean);
        ahead_relmse += usize::from(r.spread(t, g, relmse).mean < r.spread(t, pt, relmse).mean);
        cost.push(r.spread(s, g, seconds).mean / r.spread(s, pt, seconds).mean);
    }
    let cost = Spread::of(cost.into_iter());
    Some(format!(
        "**{method}** over {n} scenes (means over seeds): lowest MAPE at equal samples on \
         {lowest_mape}, lowest relMSE on {lowest_relmse}; at equal time ahead of path tracing \
         in MAPE on {ahead_mape} and in relMSE on {ahead_relmse}; its time at equal samples \
         {:.2}–{:.2}× path tracing's (mean {:.2}×).",
        cost.min, cost.max, cost.mean
    ))
}

/// The section's text: how the comparison is run, the table, the verdict, the error-vs-time
/// plot `plot` and the montages.
pub(super) fn section(
    args: &Settings,
    methods: &[String],
    results: &[SceneResult],
    plot: &str,
) -> String {
    let budget = match args.seconds {
        Some(s) => format!("{s} s (`--seconds`)"),
        None => format!(
            "the time unguided path tracing takes for {} spp",
            args.equal_time_spp
        ),
    };
    let mut table = String::from(
        "| scene | method | MAPE | relMSE | far off ‰ | seconds | equal time (s) | spp | MAPE | relMSE | far off ‰ | seconds to MAPE |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for r in results {
        table.push_str(&r.rows(args.target_mape));
    }
    let verdict = verdict("nis-kl", results).unwrap_or_default();
    let img = report::relative_to(&args.docs, &args.img);
    let mut scenes = String::new();
    let mut figures = String::new();
    for r in results {
        scenes.push_str(&format!(
            "- `{}`: {}×{}, reference {}\n",
            r.name, r.size.0, r.size.1, r.reference
        ));
        figures.push_str(&format!(
            "**{name}** (central crops: reference, then {} at equal spp, seed {seed}, at one \
             exposure; their relative error maps below, 0 to 1 in false colour):\n\n\
             ![{name}]({img}/{file})\n\n",
            methods.join(", "),
            name = r.name,
            seed = args.seed,
            file = r.montage,
        ));
    }
    let scene_args: String = args
        .scenes
        .iter()
        .map(|s| format!(" --scene {s}"))
        .collect();
    format!(
        "Reproduce: `nis bench guiding{scene_args} --spp {spp} --res {res} --reference-spp \
         {rspp} --equal-time-spp {etspp} --curve-points {points} --seeds {seeds}{drop}`. \
         Every method renders each scene, longer side {res} pixels, with {spp} samples per \
         pixel in total (guided methods spend up to half of them on training passes of 1, 2, \
         4, … spp, and the passes are combined by inverse variance), once per seed \
         ({seeds} from {seed}); cells give the mean over seeds and, in brackets, the least and \
         largest. At equal time every method gets one wall-clock budget per scene and seed, \
         {budget}, and also half, a quarter, … of it ({points} budgets): the curves below plot \
         the seeds' mean MAPE against the seconds each render took, and the last column gives \
         the seconds each method needs to reach the MAPE shown (path tracing's at the budget, \
         or the best method's without it, unless `--target-mape` is given; interpolated on the \
         mean curve as a power law, `≤` / `>` when reached at its first point / not within \
         it). MAPE and relMSE with ε = 0.01; \"far off\" is the share of pixels (per mille) \
         more than {far_off} times the reference's value off, the fireflies that rule relMSE; \
         best mean per column in bold.\n\n{scenes}\n{table}\n{verdict}\n\n\
         ![MAPE against wall-clock time]({img}/{plot})\n\n{figures}",
        spp = args.spp,
        res = args.res,
        rspp = args.reference_spp,
        etspp = args.equal_time_spp,
        points = args.curve_points,
        seeds = args.seeds,
        seed = args.seed,
        drop = if args.drop_missing_meshes {
            " --drop-missing-meshes"
        } else {
            ""
        },
        far_off = FAR_OFF_ERROR,
    )
}

/// Crops of the renders in a row over crops of their error maps in a row below, with the
/// reference at the left: the central quarter of the image (half its width and height), as
/// the paper's Figure 5 shows crops. The renders share one exposure that brings the
/// reference's mean to 0.25, so dark scenes show.
pub(super) fn montage(reference: &Image, runs: &[Run]) -> Result<Image> {
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_spread_shows_its_range_only_over_several_values_and_bolds_the_best() {
        let s = Spread::of([0.5, 0.25, 0.75].into_iter());
        assert_eq!(
            s,
            Spread {
                mean: 0.5,
                min: 0.25,
                max: 0.75
            }
        );
        assert_eq!(s.cell(0.5, 2), "**0.50** (0.25–0.75)");
        assert_eq!(s.cell(0.1, 2), "0.50 (0.25–0.75)");
        assert_eq!(Spread::of([0.5].into_iter()).cell(0.1, 3), "0.500");
    }
}
