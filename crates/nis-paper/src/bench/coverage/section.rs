//! The section `nis bench coverage` writes: the coverage tables, each warning's false alarms
//! and catches cell by cell and pooled, the sweeps of the warnings' limits, and the plot.

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
        "`nis bench coverage` (the default cells; `--peaked` the peaked ones and a signed pair; \
         `--full` the whole suite). Per cell: the \
         fraction of seeds whose 1σ and 2σ intervals cover the exact value (nominal 0.683 and \
         0.954), the mean and the worst pull (value − exact)/σ, the mean χ²/dof between the \
         final phase's iterations, the median Pareto k̂, and the fraction of runs whose k̂ warns (above \
         0.5 by more than 1.645 of its standard errors, a one-sided test at 5 %: the result \
         then warns that its error bar cannot be trusted). Cells whose 2σ coverage lies \
         below the binomial 95% band are in bold.\n\n",
    );
    if cells.iter().any(|c| c.channels) {
        md.push_str(CHANNELS_LEGEND);
    }
    for &b in budgets {
        let (lo2, _) = band(NOMINAL2, b.seeds as usize);
        md.push_str(&format!(
            "### {} evaluations, {} seeds (2σ band {:.3}–1)\n\n\
             | integrand | method | 1σ | 2σ | mean pull | worst pull | χ²/dof | median k̂ | k̂ warns | errors |\n\
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
                "| {} | {} | {:.3} | {} | {:+.2} | {:+.1} | {:.2} | {:.2} | {:.2} | {} |\n",
                c.label(),
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
    md.push_str(&warning_cells(cells, budgets));
    md.push_str(&warning_summary(cells, budgets));
    md
}

/// What the rows "… channels" are, and what their methods and warnings mean there.
const CHANNELS_LEGEND: &str = "Rows \"… channels\": the multi-channel example integrated \
    through its channels, as `nis integrate EX --channels --method M --seed S` does (its \
    defaults: for NIS one flow shared by the parts and the weight network; the channels' \
    propagators as enhancements; the integrand split by sign where it changes sign), the exact \
    value the example's. The methods are the parts' samplers: NIS-KL a flow trained on KL \
    (`--loss kl`; not the default through channels), NIS-χ² on the variance (the default), \
    VEGAS+ a VEGAS+ map per part (multi-channel VEGAS), MC uniform points per part (the classic \
    multi-channel estimator). Their warnings are the result's: the divergence is any part's (above \
    the limit), χ² the parts' summed over their degrees of freedom (χ²/dof > 3), k̂ is fitted to \
    the parts' weights pooled (each its point's share of F), the missing mass is the NIS parts' \
    summed against the combined error bar and the hole the largest of theirs in it. The runs \
    have no divergence of their own: they count as converged when fewer than half of them \
    carry a part's divergence warning (plain MC's parts report none), and the sweep of the \
    divergence limit leaves them out.\n\n";

/// The warnings a run of `method` gives, by label: χ² between iterations and k̂, then the
/// convergence figures', which plain MC reports without warning (a sampler not learned from f).
/// Through channels, the divergence is its parts' ([`Run::part_warnings`]: any part's), as the
/// result gives it; χ² (the parts' summed over their degrees of freedom), k̂, the missing mass
/// and the hole are the parts' together.
pub fn warning_labels(r: &Run, method: &str) -> Vec<&'static str> {
    let mut out = Vec::new();
    let part = |l: &str| {
        r.part_warnings
            .as_ref()
            .is_some_and(|p| p.iter().any(|w| w == l))
    };
    if r.chi2.is_some_and(|c| c > CHI2_LIMIT) {
        out.push("χ²");
    }
    if r.k_warns() {
        out.push("k̂");
    }
    if method != "MC" {
        if part("divergence") {
            out.push("divergence");
        }
        out.extend(r.convergence.warnings().iter().map(|w| w.label));
    }
    if part("other") {
        out.push("other");
    }
    out
}

/// The warnings of the table, in its column order.
pub(super) const WARNINGS: [&str; 5] = ["χ²", "k̂", "divergence", "missing mass", "hole"];

/// Whether a cell's sampler has converged at its budget: its runs cover at 2σ within the
/// binomial band, at most `CONVERGED_FAR` of them lie beyond 4σ, and the median run's sampler
/// is close to |f| with weights of finite variance: median divergence at most
/// [`DIVERGENCE_LIMIT`] and median k̂ at most [`PARETO_K_LIMIT`]. (Plain MC on a sharp peak may
/// cover at 2·10⁵, but the uniform density stays far from the peak: it never converges here.)
/// Through channels, whose result has no divergence of its own, the median part divergence
/// within the limit reads: fewer than half the runs have a part whose divergence warns (plain MC's
/// uniform parts report none).
pub fn converged(c: &Cell) -> bool {
    let s = c.stats();
    let (lo, _) = band(NOMINAL2, s.n);
    let far = c.runs.iter().filter(|r| c.pull(r).abs() > 4.0).count();
    let divergence_ok = if c.channels {
        let warned = c
            .runs
            .iter()
            .filter(|r| warning_labels(r, &c.method).contains(&"divergence"))
            .count();
        2 * warned < s.n
    } else {
        let mut d: Vec<f64> = c
            .runs
            .iter()
            .filter_map(|r| r.convergence.divergence)
            .collect();
        d.sort_by(f64::total_cmp);
        d.get(d.len() / 2)
            .is_some_and(|&median| median <= DIVERGENCE_LIMIT)
    };
    s.n > 0
        && s.cover2 >= lo
        && far as f64 <= CONVERGED_FAR * s.n as f64
        && s.median_k <= PARETO_K_LIMIT
        && divergence_ok
}

/// The share of runs beyond 4σ a converged cell may have.
pub const CONVERGED_FAR: f64 = 0.01;

/// A run beyond 4σ that no warning could have caught: its training points estimate the mass its
/// estimate missed below [`MISSING_MASS_LIMIT`] error bars (NIS), or it has no training memory.
fn unreachable(r: &Run) -> bool {
    r.convergence
        .missing_mass
        .is_none_or(|m| m <= MISSING_MASS_LIMIT)
}

/// Per budget and cell, how each warning sorts the runs: the share of runs within 2σ it flags
/// (false alarms) and how many runs beyond 4σ it catches; then the runs beyond 4σ left without
/// a warning, and how many of those are unreachable (no evaluated point shows the missing mass).
pub(super) fn warning_cells(cells: &[Cell], budgets: &[Budget]) -> String {
    let mut md = format!(
        "### Each warning, cell by cell\n\n\
         Per cell: whether the sampler converged there (2σ coverage within the binomial band, at \
         most {:.0}% of the runs beyond 4σ, median k̂ ≤ {PARETO_K_LIMIT} and median divergence \
         ≤ {DIVERGENCE_LIMIT}: a sampler close to |f| with weights of finite variance); of the \
         runs within 2σ, \
         the share any warning flags and the share each flags (false alarms: the target is at \
         most 0.10 where the sampler converged); of the runs beyond 4σ, how many any warning \
         and each warning catch, how many carry none, and of those how many no point of the run \
         could have shown (their training points estimate the missed mass below \
         {MISSING_MASS_LIMIT} error bars, or the method keeps none). Warnings: χ²/dof > 3, \
         k̂ above {PARETO_K_LIMIT} by more than {PARETO_K_Z} standard errors, divergence > \
         {DIVERGENCE_LIMIT} (not for MC), missing mass > \
         {MISSING_MASS_LIMIT} error bars (NIS), hole: one draw at a training point would move \
         the estimate by more than {HOLE_LIMIT} error bars (NIS, when the mass does not \
         warn).\n\n",
        100.0 * CONVERGED_FAR
    );
    for &b in budgets {
        md.push_str(&format!(
            "#### {} evaluations, {} seeds\n\n\
             | cell | method | converged | within 2σ | flagged (any) | χ² | k̂ | divergence | missing mass | hole | beyond 4σ | caught (any) | χ² | k̂ | divergence | missing mass | hole | unwarned (unreachable) |\n\
             |---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n",
            b.evals, b.seeds
        ));
        for c in cells.iter().filter(|c| c.evals == b.evals) {
            let labels: Vec<(f64, Vec<&str>)> = c
                .runs
                .iter()
                .map(|r| (c.pull(r), warning_labels(r, &c.method)))
                .collect();
            let within: Vec<&Vec<&str>> = labels
                .iter()
                .filter(|(p, _)| p.abs() <= 2.0)
                .map(|(_, l)| l)
                .collect();
            let share = |pred: &dyn Fn(&Vec<&str>) -> bool| {
                within.iter().filter(|l| pred(l)).count() as f64 / within.len().max(1) as f64
            };
            let far: Vec<(&Run, &Vec<&str>)> = c
                .runs
                .iter()
                .zip(&labels)
                .filter(|(_, (p, _))| p.abs() > 4.0)
                .map(|(r, (_, l))| (r, l))
                .collect();
            let caught =
                |pred: &dyn Fn(&Vec<&str>) -> bool| far.iter().filter(|(_, l)| pred(l)).count();
            let unwarned: Vec<&Run> = far
                .iter()
                .filter(|(_, l)| l.is_empty())
                .map(|(r, _)| *r)
                .collect();
            let mut row = format!(
                "| {} | {} | {} | {} | {:.2} |",
                c.label(),
                c.method,
                if converged(c) { "yes" } else { "no" },
                within.len(),
                share(&|l| !l.is_empty())
            );
            for w in WARNINGS {
                row.push_str(&format!(" {:.2} |", share(&|l| l.contains(&w))));
            }
            row.push_str(&format!(
                " {} | {} |",
                far.len(),
                caught(&|l| !l.is_empty())
            ));
            for w in WARNINGS {
                row.push_str(&format!(" {} |", caught(&|l| l.contains(&w))));
            }
            row.push_str(&format!(
                " {} ({}) |\n",
                unwarned.len(),
                unwarned.iter().filter(|r| unreachable(r)).count()
            ));
            md.push_str(&row);
        }
        md.push('\n');
    }
    md
}

/// Per budget and method, pooled over the cells: each warning's false alarms (the share of runs
/// within 2σ it flags, over the converged cells and over all) and its recall (the share of runs
/// beyond 4σ it catches); then the runs without a warning, their 2σ coverage against the band for
/// their number, and those beyond 4σ.
pub(super) fn warning_summary(cells: &[Cell], budgets: &[Budget]) -> String {
    let mut md = String::from(
        "### Each warning, pooled\n\n\
         Over the cells of a budget and method: per warning, the share of the runs within 2σ it \
         flags in the converged cells and in all, and the share of the runs beyond 4σ it catches \
         (a run may carry several); then the runs without any warning, their 2σ coverage \
         against the binomial 95% band for their number, and how many of them lie beyond 4σ \
         (unreachable ones in brackets).\n\n\
         | budget | method | converged cells | flags within 2σ, converged: any · χ² · k̂ · divergence · missing mass · hole | flags within 2σ, all | catches beyond 4σ (of n) | unwarned | unwarned 2σ | band | unwarned beyond 4σ |\n\
         |---|---|---|---|---|---|---|---|---|---|\n",
    );
    for &b in budgets {
        for method in METHODS {
            let here: Vec<&Cell> = cells
                .iter()
                .filter(|c| c.evals == b.evals && c.method == method)
                .collect();
            if here.is_empty() {
                continue;
            }
            let conv: Vec<&Cell> = here.iter().copied().filter(|c| converged(c)).collect();
            let runs = |cs: &[&Cell]| -> Vec<(f64, Vec<&str>, bool)> {
                cs.iter()
                    .flat_map(|c| {
                        c.runs
                            .iter()
                            .map(|r| (c.pull(r), warning_labels(r, method), unreachable(r)))
                    })
                    .collect()
            };
            let (all, in_conv) = (runs(&here), runs(&conv));
            let shares = |rs: &[(f64, Vec<&str>, bool)], near: bool| -> String {
                let pick: Vec<&Vec<&str>> = rs
                    .iter()
                    .filter(|(p, _, _)| if near { p.abs() <= 2.0 } else { p.abs() > 4.0 })
                    .map(|(_, l, _)| l)
                    .collect();
                if pick.is_empty() {
                    return "–".into();
                }
                let n = pick.len() as f64;
                let mut out = vec![format!(
                    "{:.2}",
                    pick.iter().filter(|l| !l.is_empty()).count() as f64 / n
                )];
                out.extend(WARNINGS.iter().map(|w| {
                    format!(
                        "{:.2}",
                        pick.iter().filter(|l| l.contains(w)).count() as f64 / n
                    )
                }));
                let joined = out.join(" · ");
                if near {
                    joined
                } else {
                    format!("{joined} ({})", pick.len())
                }
            };
            let quiet: Vec<&(f64, Vec<&str>, bool)> =
                all.iter().filter(|(_, l, _)| l.is_empty()).collect();
            let cover = quiet.iter().filter(|(p, _, _)| p.abs() <= 2.0).count() as f64
                / quiet.len().max(1) as f64;
            let (lo, hi) = band(NOMINAL2, quiet.len());
            let quiet_far = quiet.iter().filter(|(p, _, _)| p.abs() > 4.0).count();
            let quiet_far_unreachable =
                quiet.iter().filter(|(p, _, u)| p.abs() > 4.0 && *u).count();
            md.push_str(&format!(
                "| {} | {method} | {} of {} | {} | {} | {} | {} | {cover:.3} | {lo:.3}–{:.3} | {quiet_far} ({quiet_far_unreachable}) |\n",
                b.evals,
                conv.len(),
                here.len(),
                shares(&in_conv, true),
                shares(&all, true),
                shares(&all, false),
                quiet.len(),
                hi.min(1.0),
            ));
        }
    }
    md.push('\n');
    for sweep in &SWEEPS {
        md.push_str(&limit_sweep(cells, budgets, sweep));
    }
    md
}

/// A warning's figure whose limit a sweep chooses: its name, the limit results warn at, the
/// limits tried, the figure of a run, and its warning's label (the run's other warnings count as
/// they are).
pub(super) struct Sweep {
    pub(super) name: &'static str,
    pub(super) limit: f64,
    pub(super) limits: &'static [f64],
    pub(super) figure: fn(&Run) -> Option<f64>,
    pub(super) label: &'static str,
}

/// The sweeps of the limits.
pub(super) const SWEEPS: [Sweep; 4] = [
    Sweep {
        name: "k̂ (its excess over 1/2 in standard errors, the test's statistic)",
        limit: PARETO_K_Z,
        limits: &[0.0, 1.0, 1.645, 2.33, 3.0],
        figure: |r| r.k_excess(),
        label: "k̂",
    },
    Sweep {
        name: "the divergence n/ESS − 1",
        limit: DIVERGENCE_LIMIT,
        limits: &[1.0, 3.0, 10.0, 30.0, 100.0],
        figure: |r| r.convergence.divergence,
        label: "divergence",
    },
    Sweep {
        name: "the missing mass (in error bars)",
        limit: MISSING_MASS_LIMIT,
        limits: &[0.25, 0.5, 1.0, 2.0, 4.0],
        figure: |r| r.convergence.missing_mass,
        label: "missing mass",
    },
    Sweep {
        name: "the hole (the shift one draw at a training point would give, in error bars)",
        limit: HOLE_LIMIT,
        limits: &[10.0, 30.0, 100.0, 300.0, 1000.0],
        figure: |r| r.convergence.recalled_shift,
        label: "hole",
    },
];

/// The limits of `sweep` tried: the runs beyond 4σ left without a warning, the 2σ coverage of
/// the runs without one, the share of runs within 2σ warned (all cells), and the share of runs
/// within 2σ warned in the converged cells, per limit.
pub(super) fn limit_sweep(cells: &[Cell], budgets: &[Budget], sweep: &Sweep) -> String {
    let mut md = format!(
        "How the limit on {} was chosen (results warn above {}): per limit, together with the \
         other warnings, the runs beyond 4σ left without a warning / the 2σ coverage of the \
         runs without one (lower end of the band) / the share of runs within 2σ warned, in all \
         cells and in the converged ones.\n\n| budget | method |",
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
            // Channel runs record their parts' divergence as a warning, not a figure to sweep.
            let here: Vec<&Cell> = cells
                .iter()
                .filter(|c| c.evals == b.evals && c.method == method)
                .filter(|c| !(c.channels && sweep.label == "divergence"))
                .collect();
            if here.is_empty() || (sweep.label != "k̂" && method == "MC") {
                continue;
            }
            md.push_str(&format!("| {} | {method} |", b.evals));
            for &l in sweep.limits {
                let warned = |r: &Run| others(r) || (sweep.figure)(r).is_some_and(|v| v > l);
                let (mut missed, mut kept, mut kept_in) = (0, 0usize, 0usize);
                let (mut near, mut near_warned, mut near_conv, mut near_conv_warned) = (0, 0, 0, 0);
                for c in &here {
                    let conv = converged(c);
                    for r in &c.runs {
                        let p = c.pull(r).abs();
                        let w = warned(r);
                        missed += (p > 4.0 && !w) as usize;
                        kept += !w as usize;
                        kept_in += (!w && p <= 2.0) as usize;
                        if p <= 2.0 {
                            near += 1;
                            near_warned += w as usize;
                            near_conv += conv as usize;
                            near_conv_warned += (w && conv) as usize;
                        }
                    }
                }
                let cover = kept_in as f64 / kept.max(1) as f64;
                let (lo, _) = band(NOMINAL2, kept);
                let alarms = near_warned as f64 / near.max(1) as f64;
                let alarms_conv = near_conv_warned as f64 / near_conv.max(1) as f64;
                md.push_str(&format!(
                    " {missed} / {cover:.3} ({lo:.3}) / {alarms:.2} / {alarms_conv:.2} |"
                ));
            }
            md.push('\n');
        }
    }
    md.push('\n');
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
