//! The section `nis bench coverage` writes: the coverage tables, which warning caught which
//! run, the sweep of the divergence limit, the reliability figures' summary and the plot.

use super::*;

/// The binomial band: the fraction of `n` runs that cover at nominal rate `p` lies within
/// p ± 2√(p(1−p)/n) with ~95% probability.
pub fn band(p: f64, n: usize) -> (f64, f64) {
    let h = 2.0 * (p * (1.0 - p) / n.max(1) as f64).sqrt();
    (p - h, p + h)
}

pub(super) const NOMINAL2: f64 = 0.954_499_736_103_641_6;

pub(super) fn markdown(cells: &[Cell], budgets: &[Budget]) -> String {
    let mut md = String::from(
        "`nis bench coverage` (the default cells; `--peaked` the peaked ones of issue 40; \
         `--full` the whole suite). Per cell: the \
         fraction of seeds whose 1σ and 2σ intervals cover the exact value (nominal 0.683 and \
         0.954), the mean and the worst pull (value − exact)/σ, the mean χ²/dof between the \
         final phase's iterations, the median Pareto k̂, and the fraction of runs whose k̂ exceeds \
         the limit 0.5 (the \
         result then warns that its error bar cannot be trusted). Cells whose 2σ coverage lies \
         below the binomial 95% band are in bold.\n\n",
    );
    for &b in budgets {
        let (lo2, _) = band(NOMINAL2, b.seeds as usize);
        md.push_str(&format!(
            "### {} evaluations, {} seeds (2σ band {:.3}–1)\n\n\
             | integrand | method | 1σ | 2σ | mean pull | worst pull | χ²/dof | median k̂ | k̂ > 0.5 | errors |\n\
             |---|---|---|---|---|---|---|---|---|---|\n",
            b.evals, b.seeds, lo2
        ));
        for c in cells.iter().filter(|c| c.evals == b.evals) {
            let s = c.stats();
            let cover2 = if s.cover2 < lo2 {
                format!("**{:.3}**", s.cover2)
            } else {
                format!("{:.3}", s.cover2)
            };
            md.push_str(&format!(
                "| {} d{} | {} | {:.3} | {} | {:+.2} | {:+.1} | {:.2} | {:.2} | {:.2} | {} |\n",
                c.integrand,
                c.dim,
                c.method,
                s.cover1,
                cover2,
                s.mean_pull,
                s.worst_pull,
                s.mean_chi2,
                s.median_k,
                s.flagged,
                c.errors.len()
            ));
        }
        md.push('\n');
    }
    md.push_str(&diagnostic_summary(cells, budgets));
    md.push_str(&warning_summary(cells, budgets));
    md
}

/// The warnings a run of `method` gives, by label: χ² between iterations and k̂ (the result's
/// warnings before issue 40), then the convergence figures', which plain MC reports without
/// warning (a sampler not learned from f).
pub fn warning_labels(r: &Run, method: &str) -> Vec<&'static str> {
    let mut out = Vec::new();
    if r.chi2.is_some_and(|c| c > 3.0) {
        out.push("χ²");
    }
    if r.pareto_k.is_some_and(|k| k > PARETO_K_LIMIT) {
        out.push("k̂");
    }
    if method != "MC" {
        out.extend(r.convergence.warnings().iter().map(|w| w.label));
    }
    out
}

/// Whether the result warned before the convergence figures (χ² or k̂).
pub(super) fn warned_before(r: &Run) -> bool {
    r.chi2.is_some_and(|c| c > 3.0) || r.pareto_k.is_some_and(|k| k > PARETO_K_LIMIT)
}

