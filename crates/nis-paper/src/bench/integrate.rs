//! `nis bench integrate`: the built-in suite (`nis::integrands`) with plain MC, VEGAS+ and four
//! NIS variants (PQ/KL, PQ/χ², RQ/KL with the stratified latent of the default final phase, and
//! PQ/KL with i.i.d. latents) at one budget over a few seeds; relative variance per evaluation,
//! pulls and wall time, into `docs/results/integration.md`.

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
    /// NIS with i.i.d. latents in the final phase instead of the (default) stratified ones.
    iid: bool,
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
        if self.iid {
            settings.nis.stratify = None;
        }
        integrator(self.method, f.dim, &settings)?.integrate(f, evals)
    }
}

fn methods() -> Vec<MethodSpec> {
    let nis = |label, transform, loss| MethodSpec {
        label,
        method: Method::Nis,
        nis: Some((transform, loss)),
        iid: false,
    };
    vec![
        MethodSpec {
            label: "uniform",
            method: Method::Uniform,
            nis: None,
            iid: false,
        },
        MethodSpec {
            label: "VEGAS+",
            method: Method::Vegas,
            nis: None,
            iid: false,
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
        MethodSpec {
            iid: true,
            ..nis(
                "NIS-PQ/KL i.i.d.",
                TransformKind::Quadratic { bins: 16 },
                Loss::Kl,
            )
        },
    ]
}

/// Which cells `nis bench integrate` runs, and how often.
#[derive(Clone, Debug)]
pub struct Options<'a> {
    /// Evaluations per run.
    pub evals: u64,
    /// Only these integrands (comma-separated names).
    pub only: Option<&'a str>,
    /// Only these dimensions (empty: all of the suite's).
    pub dims: &'a [usize],
    /// Seeds 0..seeds per cell (the cells show medians).
    pub seeds: u64,
}

/// The median of `v` (the mean of the middle two for an even count); NaN when empty.
fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    let m = v.len() / 2;
    if v.len() % 2 == 1 {
        v[m]
    } else {
        0.5 * (v[m - 1] + v[m])
    }
}

impl Options<'_> {
    /// The section of the docs a run writes: "integrate" for the whole suite, a section of its
    /// own for a subset (so a run of a few cells does not replace the whole suite's table).
    fn section(&self) -> (String, String) {
        let mut key = String::from("integrate");
        let mut cells = Vec::new();
        if let Some(only) = self.only {
            key.push('-');
            key.push_str(&only.replace(',', "-"));
            cells.push(format!("`--only {only}`"));
        }
        if !self.dims.is_empty() {
            let dims: Vec<String> = self.dims.iter().map(|d| d.to_string()).collect();
            key.push_str(&format!("-d{}", dims.join("-")));
            cells.push(format!("`--dims {}`", dims.join(",")));
        }
        let title = if cells.is_empty() {
            "Integration suite (`nis bench integrate`)".to_string()
        } else {
            format!(
                "Integration suite, {} (`nis bench integrate`)",
                cells.join(" ")
            )
        };
        (key, title)
    }
}

/// Runs every method on the chosen cells of the suite at `o.evals` evaluations, seeds
/// 0..`o.seeds`; `log` sees a line per run. Writes the section of `docs` that
/// `Options::section` names and returns its Markdown.
pub fn run(o: &Options, docs: &Path, log: &mut dyn FnMut(&str)) -> Result<String> {
    let (evals, seeds) = (o.evals, o.seeds.max(1));
    let methods = methods();
    let mut rel = format!(
        "Budget: {evals} evaluations per integrand and method (NIS training included), seeds \
         0–{}. Cells: the median over the seeds of the relative variance per evaluation \
         Var(f/q)/F² = n_final·σ²/F² (lower is better) and, in brackets, the pulls \
         (value − exact)/σ of the seeds — |pull| ≫ 3 is a confident wrong answer. NIS-PQ/KL, \
         NIS-PQ/χ² and NIS-RQ/KL run the default final phase (the flow's latent stratified); \
         NIS-PQ/KL i.i.d. is NIS-PQ/KL with `\"stratify\": null`.\n\n| integrand | d |",
        seeds - 1
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
        if o.only
            .is_some_and(|only| !only.split(',').any(|n| n == e.name))
        {
            continue;
        }
        for &d in e.dims {
            if !o.dims.is_empty() && !o.dims.contains(&d) {
                continue;
            }
            let f = nis::integrands::by_name(e.name, Some(d))?;
            rel.push_str(&format!("| {} | {d} |", e.name));
            secs.push_str(&format!("| {} | {d} |", e.name));
            let (mut vegas_rv, mut best_nis) = (f64::NAN, f64::INFINITY);
            for m in &methods {
                let (mut rvs, mut pulls, mut times) = (Vec::new(), Vec::new(), Vec::new());
                for seed in 0..seeds {
                    let r = m.run(&f, evals, seed)?;
                    let pull = (r.value - f.exact) / r.std_err;
                    log(&format!(
                        "{:<13} d={d:<2} {:<16} seed {seed} {:.6e} ± {:.2e} (exact {:.6e}) rel.var {:.3e} pull {pull:+.2} {:.1}s",
                        e.name, m.label, r.value, r.std_err, f.exact, r.rel_var_per_eval, r.seconds
                    ));
                    rvs.push(r.rel_var_per_eval);
                    pulls.push(pull);
                    times.push(r.seconds);
                }
                let rv = median(rvs);
                let shown: Vec<String> = pulls.iter().map(|p| format!("{p:+.1}")).collect();
                rel.push_str(&format!(" {rv:.3e} [{}] |", shown.join(" ")));
                secs.push_str(&format!(" {:.2} |", median(times)));
                // A confident wrong answer does not count as a variance.
                let ok = pulls.iter().all(|p| p.abs() < 5.0);
                if m.method == Method::Vegas {
                    vegas_rv = if ok { rv } else { f64::NAN };
                } else if m.method == Method::Nis && ok {
                    best_nis = best_nis.min(rv);
                }
            }
            rel.push_str(&format!(" {:.1} |\n", vegas_rv / best_nis));
            secs.push('\n');
        }
    }
    let body = format!("{rel}\nSeconds (wall, 2 threads, median over the seeds):\n\n{secs}");
    let (key, title) = o.section();
    report::write_section(docs, &key, &title, &body)?;
    Ok(body)
}

#[cfg(test)]
mod tests {
    use super::{median, Options};

    #[test]
    fn a_subset_writes_a_section_of_its_own() {
        let all = Options {
            evals: 10,
            only: None,
            dims: &[],
            seeds: 1,
        };
        assert_eq!(all.section().0, "integrate");
        let some = Options {
            only: Some("camel,gauss"),
            dims: &[4, 8],
            ..all
        };
        assert_eq!(some.section().0, "integrate-camel-gauss-d4-8");
    }

    #[test]
    fn medians_of_odd_and_even_counts() {
        assert_eq!(median(vec![3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(vec![4.0, 1.0, 3.0, 2.0]), 2.5);
        assert!(median(Vec::new()).is_nan());
    }
}
