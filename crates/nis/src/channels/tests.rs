//! The channel interface rejects bad input with errors that name the channel and the point; the
//! Breit–Wigner mapping inverts its CDF and is normalised.

use super::*;
use crate::error::Error;

/// x = u² in every coordinate of `dim`: g = Π 1/(2√x).
fn square(dim: usize) -> Box<dyn Channel> {
    Box::new(ChannelFn::new(
        dim,
        |u: &[f64], x: &mut [f64]| {
            for (x, u) in x.iter_mut().zip(u) {
                *x = u * u;
            }
        },
        |x: &[f64]| x.iter().map(|v| 0.5 / v.sqrt()).product(),
    ))
}

fn flat(dim: usize) -> Box<dyn Channel> {
    Box::new(ChannelFn::new(
        dim,
        |u: &[f64], x: &mut [f64]| x.copy_from_slice(u),
        |_: &[f64]| 1.0,
    ))
}

/// A channel whose map and density are whatever the closures say (for broken channels).
fn broken(sample: fn(&[f64], &mut [f64]), density: fn(&[f64]) -> f64) -> Box<dyn Channel> {
    Box::new(ChannelFn::new(1, sample, density))
}

#[test]
fn the_checker_rejects_samples_outside_the_cube_and_bad_densities_naming_channel_and_point() {
    // Outside the cube, above and below, and NaN coordinates.
    for bad in [1.5, -0.1, f64::NAN] {
        let e = check_sampled(
            3,
            2,
            &[0.1, 0.2, 0.3, 0.4],
            &[0.1, 0.2, 0.3, bad],
            &[1.0, 1.0],
        )
        .unwrap_err();
        match &e {
            Error::Channel {
                channel,
                point,
                reason,
            } => {
                assert_eq!(*channel, 3);
                assert_eq!(point[0], 0.3);
                assert!(
                    reason.contains("left the unit cube") && reason.contains("point 1"),
                    "{e}"
                );
            }
            other => panic!("wrong error {other}"),
        }
    }
    // Densities negative, zero, NaN or infinite at a sampled point.
    for bad in [-1.0, 0.0, f64::NAN, f64::INFINITY] {
        let e = check_sampled(0, 1, &[0.5, 0.6], &[0.5, 0.6], &[1.0, bad]).unwrap_err();
        assert!(
            matches!(&e, Error::Channel { channel: 0, point, .. } if point == &[0.6]),
            "{e}"
        );
        assert!(e.to_string().contains("density"), "{e}");
    }
    // Wrong lengths: u not whole points, x or g of another length.
    assert!(matches!(
        check_sampled(0, 2, &[0.1; 3], &[0.1; 3], &[1.0]),
        Err(Error::Dimension { .. })
    ));
    assert!(matches!(
        check_sampled(0, 2, &[0.1; 4], &[0.1; 2], &[1.0; 2]),
        Err(Error::Dimension { .. })
    ));
    assert!(matches!(
        check_sampled(0, 2, &[0.1; 4], &[0.1; 4], &[1.0; 3]),
        Err(Error::Dimension { .. })
    ));
    assert!(check_sampled(0, 0, &[], &[], &[]).is_err());
    // Good batches pass, the faces of the cube included.
    assert!(check_sampled(0, 2, &[0.0, 1.0], &[0.0, 1.0], &[2.0]).is_ok());
}