/// Before and after the convergence warnings, per budget and method: the runs more than 4σ off
/// that carry no warning, the 2σ coverage of the runs without one, the share of runs within 2σ
/// warned anyway, and which warning caught the runs beyond 4σ.
pub(super) fn warning_summary(cells: &[Cell], budgets: &[Budget]) -> String {
    let mut md = String::from(
        "### Which warning caught which run\n\n\
         Over all cells of a budget and method, before (the warnings of χ²/dof > 3 and k̂ > 0.5) \
         and after the convergence warnings (`nis::integrate::Convergence`): the runs more than \
         4σ off without any warning (the goal is none), the 2σ coverage of the runs without a \
         warning (their number in brackets) against the binomial 95% band for their number, and \
         the share of the runs within 2σ that warn anyway (false alarms). Then, for the runs \
         beyond 4σ, how many each warning caught (a run may carry several).\n\n\
         | budget | method | runs | beyond 4σ | unwarned beyond 4σ (before → after) | unwarned 2σ before | band | unwarned 2σ after | band | warned within 2σ (before → after) | beyond 4σ caught by |\n\
         |---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for &b in budgets {
        for method in METHODS {
            let runs = pooled_runs(cells, b, method);
            if runs.is_empty() {
                continue;
            }
            let after = |r: &Run| !warning_labels(r, method).is_empty();
            let far: Vec<&Run> = runs
                .iter()
                .filter(|(p, _)| p.abs() > 4.0)
                .map(|(_, r)| *r)
                .collect();
            let missed = |warned: &dyn Fn(&Run) -> bool| far.iter().filter(|r| !warned(r)).count();
            let unwarned = |warned: &dyn Fn(&Run) -> bool| {
                let kept: Vec<f64> = runs
                    .iter()
                    .filter(|(_, r)| !warned(r))
                    .map(|(p, _)| *p)
                    .collect();
                let cover = kept.iter().filter(|p| p.abs() <= 2.0).count() as f64
                    / kept.len().max(1) as f64;
                let (lo, hi) = band(NOMINAL2, kept.len());
                format!("{cover:.3} ({}) | {lo:.3}–{:.3}", kept.len(), hi.min(1.0))
            };
            let within: Vec<&Run> = runs
                .iter()
                .filter(|(p, _)| p.abs() <= 2.0)
                .map(|(_, r)| *r)
                .collect();
            let false_alarms = |warned: &dyn Fn(&Run) -> bool| {
                within.iter().filter(|r| warned(r)).count() as f64 / within.len().max(1) as f64
            };
            let mut caught: Vec<(&str, usize)> = Vec::new();
            for r in &far {
                for l in warning_labels(r, method) {
                    match caught.iter_mut().find(|(k, _)| *k == l) {
                        Some((_, n)) => *n += 1,
                        None => caught.push((l, 1)),
                    }
                }
            }
            let caught = caught
                .iter()
                .map(|(l, n)| format!("{l} {n}"))
                .collect::<Vec<_>>()
                .join(", ");
            md.push_str(&format!(
                "| {} | {method} | {} | {} | {} → {} | {} | {} | {:.2} → {:.2} | {} |\n",
                b.evals,
                runs.len(),
                far.len(),
                missed(&warned_before),
                missed(&after),
                unwarned(&warned_before),
                unwarned(&after),
                false_alarms(&warned_before),
                false_alarms(&after),
                if caught.is_empty() {
                    "–".into()
                } else {
                    caught
                },
            ));
        }
    }
    md.push('\n');
    for sweep in &SWEEPS {
        md.push_str(&limit_sweep(cells, budgets, sweep));
    }
    md
}

/// A convergence figure whose limit a sweep chooses: its name, the limit results warn at, the
/// limits tried, the figure of a run, and its warning's label (the run's other warnings count as
/// they are).
pub(super) struct Sweep {
    pub(super) name: &'static str,
    pub(super) limit: f64,
    pub(super) limits: &'static [f64],
    pub(super) figure: fn(&Run) -> Option<f64>,
    pub(super) label: &'static str,
}

/// The sweeps of the two convergence warnings.
pub(super) const SWEEPS: [Sweep; 2] = [
    Sweep {
        name: "the divergence n/ESS − 1",
        limit: DIVERGENCE_LIMIT,
        limits: &[1.0, 2.0, 3.0, 5.0, 10.0, 30.0],
        figure: |r| r.convergence.divergence,
        label: "divergence",
    },
    Sweep {
        name: "the recalled weight (the largest weight the final sampler gives a training point \
               over the estimate's largest)",
        limit: RECALLED_WEIGHT_LIMIT,
        limits: &[2.0, 3.0, 5.0, 10.0, 30.0, 100.0],
        figure: |r| r.convergence.training_weight_ratio,
        label: "recalled weight",
    },
];

