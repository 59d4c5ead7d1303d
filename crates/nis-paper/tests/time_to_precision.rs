//! `nis bench time-to-precision` end to end on our side (no Python): one cheap integrand, a cap
//! of a second or two, and the structure of what comes back; no assertion on speed.

use nis_paper::bench::time_to_precision::{self as ttp, ladder, Contender, Options};

#[test]
fn a_tiny_race_has_a_ladder_per_method_and_seed_and_writes_its_section_and_plot() {
    let dir = std::env::temp_dir().join(format!("ttp-e2e-{}", std::process::id()));
    let docs = dir.join("results/integration.md");
    let options = Options {
        cells: vec![("camel".into(), 2)],
        contenders: vec![Contender::Vegas, Contender::Uniform],
        targets: vec![1e-2, 1e-3],
        seeds: 2,
        cap: 1.5,
        cost_us: 0.0,
        cli: None,
        docs: Some(docs.clone()),
        trusted: false,
    };
    let mut events = (0, 0);
    let (cells, md) = ttp::run(&options, &mut |p| {
        assert!(p.done <= p.total);
        if p.finished {
            events.0 += 1;
        } else {
            events.1 += 1;
        }
    })
    .unwrap();
    assert_eq!(events.0, 4, "a finished line per ladder");
    assert!(events.1 >= 4, "a message per run");
    assert_eq!(cells.len(), 1);
    let cell = &cells[0];
    assert_eq!((cell.name.as_str(), cell.dim), ("camel", 2));
    assert_eq!(cell.cost.spins, 0);
    assert_eq!(cell.ladders.len(), 4);
    for l in &cell.ladders {
        assert!(!l.runs.is_empty());
        // Budgets double from 10⁴; every run is a real estimate.
        for (i, r) in l.runs.iter().enumerate() {
            assert_eq!(r.evals, ladder::FIRST_BUDGET << i);
            assert!(r.seconds > 0.0 && r.std_err > 0.0 && r.value.is_finite());
        }
        // The ladder stopped for a reason: every target reached, or the cap.
        let all = options
            .targets
            .iter()
            .all(|&t| l.runs.iter().any(|r| r.reaches(t, cell.exact, options.cap)));
        let spent: f64 = l.runs.iter().map(|r| r.seconds).sum();
        let last = l.runs.last().unwrap();
        assert!(all || spent + 2.0 * last.seconds > options.cap);
        assert_eq!(
            ladder::next_budget(&l.runs, &options.targets, cell.exact, options.cap),
            None
        );
    }
    // A row per target, a column per method, and a cell for each.
    for t in ["1e-2", "1e-3"] {
        let row = md
            .lines()
            .find(|l| l.starts_with(&format!("| camel | 2 | {t} |")))
            .unwrap_or_else(|| panic!("no row for {t} in\n{md}"));
        assert_eq!(row.matches(" s (").count(), 2, "{row}");
    }
    let written = std::fs::read_to_string(&docs).unwrap();
    assert!(written.contains("<!-- time-to-precision:start -->"));
    assert!(written.contains("<!-- time-to-precision:end -->"));
    assert!(written.contains("](../img/time-to-precision-camel-d2.png)"));
    let png = std::fs::read(dir.join("img/time-to-precision-camel-d2.png")).unwrap();
    assert_eq!(&png[1..4], b"PNG");
    // Trusted answers only: a section and plots of their own beside the first.
    let trusted = Options {
        contenders: vec![Contender::Vegas],
        seeds: 1,
        trusted: true,
        ..options
    };
    let (_, md) = ttp::run(&trusted, &mut |_| {}).unwrap();
    assert!(md.contains("Trusted answers only"), "{md}");
    let written = std::fs::read_to_string(&docs).unwrap();
    assert!(written.contains("<!-- time-to-precision:start -->"));
    assert!(written.contains("<!-- time-to-precision-trusted:start -->"));
    assert!(written.contains("](../img/time-to-precision-camel-d2-trusted.png)"));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn bad_options_are_typed_errors() {
    let base = Options {
        cells: vec![("camel".into(), 2)],
        contenders: vec![Contender::Uniform],
        ..Options::default()
    };
    let cases = [
        Options {
            seeds: 0,
            ..base.clone()
        },
        Options {
            cap: -1.0,
            ..base.clone()
        },
        Options {
            targets: vec![0.0],
            ..base.clone()
        },
        Options {
            cost_us: f64::NAN,
            ..base.clone()
        },
        Options {
            contenders: vec![Contender::VegasPackage],
            ..base.clone()
        },
        Options {
            cells: vec![("no-such".into(), 2)],
            ..base.clone()
        },
    ];
    for o in cases {
        assert!(ttp::run(&o, &mut |_| {}).is_err());
    }
    assert!("vegas".parse::<Contender>().is_err());
    assert_eq!(
        "vegas-py".parse::<Contender>().unwrap(),
        Contender::VegasPackage
    );
    assert_eq!(
        "nis-codes".parse::<Contender>().unwrap(),
        Contender::NisCodes
    );
}
