use super::*;
use crate::channels::examples;

fn integrate(
    name: &str,
    method: Method,
    evals: u64,
    seed: u64,
    config: MultiChannelConfig,
) -> (IntegrationResult, f64) {
    let ex = examples::by_name(name).unwrap();
    let set = ChannelSet::new(ex.channels).unwrap();
    let mut mc = MultiChannel::new(set, method, Settings::default().seed(seed), config).unwrap();
    (mc.integrate(&ex.integrand, evals).unwrap(), ex.exact)
}

#[test]
fn classic_multi_channel_estimates_cover_and_beat_one_channel() {
    // Plain MC through the channels over 40 seeds: at least 34 within 2σ (95.4%, 4 binomial
    // σ below 38.2 is 32.9), and ≥ 10× less variance per evaluation than uniform points.
    let mut covered = 0;
    let mut rel_var = 0.0;
    for seed in 0..40 {
        let (r, exact) = integrate(
            "resonances-4d",
            Method::Uniform,
            200_000,
            seed,
            MultiChannelConfig::default(),
        );
        covered += usize::from((r.value - exact).abs() <= 2.0 * r.std_err);
        rel_var += r.rel_var_per_eval / 40.0;
        let report = r.channels.as_ref().unwrap();
        assert_eq!(report.means.len(), 3);
        assert!((report.weights.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        assert!(report.signs.is_none());
    }
    let ex = examples::by_name("resonances-4d").unwrap();
    let mut plain = crate::integrate::uniform::PlainMc::new(4, Default::default()).unwrap();
    let one = plain.integrate(&ex.integrand, 200_000).unwrap();
    eprintln!(
        "resonances-4d: {covered}/40 within 2σ; rel. var./eval {rel_var:.3} with channels, {:.3} \
         with uniform points",
        one.rel_var_per_eval
    );
    assert!(covered >= 34, "{covered}/40");
    assert!(one.rel_var_per_eval > 10.0 * rel_var);
}

#[test]
fn nis_per_channel_covers_on_the_dalitz_plot() {
    let mut covered = 0;
    for seed in 0..10 {
        let (r, exact) = integrate(
            "dalitz",
            Method::Nis,
            200_000,
            seed,
            MultiChannelConfig::default(),
        );
        covered += usize::from((r.value - exact).abs() <= 2.0 * r.std_err);
        assert!(
            (r.value - exact).abs() <= 5.0 * r.std_err,
            "{r:?} vs {exact}"
        );
    }
    // 10 seeds: 9.5 expected, 7 or fewer would be 4 binomial σ low.
    assert!(covered >= 8, "{covered}/10");
}

#[test]
fn a_signed_integrand_is_split_and_each_sign_reported() {
    // MadNIS's ±Gaussian toy: ∫ = 0 exactly; the pilot sees both signs and splits every channel.
    let (r, exact) = integrate(
        "gauss-pm",
        Method::Vegas,
        400_000,
        3,
        MultiChannelConfig::default(),
    );
    assert_eq!(exact, 0.0);
    let s = r.channels.as_ref().unwrap().signs.expect("split by sign");
    assert!((r.value - exact).abs() <= 4.0 * r.std_err, "{r:?}");
    assert!((r.value - (s.positive - s.negative)).abs() < 1e-12);
    assert!((s.negative_fraction - 0.5).abs() < 0.01, "{s:?}");
    // Forced whole: one part per channel.
    let whole = MultiChannelConfig {
        signs: Signs::Whole,
        ..MultiChannelConfig::default()
    };
    let (r, _) = integrate("gauss-pm", Method::Vegas, 400_000, 3, whole);
    assert!(r.channels.unwrap().signs.is_none());
}

#[test]
fn splitting_by_sign_lowers_the_variance_of_one_channel() {
    // A positive and a negative Gaussian bump in 2-d (weights 1 and −0.6), one identity channel:
    // split, each part's sampler can flatten its bump; whole, a sampler of |f| cannot cancel.
    let bump = |x: &[f64], c: f64| {
        (-((x[0] - c).powi(2) + (x[1] - c).powi(2)) / (2.0 * 0.05f64.powi(2))).exp()
            / (2.0 * std::f64::consts::PI * 0.05f64.powi(2))
    };
    let f = move |x: &[f64]| bump(x, 0.3) - 0.6 * bump(x, 0.7);
    let run = |signs| {
        let config = MultiChannelConfig {
            signs,
            ..MultiChannelConfig::default()
        };
        let mut mc =
            MultiChannel::single(2, Method::Vegas, Settings::default().seed(1), config).unwrap();
        mc.integrate(&f, 400_000).unwrap()
    };
    let (split, whole) = (run(Signs::Auto), run(Signs::Whole));
    assert!(split.channels.as_ref().unwrap().signs.is_some());
    for r in [&split, &whole] {
        assert!((r.value - 0.4).abs() < 5.0 * r.std_err, "{r:?}");
    }
    eprintln!(
        "± bumps: σ {:.2e} split, {:.2e} whole",
        split.std_err, whole.std_err
    );
    assert!(split.std_err < whole.std_err);
}

#[test]
fn bad_input_is_an_error_before_the_estimate() {
    let ex = examples::by_name("dalitz").unwrap();
    let set = ChannelSet::new(ex.channels).unwrap();
    let mut mc = MultiChannel::new(
        set,
        Method::Uniform,
        Settings::default(),
        Default::default(),
    )
    .unwrap();
    // A 3-d integrand for 2-d channels.
    let f3 = crate::integrands::by_name("gauss", Some(3)).unwrap();
    assert!(mc.integrate(&f3, 100_000).is_err());
    // Too small a budget for the parts.
    let e = mc.integrate(&ex.integrand, 100).unwrap_err().to_string();
    assert!(e.contains("need at least"), "{e}");
    // A channel that leaves the cube: the error names the channel and the point.
    let out = ChannelFn::new(1, |u: &[f64], x: &mut [f64]| x[0] = 2.0 * u[0], |_| 0.5);
    let set = ChannelSet::new(vec![Box::new(out)]).unwrap();
    let mut mc = MultiChannel::new(
        set,
        Method::Uniform,
        Settings::default(),
        Default::default(),
    )
    .unwrap();
    let e = mc.integrate(&|x: &[f64]| x[0], 100_000).unwrap_err();
    assert!(matches!(e, Error::Channel { channel: 0, .. }), "{e}");
    // Settings out of range.
    let bad = MultiChannelConfig {
        adapt_fraction: 1.0,
        ..MultiChannelConfig::default()
    };
    assert!(MultiChannel::single(2, Method::Nis, Settings::default(), bad).is_err());
}

#[test]
fn a_saved_multi_channel_integrator_loads_for_the_same_channels_only() {
    let dir = std::env::temp_dir().join(format!("nis-multichannel-{}", std::process::id()));
    let ex = examples::by_name("dalitz").unwrap();
    let set = ChannelSet::new(ex.channels).unwrap();
    let mut mc = MultiChannel::new(
        set,
        Method::Nis,
        Settings::default().seed(2),
        Default::default(),
    )
    .unwrap();
    // Nothing to save before the first call; VEGAS+ has nothing to save at all.
    assert!(mc.save(&dir).is_err());
    mc.integrate(&ex.integrand, 60_000).unwrap();
    mc.save(&dir).unwrap();
    let set = ChannelSet::new(examples::by_name("dalitz").unwrap().channels).unwrap();
    let mut loaded = MultiChannel::load(&dir, set).unwrap();
    assert_eq!(loaded.weights(), mc.weights());
    let r = loaded.integrate(&ex.integrand, 60_000).unwrap();
    assert!((r.value - ex.exact).abs() < 5.0 * r.std_err, "{r:?}");
    // Other channels: a clear error naming the manifest.
    let other = ChannelSet::new(examples::by_name("resonances-4d").unwrap().channels).unwrap();
    let e = MultiChannel::load(&dir, other)
        .err()
        .expect("an error")
        .to_string();
    assert!(
        e.contains("channels.json") && e.contains("3 channels in 4"),
        "{e}"
    );
    let set = ChannelSet::new(examples::by_name("dalitz").unwrap().channels).unwrap();
    let mut vegas =
        MultiChannel::new(set, Method::Vegas, Settings::default(), Default::default()).unwrap();
    vegas.integrate(&ex.integrand, 60_000).unwrap();
    assert!(vegas.save(&dir).is_err());
    std::fs::remove_dir_all(&dir).unwrap();
}
