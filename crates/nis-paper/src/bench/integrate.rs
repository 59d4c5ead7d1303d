//! `nis bench integrate`: the built-in suite (`nis::integrands`) with plain MC, VEGAS+ and three
//! NIS variants (PQ/KL, PQ/χ², RQ/KL) at one budget; relative variance per evaluation, pulls and
//! wall time, into `docs/BENCHMARKS.md`.

use std::path::Path;

use nis::integrate::{integrator, IntegrationResult, Method, Settings};
use nis::loss::Loss;
use nis::TransformKind;

use crate::error::Result;
use crate::report;

/// One method of the integration benchmark: a method of the library, with the flow's transform
/// and loss for NIS.
struct MethodSpec {
    label: &'static str,
    method: Method,
    nis: Option<(TransformKind, Loss)>,
}

impl MethodSpec {
    fn run(
        &self,
        f: &nis::integrands::Builtin,
        evals: u64,
        seed: u64,
    ) -> nis::Result<IntegrationResult> {
        let mut settings = Settings::default().seed(seed);
        if let Some((transform, loss)) = self.nis {
            settings.nis.flow.transform = transform;
            settings.nis.loss = loss;
        }
        integrator(self.method, f.dim, &settings)?.integrate(f, evals)
    }
}

fn methods() -> Vec<MethodSpec> {
    let nis = |label, transform, loss| MethodSpec {
        label,
        method: Method::Nis,
        nis: Some((transform, loss)),
    };
    vec![
        MethodSpec {
            label: "uniform",
            method: Method::Uniform,
            nis: None,
        },
        MethodSpec {
            label: "VEGAS+",
            method: Method::Vegas,
            nis: None,
        },
        nis("NIS-PQ/KL", TransformKind::Quadratic { bins: 16 }, Loss::Kl),
        nis(
            "NIS-PQ/χ²",
            TransformKind::Quadratic { bins: 16 },
            Loss::ChiSquare,
        ),
        nis(
            "NIS-RQ/KL",
            TransformKind::RationalQuadratic { bins: 16 },
            Loss::Kl,
        ),
    ]
}

/// Runs every method on the suite (or only the integrand `only`) at `evals` evaluations, seed 0;
/// `log` sees a line per run. Writes the section "integrate" of `docs` and returns its Markdown.
pub fn run(
    evals: u64,
    only: Option<&str>,
    docs: &Path,
    log: &mut dyn FnMut(&str),
) -> Result<String> {
    let methods = methods();
    let mut rel = format!(
        "Budget: {evals} evaluations per integrand and method (NIS training included), seed 0. \
         Cells: relative variance per evaluation Var(f/q)/F² = n_final·σ²/F² (lower is better) and, \
         in brackets, the pull (value − exact)/σ — |pull| ≫ 3 is a confident wrong answer.\n\n| integrand | d |"
    );
    let mut secs = String::from("| integrand | d |");
    for m in &methods {
        rel.push_str(&format!(" {} |", m.label));
        secs.push_str(&format!(" {} |", m.label));
    }
    rel.push_str(" VEGAS / best NIS |\n|---|---:|");
    secs.push_str("\n|---|---:|");
    for _ in &methods {
        rel.push_str("---:|");
        secs.push_str("---:|");
    }
    rel.push_str("---:|\n");
    secs.push('\n');
    for e in nis::integrands::SUITE {
        if only.is_some_and(|o| o != e.name) {
            continue;
        }
        for &d in e.dims {
            let f = nis::integrands::by_name(e.name, Some(d))?;
            rel.push_str(&format!("| {} | {d} |", e.name));
            secs.push_str(&format!("| {} | {d} |", e.name));
            let (mut vegas_rv, mut best_nis) = (f64::NAN, f64::INFINITY);
            for m in &methods {
                let r = m.run(&f, evals, 0)?;
                let pull = (r.value - f.exact) / r.std_err;
                log(&format!(
                    "{:<13} d={d:<2} {:<10} {:.6e} ± {:.2e} (exact {:.6e}) rel.var {:.3e} pull {pull:+.2} {:.1}s",
                    e.name, m.label, r.value, r.std_err, f.exact, r.rel_var_per_eval, r.seconds
                ));
                rel.push_str(&format!(" {:.3e} [{pull:+.1}] |", r.rel_var_per_eval));
                secs.push_str(&format!(" {:.2} |", r.seconds));
                // A confident wrong answer does not count as a variance.
                let ok = pull.abs() < 5.0;
                if m.method == Method::Vegas {
                    vegas_rv = if ok { r.rel_var_per_eval } else { f64::NAN };
                } else if m.method == Method::Nis && ok {
                    best_nis = best_nis.min(r.rel_var_per_eval);
                }
            }
            rel.push_str(&format!(" {:.1} |\n", vegas_rv / best_nis));
            secs.push('\n');
        }
    }
    let body = format!("{rel}\nSeconds (wall, 2 threads):\n\n{secs}");
    report::write_section(
        docs,
        "integrate",
        "Integration suite (`nis bench integrate`)",
        &body,
    )?;
    Ok(body)
}