#[test]
fn a_set_checks_what_its_channels_sample() {
    let set = ChannelSet::new(vec![
        flat(1),
        broken(|u, x| x[0] = u[0] + 1.0, |_| 1.0),
        broken(|u, x| x[0] = u[0], |_| -1.0),
        broken(|u, x| x[0] = u[0], |_| f64::NAN),
    ])
    .unwrap();
    let mut x = [0.0; 2];
    assert!(set.sample(0, &[0.25, 0.5], &mut x).is_ok());
    let e = set.sample(1, &[0.25, 0.5], &mut x).unwrap_err();
    assert!(
        matches!(&e, Error::Channel { channel: 1, point, .. } if point == &[1.25]),
        "{e}"
    );
    for k in [2, 3] {
        let e = set.sample(k, &[0.25, 0.5], &mut x).unwrap_err();
        assert!(
            matches!(&e, Error::Channel { channel, .. } if *channel == k),
            "{e}"
        );
    }
    // Densities of all channels at points no channel sampled: negative or NaN is an error.
    let mut g = [0.0; 4];
    assert!(matches!(
        set.densities(&[0.5], &mut g),
        Err(Error::Channel { channel: 2, .. })
    ));
    // Wrong lengths and a channel that does not exist.
    assert!(matches!(
        set.sample(0, &[0.25, 0.5], &mut [0.0; 3]),
        Err(Error::Dimension { .. })
    ));
    assert!(matches!(
        set.sample(4, &[0.25], &mut [0.0]),
        Err(Error::Config(_))
    ));
    let good = ChannelSet::new(vec![flat(2), square(2)]).unwrap();
    assert!(matches!(
        good.mixture_density(&[0.5; 3], &mut [0.0]),
        Err(Error::Dimension { .. })
    ));
    assert!(matches!(
        good.mixture_density(&[0.5; 4], &mut [0.0]),
        Err(Error::Dimension { .. })
    ));
    assert!(matches!(
        good.channel_weights(&[0.5; 2], &mut [0.0; 3]),
        Err(Error::Dimension { .. })
    ));
    assert!(matches!(
        flat(2).sample(&[0.5; 3], &mut [0.0; 3]),
        Err(Error::Dimension { .. })
    ));
    assert!(matches!(
        flat(2).density(&[0.5; 2], &mut [0.0; 2]),
        Err(Error::Dimension { .. })
    ));
}

#[test]
fn a_set_needs_channels_of_one_dimension_and_finite_positive_priors() {
    assert!(matches!(ChannelSet::new(vec![]), Err(Error::Config(_))));
    assert!(matches!(
        ChannelSet::new(vec![flat(0)]),
        Err(Error::Config(_))
    ));
    assert!(matches!(
        ChannelSet::new(vec![flat(2), flat(3)]),
        Err(Error::Dimension { .. })
    ));
    assert!(matches!(
        ChannelSet::with_priors(vec![flat(2), flat(2)], vec![1.0]),
        Err(Error::Dimension { .. })
    ));
    for bad in [0.0, -1.0, f64::NAN, f64::INFINITY] {
        let e = ChannelSet::with_priors(vec![flat(2), flat(2)], vec![1.0, bad]).unwrap_err();
        assert!(e.to_string().contains("channel 1"), "{e}");
    }
    let set = ChannelSet::with_priors(vec![flat(2), square(2)], vec![1.0, 3.0]).unwrap();
    assert_eq!((set.len(), set.dim(), set.is_empty()), (2, 2, false));
    assert_eq!(set.priors(), [1.0, 3.0]);
}

#[test]
fn mixture_density_and_channel_weights_follow_their_definitions() {
    let set = ChannelSet::with_priors(vec![flat(2), square(2)], vec![1.0, 3.0]).unwrap();
    let x = [0.25, 0.04, 0.81, 0.49];
    let g_sq = [1.0 / (4.0 * 0.5 * 0.2), 1.0 / (4.0 * 0.9 * 0.7)];
    let mut g = [0.0; 2];
    set.mixture_density(&x, &mut g).unwrap();
    let mut alpha = [0.0; 4];
    set.channel_weights(&x, &mut alpha).unwrap();
    for i in 0..2 {
        let want = 0.25 + 0.75 * g_sq[i];
        assert!((g[i] / want - 1.0).abs() < 1e-14);
        assert!((alpha[2 * i] - 0.25 / want).abs() < 1e-14);
        assert!((alpha[2 * i] + alpha[2 * i + 1] - 1.0).abs() < 1e-14);
    }
}

