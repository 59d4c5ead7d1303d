//! The NIS integrator's own tests: the weights' average and the recalled training weight.

use super::*;
use crate::TransformKind;

/// A narrow Gaussian bump (std 0.03) at (c, c), of integral about 1.
fn bump(x: &[f64], c: f64) -> f64 {
    let r2 = (x[0] - c).powi(2) + (x[1] - c).powi(2);
    (-r2 / (2.0 * 0.03f64.powi(2))).exp() / (2.0 * std::f64::consts::PI * 0.03f64.powi(2))
}

#[test]
fn a_flow_that_dropped_a_region_training_saw_warns() {
    let one = |x: &[f64]| bump(x, 0.25);
    let config = NisConfig::builder().seed(5).build().unwrap();
    let mut nis = NisIntegrator::new(2, config).unwrap();
    nis.train(&one, 60_000).unwrap();
    // Trained on the bump it is asked about: the recalled weight is of the estimate's size.
    let r = nis.estimate(&one, 20_000).unwrap();
    let ratio = r.convergence.training_weight_ratio.unwrap();
    assert!(ratio < super::super::RECALLED_WEIGHT_LIMIT, "{ratio}");
    assert!(
        !r.warnings.iter().any(|w| w.contains("dropped")),
        "{:?}",
        r.warnings
    );
    // As if training had also seen f at a second bump at (0.75, 0.75) that the flow then
    // dropped (in 2-d the defensive uniform share would find it again in the estimate, so
    // the estimate here is of the first bump alone).
    let x = [0.75f32, 0.75, 0.76, 0.74];
    let fx = [bump(&[0.75, 0.75], 0.75), bump(&[0.76, 0.74], 0.75)];
    nis.memory.observe(&x, &fx, 1, &mut nis.streams.memory);
    let r = nis.estimate(&one, 20_000).unwrap();
    let ratio = r.convergence.training_weight_ratio.unwrap();
    assert!(
        ratio > 10.0 * super::super::RECALLED_WEIGHT_LIMIT,
        "{ratio}"
    );
    assert!(
        r.warnings.iter().any(|w| w.contains("dropped")),
        "{:?}",
        r.warnings
    );
}

#[test]
fn averaging_the_weights_leaves_the_training_alone() {
    // Two integrators, with and without the average, trained twice on the same stream: the
    // Adam iterates must agree bit for bit after each training, while the averaged one
    // holds other weights for its estimates.
    let f = crate::integrands::by_name("camel", Some(2)).unwrap();
    let config = |average| {
        NisConfig::builder()
            .flow(FlowConfig {
                transform: TransformKind::Quadratic { bins: 4 },
                hidden_layers: 1,
                hidden_width: 8,
                blob_bins: 4,
                ..FlowConfig::default()
            })
            .batch(64)
            .average_span(average)
            .seed(3)
            .build()
            .unwrap()
    };
    let mut plain = NisIntegrator::new(2, config(0.0)).unwrap();
    let mut averaged = NisIntegrator::new(2, config(0.5)).unwrap();
    for round in 1..=2 {
        plain.train(&f, 640).unwrap();
        averaged.train(&f, 640).unwrap();
        assert!(plain.average.is_none());
        let a = averaged.average.as_ref().unwrap();
        assert_eq!(a.steps(), 10 * round);
        assert_eq!(a.iterate(), plain.flow().params());
        assert_ne!(averaged.flow().params(), plain.flow().params());
    }
}
