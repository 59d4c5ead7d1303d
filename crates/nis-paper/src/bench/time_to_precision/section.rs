//! What `nis bench time-to-precision` writes: the Markdown table of the medians, its section of
//! the results page and a plot per cell.

use std::path::Path;

use super::ladder::Outcome;
use super::{plot, CellResult, Options};
use crate::error::Result;
use crate::report;

/// Writes the plots of every cell beside `docs`, links them from `md` and writes `md` as the
/// section of `docs` (a synthetic cost gets a section of its own).
pub(super) fn write_docs(
    o: &Options,
    docs: &Path,
    cells: &[CellResult],
    md: &mut String,
) -> Result<()> {
    let dir = report::images_dir(docs);
    md.push_str(if o.trusted {
        "\nRelative error against wall time, every run (circles: honest and unwarned, crosses: |pull| ≥ 4 or a warning; dashed: the targets):\n\n"
    } else {
        "\nRelative error against wall time, every run (circles: honest, crosses: |pull| ≥ 4; dashed: the targets):\n\n"
    });
    for c in cells {
        let file = dir.join(format!(
            "time-to-precision-{}-d{}{}{}.png",
            c.name,
            c.dim,
            cost_suffix(o.cost_us),
            trusted_suffix(o.trusted)
        ));
        report::write_file(&file, &plot::png(c, &o.targets)?)?;
        md.push_str(&format!(
            "![{} d={}]({})\n",
            c.name,
            c.dim,
            report::relative_to(docs, &file)
        ));
    }
    let (key, mut title) = if o.cost_us > 0.0 {
        (
            "time-to-precision-cost",
            format!("Time to precision with a synthetic cost of {} µs per point (`nis bench time-to-precision --cost-us {}`)", o.cost_us, o.cost_us),
        )
    } else {
        (
            "time-to-precision",
            "Time to precision (`nis bench time-to-precision`)".to_string(),
        )
    };
    let key = format!("{key}{}", trusted_suffix(o.trusted));
    if o.trusted {
        title.push_str(", trusted answers (`--trusted`)");
    }
    report::write_section(docs, &key, &title, md)?;
    Ok(())
}

fn trusted_suffix(trusted: bool) -> &'static str {
    if trusted {
        "-trusted"
    } else {
        ""
    }
}

fn cost_suffix(cost_us: f64) -> String {
    if cost_us > 0.0 {
        format!("-cost{cost_us}us")
    } else {
        String::new()
    }
}

/// "1.6 s (1.3e6)" for a reached target, "> 300 s (2.1e-3)" for a capped one, "—" for none.
pub fn cell_text(o: Option<&Outcome>, cap: f64) -> String {
    match o {
        None => "—".into(),
        Some(Outcome::Reached { seconds, evals }) => {
            format!("{seconds:.2} s ({:.1e})", *evals as f64)
        }
        Some(Outcome::Capped { rel_err }) if rel_err.is_finite() => {
            format!("> {cap} s ({rel_err:.1e})")
        }
        Some(Outcome::Capped { .. }) => format!("> {cap} s (no honest run)"),
    }
}

pub(super) fn table(
    o: &Options,
    cells: &[CellResult],
    shared: bool,
    versions: Option<&(String, String)>,
) -> String {
    let mut md = format!(
        "Fresh runs at budgets doubling from 10⁴ evaluations, seeds 1–{}; a method reaches a \
         target relative error std_err/|value| with the first run below it whose pull \
         |value − exact|/σ is under 4. Cells: the wall time of that run (median over seeds; a \
         seed that does not reach it counts as slowest) and, in brackets, its evaluations \
         (training included). Each ladder (method, integrand, seed) is capped at {} s of wall \
         time: a run that would take it past the cap is not started, and the cell reads \
         \"> {} s\" with the smallest honest relative error reached. Methods: `nis`, `vegas+` \
         and `mc` are ours with their defaults (timed in process, building the integrator \
         included), `nis-codes` ours with the flow of fewer layers (`\"masks\": \"codes\"`); `vegas-py` is the Python `vegas` package{} as its documentation runs it (5 \
         adapting iterations discarded, then 15 for the result, N/20 points each), integrating \
         the same integrand served by `nis eval` over a pipe, timed around its two calls.\n\n",
        o.seeds,
        o.cap,
        o.cap,
        versions.map_or(String::new(), |(v, p)| format!(" {v} (Python {p})")),
    );
    if o.trusted {
        md.push_str(
            "Trusted answers only (`--trusted`): a run of ours whose result warns (k̂, χ²/dof, \
             divergence, recalled weight, a limit hit) does not reach a target, however small its \
             error bar and pull; the `vegas` package reports no warnings, so its runs count as \
             above.\n\n",
        );
    }
    if o.cost_us > 0.0 {
        md.push_str(&format!(
            "Synthetic cost: each point also spins on dependent arithmetic, calibrated to add {} \
             µs of wall time per point on this machine (`nis eval --spins` serves the same code to \
             Python). Measured wall µs per point of a batch, with the cost:\n\n\
             | integrand | d | spins | ours (in process) | `vegas-py` (through the pipe) |\n\
             |---|---:|---:|---:|---:|\n",
            o.cost_us
        ));
        for c in cells {
            md.push_str(&format!(
                "| {} | {} | {} | {:.2} | {} |\n",
                c.name,
                c.dim,
                c.cost.spins,
                c.cost.ours_us,
                c.cost.python_us.map_or("—".into(), |u| format!("{u:.2}"))
            ));
        }
        md.push('\n');
    }
    md.push_str("| integrand | d | target |");
    for c in &o.contenders {
        md.push_str(&format!(" `{}` |", c.name()));
    }
    md.push_str("\n|---|---:|---:|");
    for _ in &o.contenders {
        md.push_str("---:|");
    }
    md.push('\n');
    for c in cells {
        for &t in &o.targets {
            md.push_str(&format!("| {} | {} | {t:.0e} |", c.name, c.dim));
            for &k in &o.contenders {
                md.push_str(&format!(
                    " {} |",
                    cell_text(c.median(k, t, o.cap).as_ref(), o.cap)
                ));
            }
            md.push('\n');
        }
    }
    if shared {
        md.push_str(
            "\nMeasured on a shared machine (other processes were running): these times are \
             noisy.\n",
        );
    }
    let full = Options::default();
    if o.cells != full.cells
        || o.contenders != full.contenders
        || o.targets != full.targets
        || o.seeds != full.seeds
        || o.cap != full.cap
    {
        md.push_str(
            "\nThis is a partial run (fewer cells, methods, targets or seeds, or a lower cap than \
             the defaults). The full tables are `nis bench time-to-precision` and `nis bench \
             time-to-precision --cost-us 10` (hours each; run them on a quiet machine).\n",
        );
    }
    md
}
