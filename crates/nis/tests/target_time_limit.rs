//! A time limit ends a run to a precision target with a warning and its reason. Alone in its
//! test binary: the checks on the time taken must not share the cores with other tests.

use nis::integrands;
use nis::integrate::nis::{NisConfig, NisIntegrator};
use nis::integrate::vegas::{Vegas, VegasConfig};
use nis::integrate::{Integrator, Stop, Target};

#[test]
fn a_time_limit_ends_the_run_with_a_warning_and_its_reason() {
    // A slow integrand (50 µs a point) against 0.3 s.
    let f = integrands::by_name("camel", Some(2)).unwrap();
    let slow = |x: &[f64]| {
        std::thread::sleep(std::time::Duration::from_micros(50));
        f.value(x)
    };
    let mut v = Vegas::new(2, VegasConfig::default()).unwrap();
    let r = v
        .integrate_to(&slow, &Target::rel(1e-5).max_seconds(0.3))
        .unwrap();
    assert_eq!(r.stop, Some(Stop::MaxSeconds));
    assert!(r.seconds < 3.0, "{}", r.seconds);
    assert!(
        r.warnings.iter().any(|w| w.contains("max_seconds")),
        "{:?}",
        r.warnings
    );
}

#[test]
fn nis_keeps_to_a_time_limit_far_below_its_target() {
    // 10⁻⁴ on camel d = 8 needs seconds; 0.5 s leaves a flow barely trained, whose predicted
    // need (10⁸ evaluations, the limit) must not size a final phase the time cannot pay for
    // (with 0.05 s it took 7–9 s before the plan was capped by the time left).
    let f = integrands::by_name("camel", Some(8)).unwrap();
    let config = NisConfig {
        race_vegas: false,
        ..NisConfig::default()
    };
    let mut nis = NisIntegrator::new(8, config).unwrap();
    match nis.integrate_to(&f, &Target::rel(1e-4).max_seconds(0.5)) {
        Ok(r) => {
            assert_eq!(r.stop, Some(Stop::MaxSeconds));
            assert!(r.seconds < 5.0, "{}", r.seconds);
        }
        // A stalled machine can make one batch of the flow look slower than the share of the
        // limit training may take: refused before any evaluation, which keeps to it too.
        Err(e) => assert!(e.to_string().contains("less than one batch"), "{e}"),
    }
}

#[test]
fn channels_keep_to_a_time_limit_from_the_adaptation_on() {
    // At 20 µs a point the parts' adaptation (100,000 evaluations each by default) alone takes
    // seconds; the probe of its cost caps it to the limit's share.
    use nis::channels::{examples, ChannelSet};
    use nis::integrate::multichannel::{MultiChannel, MultiChannelConfig};
    use nis::integrate::{Method, Settings};
    let ex = examples::by_name("resonances-4d").unwrap();
    let slow = |x: &[f64]| {
        std::thread::sleep(std::time::Duration::from_micros(20));
        ex.integrand.value(x)
    };
    for method in [Method::Nis, Method::Uniform] {
        let set = ChannelSet::new(examples::by_name("resonances-4d").unwrap().channels).unwrap();
        let config = MultiChannelConfig::default();
        let mut mc = MultiChannel::new(set, method, Settings::default(), config).unwrap();
        match mc.integrate_to(&slow, &Target::rel(1e-5).max_seconds(1.0)) {
            Ok(r) => {
                assert_eq!(r.stop, Some(Stop::MaxSeconds), "{method:?}");
                assert!(r.seconds < 4.0, "{method:?}: {}", r.seconds);
            }
            // A stalled machine can make the least adaptation look slower than the limit.
            Err(e) => assert!(e.to_string().contains("cannot pay"), "{e}"),
        }
    }
}
