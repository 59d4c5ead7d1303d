//! The coverage bench's statistics, warnings, cache and section.

use super::*;
use nis::integrate::{SETTLED_VAR_REL_ERR, TAIL_END_P};

fn run_of(value: f64, std_err: f64, k: Option<f64>) -> Run {
    Run {
        seed: 0,
        value,
        std_err,
        chi2: Some(1.0),
        pareto_k: k,
        pareto_k_limit: None,
        tail_end_p: None,
        ess: 1.0,
        var_rel_err: None,
        seconds: 0.0,
        convergence: Convergence::default(),
        part_warnings: None,
    }
}

#[test]
fn stats_count_coverage_pulls_and_flags() {
    let cell = Cell {
        integrand: "x".into(),
        dim: 2,
        method: "MC".into(),
        channels: false,
        evals: 10,
        exact: 1.0,
        exact_err: 0.0,
        runs: vec![
            run_of(1.5, 1.0, Some(0.1)),  // pull 0.5
            run_of(2.5, 1.0, Some(0.9)),  // pull 1.5, flagged
            run_of(-4.0, 1.0, Some(0.2)), // pull −5
            run_of(1.0, 1.0, None),       // pull 0
        ],
        errors: vec![],
    };
    let s = cell.stats();
    assert_eq!((s.n, s.cover1, s.cover2), (4, 0.5, 0.75));
    assert_eq!(s.worst_pull, -5.0);
    assert_eq!(s.mean_pull, (0.5 + 1.5 - 5.0 + 0.0) / 4.0);
    assert_eq!(s.flagged, 0.25);
    let (lo, hi) = band(0.5, 100);
    assert!((lo - 0.4).abs() < 1e-12 && (hi - 0.6).abs() < 1e-12);
}

#[test]
fn each_warning_is_named_and_the_divergence_is_one_of_them() {
    let mut r = run_of(1.0, 1.0, Some(0.7));
    r.chi2 = Some(4.0);
    r.convergence.divergence = Some(2.0 * DIVERGENCE_LIMIT);
    assert_eq!(warning_labels(&r, "NIS-KL"), ["χ²", "k̂", "divergence"]);
    assert_eq!(warning_labels(&r, "MC"), ["χ²", "k̂"]);
    let mut quiet = run_of(1.0, 1.0, Some(0.1));
    quiet.convergence.divergence = Some(0.5 * DIVERGENCE_LIMIT);
    assert!(warning_labels(&quiet, "NIS-KL").is_empty());
    quiet.convergence.divergence = Some(2.0 * DIVERGENCE_LIMIT);
    assert_eq!(warning_labels(&quiet, "VEGAS+"), ["divergence"]);
    // A large recalled weight alone is a figure, not a warning; a missing mass is.
    quiet.convergence.training_weight_ratio = Some(100.0);
    assert_eq!(warning_labels(&quiet, "NIS-χ²"), ["divergence"]);
    quiet.convergence.missing_mass = Some(2.0 * MISSING_MASS_LIMIT);
    quiet.convergence.recalled_shift = Some(2.0 * HOLE_LIMIT);
    assert_eq!(
        warning_labels(&quiet, "NIS-χ²"),
        ["divergence", "missing mass"]
    );
    // A hole warns only where the mass does not.
    quiet.convergence.missing_mass = Some(0.5 * MISSING_MASS_LIMIT);
    assert_eq!(warning_labels(&quiet, "NIS-χ²"), ["divergence", "hole"]);
}

#[test]
fn a_cell_runs_resumes_from_its_cache_and_writes_the_section() {
    let dir = std::env::temp_dir().join(format!("nis-coverage-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let f = integrands::by_name("camel", Some(2)).unwrap();
    let budget = Budget {
        evals: 4_000,
        seeds: 6,
    };
    let cell = run_cell(&f, "VEGAS+", budget);
    assert_eq!(cell.runs.len(), 6);
    // Seeds are independent of the parallel schedule: a second run is identical.
    let again = run_cell(&f, "VEGAS+", budget);
    assert_eq!(
        cell.runs.iter().map(|r| r.value).collect::<Vec<_>>(),
        again.runs.iter().map(|r| r.value).collect::<Vec<_>>()
    );
    // A cached cell is read back instead of run.
    let spec = Spec {
        name: "camel".into(),
        dim: 2,
        channels: false,
    };
    let path = cache_path(&dir, &spec, "VEGAS+", budget);
    // A channel cell of the same name keeps a file of its own.
    let through = Spec {
        channels: true,
        ..spec.clone()
    };
    assert_ne!(cache_path(&dir, &through, "VEGAS+", budget), path);
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::write(&path, serde_json::to_vec(&cell).unwrap()).unwrap();
    let back: Cell = serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
    assert_eq!(back.runs.len(), 6);
    let md = markdown(&[back], &[budget]);
    assert!(md.contains("| camel d2 | VEGAS+ |"));
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_channel_cell_converges_while_fewer_than_half_its_runs_have_a_part_diverging() {
    let warned = |w: bool| {
        let mut r = run_of(1.0, 1.0, Some(0.1));
        r.part_warnings = Some(if w { vec!["divergence".into()] } else { vec![] });
        r
    };
    let mut cell = Cell {
        integrand: "resonances-4d".into(),
        dim: 4,
        method: "NIS-χ²".into(),
        channels: true,
        evals: 10,
        exact: 1.0,
        exact_err: 0.0,
        runs: vec![warned(true), warned(false), warned(false), warned(false)],
        errors: vec![],
    };
    assert_eq!(cell.label(), "resonances-4d d4 channels");
    assert!(converged(&cell));
    cell.runs[1] = warned(true);
    assert!(!converged(&cell));
    // The parts' χ² together is the run's.
    let mut r = warned(false);
    r.chi2 = Some(10.0);
    assert_eq!(warning_labels(&r, "NIS-χ²"), ["χ²"]);
    r.chi2 = Some(2.0);
    assert!(warning_labels(&r, "NIS-χ²").is_empty());
}

#[test]
fn a_tail_that_ends_with_a_settled_variance_does_not_flag_the_run() {
    let mut r = run_of(1.0, 0.1, Some(0.9));
    r.pareto_k_limit = Some(0.58);
    assert!(r.k_warns(), "no tail-end figure: judged by k̂ alone");
    r.tail_end_p = Some(0.5);
    assert!(r.k_warns(), "the largest weight is where the tail reaches");
    r.tail_end_p = Some(TAIL_END_P / 10.0);
    assert!(
        r.k_warns(),
        "the tail ends, but no variance error says it is settled"
    );
    r.var_rel_err = Some(SETTLED_VAR_REL_ERR * 2.0);
    assert!(
        r.k_warns(),
        "the tail ends, but the variance estimate is uncertain"
    );
    r.var_rel_err = Some(SETTLED_VAR_REL_ERR / 2.0);
    assert!(!r.k_warns(), "the tail ends and the variance is settled");
    r.pareto_k = Some(0.5);
    r.tail_end_p = Some(0.5);
    assert!(!r.k_warns(), "below its limit");
}
