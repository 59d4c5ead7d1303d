//! A time limit ends a run to a precision target with a warning and its reason. Alone in its
//! test binary: the check on the time it took must not share the cores with other tests.

use nis::integrands;
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