/// The limits of `sweep` tried: the runs beyond 4σ left without a warning, the 2σ coverage of
/// the runs without one, and the share of runs within 2σ warned, per limit.
pub(super) fn limit_sweep(cells: &[Cell], budgets: &[Budget], sweep: &Sweep) -> String {
    let mut md = format!(
        "How the limit on {} was chosen (results warn above {}): per limit, together with the \
         other warnings, the runs beyond 4σ left without a warning / the 2σ coverage of the \
         runs without one (band) / the share of runs within 2σ warned.\n\n| budget | method |",
        sweep.name, sweep.limit
    );
    for l in sweep.limits {
        md.push_str(&format!(" {l} |"));
    }
    md.push_str(&format!(
        "\n|---|---|{}\n",
        "---|".repeat(sweep.limits.len())
    ));
    for &b in budgets {
        for method in METHODS {
            let others = |r: &Run| warning_labels(r, method).iter().any(|l| *l != sweep.label);
            let runs = pooled_runs(cells, b, method);
            if runs.is_empty() {
                continue;
            }
            md.push_str(&format!("| {} | {method} |", b.evals));
            for &l in sweep.limits {
                let warned = |r: &Run| others(r) || (sweep.figure)(r).is_some_and(|v| v > l);
                let missed = runs
                    .iter()
                    .filter(|(p, r)| p.abs() > 4.0 && !warned(r))
                    .count();
                let kept: Vec<f64> = runs
                    .iter()
                    .filter(|(_, r)| !warned(r))
                    .map(|(p, _)| *p)
                    .collect();
                let cover = kept.iter().filter(|p| p.abs() <= 2.0).count() as f64
                    / kept.len().max(1) as f64;
                let (lo, _) = band(NOMINAL2, kept.len());
                let within: Vec<&Run> = runs
                    .iter()
                    .filter(|(p, _)| p.abs() <= 2.0)
                    .map(|(_, r)| *r)
                    .collect();
                let alarms =
                    within.iter().filter(|r| warned(r)).count() as f64 / within.len().max(1) as f64;
                md.push_str(&format!(" {missed} / {cover:.3} ({lo:.3}) / {alarms:.2} |"));
            }
            md.push('\n');
        }
    }
    md.push('\n');
    md
}

/// How the k̂ flag sorts the runs, per budget and method, at the limit and two lower thresholds.
pub(super) fn diagnostic_summary(cells: &[Cell], budgets: &[Budget]) -> String {
    let mut md = format!(
        "### The reliability flag\n\n\
         Over all cells of a budget and method, for the limit k̂ > {PARETO_K_LIMIT} that results \
         warn at and for PSIS's 0.7: the runs more than 4σ off and how many of them are flagged, \
         the fraction of all runs flagged (the price: false alarms where the error bar was \
         fine), and the 2σ coverage of the runs left unflagged, against the binomial 95% band \
         for their number.\n\n\
         | budget | method | runs | beyond 4σ | flagged ({PARETO_K_LIMIT}) | flagged (0.7) | all flagged ({PARETO_K_LIMIT}) | all flagged (0.7) | unflagged 2σ ({PARETO_K_LIMIT}) | band | unflagged 2σ (0.7) | band |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    for &b in budgets {
        for method in METHODS {
            let runs = pooled_runs(cells, b, method);
            if runs.is_empty() {
                continue;
            }
            let flagged_at = |r: &Run, t: f64| r.pareto_k.is_some_and(|k| k > t);
            let far: Vec<&(f64, &Run)> = runs.iter().filter(|(p, _)| p.abs() > 4.0).collect();
            let caught = |t: f64| far.iter().filter(|(_, r)| flagged_at(r, t)).count();
            let share = |t: f64| {
                runs.iter().filter(|(_, r)| flagged_at(r, t)).count() as f64 / runs.len() as f64
            };
            // 2σ coverage of the unflagged runs, and the band for their number.
            let unflagged = |t: f64| {
                let kept: Vec<f64> = runs
                    .iter()
                    .filter(|(_, r)| !flagged_at(r, t))
                    .map(|(p, _)| *p)
                    .collect();
                let cover = kept.iter().filter(|p| p.abs() <= 2.0).count() as f64
                    / kept.len().max(1) as f64;
                let (lo, hi) = band(NOMINAL2, kept.len());
                format!("{cover:.3} | {lo:.3}–{:.3}", hi.min(1.0))
            };
            md.push_str(&format!(
                "| {} | {method} | {} | {} | {} | {} | {:.2} | {:.2} | {} | {} |\n",
                b.evals,
                runs.len(),
                far.len(),
                caught(PARETO_K_LIMIT),
                caught(0.7),
                share(PARETO_K_LIMIT),
                share(0.7),
                unflagged(PARETO_K_LIMIT),
                unflagged(0.7),
            ));
        }
    }
    md
}