#[test]
fn breit_wigner_inverts_its_cdf_is_normalised_and_rejects_bad_parameters() {
    let bw = BreitWigner::resonance(0.9, 0.05, 0.4, 3.0).unwrap();
    for i in 0..=100 {
        let u = i as f64 / 100.0;
        let s = bw.sample(u);
        assert!((bw.cdf(s) - u).abs() < 1e-13, "u = {u}");
    }
    // ∫ pdf = 1 by a midpoint sum fine enough for the peak (width mΓ = 0.045).
    let n = 200_000;
    let (lo, hi) = bw.limits();
    let h = (hi - lo) / n as f64;
    let total: f64 = (0..n).map(|i| bw.pdf(lo + (i as f64 + 0.5) * h) * h).sum();
    assert!((total - 1.0).abs() < 1e-8, "{total}");
    assert_eq!(bw.pdf(0.3), 0.0);
    assert_eq!((bw.cdf(0.3), bw.cdf(3.5)), (0.0, 1.0));
    // Far from the peak on one side: no cancellation between arctangents near −π/2.
    let tail = BreitWigner::new(0.3, 0.003, 0.0, 1e-6).unwrap();
    assert!((tail.cdf(tail.sample(0.5)) - 0.5).abs() < 1e-9);
    assert!(BreitWigner::new(0.3, 0.0, 0.0, 1.0).is_err());
    assert!(BreitWigner::new(0.3, 0.1, 1.0, 1.0).is_err());
    assert!(BreitWigner::new(f64::NAN, 0.1, 0.0, 1.0).is_err());
}

#[test]
fn enhancements_count_only_where_their_channel_samples_and_bad_ones_are_errors() {
    // Channel 0 reaches x₀ < ½ only; its enhancement (10) does not vanish beyond.
    let half = ChannelFn::new(
        1,
        |u: &[f64], x: &mut [f64]| x[0] = 0.5 * u[0],
        |x: &[f64]| if x[0] < 0.5 { 2.0 } else { 0.0 },
    )
    .with_enhancement(|_: &[f64]| 10.0);
    let set = ChannelSet::new(vec![Box::new(half), flat(1)]).unwrap();
    assert!(set.enhanced());
    let x = [0.25, 0.75];
    let mut g = [0.0; 4];
    set.densities(&x, &mut g).unwrap();
    let b = set.weight_basis(&x, &g).unwrap().unwrap();
    // Channel 1 has none: its density stands in.
    assert_eq!(b, [10.0, 1.0, 0.0, 1.0]);
    // The channel weights are made of them (equal priors).
    let mut alpha = [0.0; 4];
    set.channel_weights(&x, &mut alpha).unwrap();
    for (got, want) in alpha.iter().zip([10.0 / 11.0, 1.0 / 11.0, 0.0, 1.0]) {
        assert!((got - want).abs() < 1e-15, "{alpha:?}");
    }
    let plain = ChannelSet::new(vec![
        Box::new(
            ChannelFn::new(1, |u: &[f64], x: &mut [f64]| x[0] = u[0], |_: &[f64]| 1.0)
                .with_enhancement(|_: &[f64]| 10.0),
        ),
        flat(1),
    ])
    .unwrap()
    .without_enhancements();
    assert!(!plain.enhanced());
    // The densities themselves.
    assert_eq!(plain.weight_basis(&x, &g).unwrap(), None);
    for bad in [-1.0, f64::NAN, f64::INFINITY] {
        let c = ChannelFn::new(1, |u: &[f64], x: &mut [f64]| x[0] = u[0], |_: &[f64]| 1.0)
            .with_enhancement(move |_: &[f64]| bad);
        let set = ChannelSet::new(vec![flat(1), Box::new(c)]).unwrap();
        let mut g = [0.0; 2];
        set.densities(&[0.5], &mut g).unwrap();
        match set.weight_basis(&[0.5], &g) {
            Err(Error::Channel {
                channel, reason, ..
            }) => {
                assert_eq!(channel, 1);
                assert!(reason.contains("enhancement"), "{reason}");
            }
            other => panic!("{other:?}"),
        }
    }
}