/// 2σ coverage per cell, one panel per budget, one colour per method, the nominal rate and its
/// binomial band as lines.
pub(super) fn plot(cells: &[Cell], budgets: &[Budget]) -> Result<image::RgbImage> {
    const W: u32 = 1100;
    const H: u32 = 460;
    const COLOURS: [RGBColor; 4] = [
        RGBColor(31, 119, 180),
        RGBColor(255, 127, 14),
        RGBColor(44, 160, 44),
        RGBColor(127, 127, 127),
    ];
    let mut buffer = vec![255u8; (W * H * 3) as usize];
    {
        let root = canvas(&mut buffer, (W, H), None)?;
        let panels = root.split_evenly((1, budgets.len()));
        for (panel, b) in panels.iter().zip(budgets) {
            let here: Vec<&Cell> = cells.iter().filter(|c| c.evals == b.evals).collect();
            let n_int = here.len() / METHODS.len();
            let bottom = here
                .iter()
                .map(|c| c.stats().cover2)
                .fold(0.8f64, f64::min)
                .max(0.0)
                - 0.02;
            let mut builder = ChartBuilder::on(panel);
            builder.margin(12);
            if has_font() {
                builder
                    .caption(
                        format!("2σ coverage, {} evals × {} seeds", b.evals, b.seeds),
                        ("sans-serif", 16),
                    )
                    .x_label_area_size(30)
                    .y_label_area_size(50);
            }
            let mut chart = builder
                .build_cartesian_2d(-0.5f64..n_int as f64 - 0.5, bottom..1.0f64)
                .map_err(figure_error)?;
            let mut mesh = chart.configure_mesh();
            if has_font() {
                mesh.x_desc("cell (integrand, dimension)");
            } else {
                mesh.x_labels(0).y_labels(0);
            }
            mesh.draw().map_err(figure_error)?;
            let (lo, hi) = band(NOMINAL2, b.seeds as usize);
            for (y, style) in [
                (NOMINAL2, BLACK.stroke_width(2)),
                (lo, BLACK.mix(0.4).stroke_width(1)),
                (hi.min(1.0), BLACK.mix(0.4).stroke_width(1)),
            ] {
                chart
                    .draw_series(LineSeries::new([(-0.5, y), (n_int as f64 - 0.5, y)], style))
                    .map_err(figure_error)?;
            }
            for (k, method) in METHODS.iter().enumerate() {
                let colour = COLOURS[k];
                let points: Vec<(f64, f64)> = here
                    .iter()
                    .filter(|c| c.method == *method)
                    .enumerate()
                    .map(|(i, c)| (i as f64 + (k as f64 - 1.5) * 0.12, c.stats().cover2))
                    .collect();
                let s = chart
                    .draw_series(points.iter().map(|&p| Circle::new(p, 4, colour.filled())))
                    .map_err(figure_error)?;
                if has_font() {
                    s.label(*method)
                        .legend(move |(x, y)| Circle::new((x + 6, y), 4, colour.filled()));
                }
            }
            draw_legend(&mut chart, SeriesLabelPosition::LowerLeft, 13)?;
        }
        root.present().map_err(figure_error)?;
    }
    image::RgbImage::from_raw(W, H, buffer).ok_or_else(|| figure_error("plot buffer size"))
}

/// Every run of `method` at budget `b` over all cells, with its pull.
fn pooled_runs<'a>(cells: &'a [Cell], b: Budget, method: &str) -> Vec<(f64, &'a Run)> {
    cells
        .iter()
        .filter(|c| c.evals == b.evals && c.method == method)
        .flat_map(|c| c.runs.iter().map(move |r| (c.pull(r), r)))
        .collect()
}
