//! The C ABI called from Rust: results bit-identical to the library's for the same config and
//! seed, the callback's threading contract, samples, save/load, and error codes.

use std::ffi::{c_int, c_void, CStr, CString};
use std::sync::atomic::{AtomicUsize, Ordering};

use nis::integrate::nis::NisIntegrator;
use nis::integrate::{integrator, Integrator, Method, Settings, VectorFn};
use nis_c::*;

/// The integrand of these tests: a Gaussian bump off the centre, f(x) = exp(-|x - 0.3|²/0.02).
fn bump(p: &[f64]) -> f64 {
    (-p.iter().map(|v| (v - 0.3) * (v - 0.3)).sum::<f64>() / 0.02).exp()
}

unsafe extern "C" fn bump_c(
    x: *const f64,
    n: usize,
    dim: usize,
    out: *mut f64,
    _user: *mut c_void,
) -> c_int {
    unsafe { each_point(x, n, dim, out, bump) }
}

/// `out[i] = value(x_i)` for the `n` points of `x` (`dim` each), a callback's body.
unsafe fn each_point(
    x: *const f64,
    n: usize,
    dim: usize,
    out: *mut f64,
    value: impl Fn(&[f64]) -> f64,
) -> c_int {
    let x = unsafe { std::slice::from_raw_parts(x, n * dim) };
    let out = unsafe { std::slice::from_raw_parts_mut(out, n) };
    for (o, p) in out.iter_mut().zip(x.chunks_exact(dim)) {
        *o = value(p);
    }
    0
}

/// Two components: the bump and x₀ times it.
fn pair(p: &[f64], out: &mut [f64]) {
    out[0] = bump(p);
    out[1] = p[0] * out[0];
}

unsafe extern "C" fn pair_c(
    x: *const f64,
    n: usize,
    dim: usize,
    out: *mut f64,
    _user: *mut c_void,
) -> c_int {
    let x = unsafe { std::slice::from_raw_parts(x, n * dim) };
    let out = unsafe { std::slice::from_raw_parts_mut(out, 2 * n) };
    for (o, p) in out.chunks_exact_mut(2).zip(x.chunks_exact(dim)) {
        pair(p, o);
    }
    0
}

/// Counts the callback's calls in flight; records the most at once and the largest batch.
#[derive(Default)]
struct Overlap {
    in_flight: AtomicUsize,
    most: AtomicUsize,
    calls: AtomicUsize,
    largest_batch: AtomicUsize,
}

unsafe extern "C" fn watched_c(
    x: *const f64,
    n: usize,
    dim: usize,
    out: *mut f64,
    user: *mut c_void,
) -> c_int {
    let w = unsafe { &*(user as *const Overlap) };
    let now = w.in_flight.fetch_add(1, Ordering::SeqCst) + 1;
    w.most.fetch_max(now, Ordering::SeqCst);
    w.calls.fetch_add(1, Ordering::SeqCst);
    w.largest_batch.fetch_max(n, Ordering::SeqCst);
    // Long enough for another thread to come in, were it allowed.
    std::thread::sleep(std::time::Duration::from_micros(200));
    let status = unsafe { bump_c(x, n, dim, out, user) };
    w.in_flight.fetch_sub(1, Ordering::SeqCst);
    status
}

/// A handle made from `json`, which must be accepted.
fn create(json: &str) -> *mut nis_integrator {
    let json = CString::new(json).unwrap();
    let mut integ = std::ptr::null_mut();
    assert_eq!(
        unsafe { nis_create(json.as_ptr(), &mut integ) },
        NIS_OK,
        "{}",
        last_error()
    );
    integ
}

fn last_error() -> String {
    unsafe { CStr::from_ptr(nis_last_error_message()) }
        .to_string_lossy()
        .into_owned()
}

/// Same bits, NaN included.
fn same(a: f64, b: f64) -> bool {
    a.to_bits() == b.to_bits()
}

fn settings(json: &str) -> Settings {
    serde_json::from_str(json).unwrap()
}

#[test]
fn results_are_bit_identical_to_the_library_for_every_method() {
    let sections = r#"{"nis": {"batch": 512, "final_iterations": 4}, "vegas": {"iterations": 5}}"#;
    for method in Method::ALL {
        let json = format!(
            r#"{{"method": "{method}", "dim": 3, "seed": 11, "nis": {{"batch": 512, "final_iterations": 4}}, "vegas": {{"iterations": 5}}}}"#
        );
        let integ = create(&json);
        let mut rust = integrator(method, 3, &settings(sections).seed(11)).unwrap();
        // Two calls: the second continues the adapted state on both sides.
        for evals in [20_000, 30_000] {
            let mut c = nis_result::default();
            let status =
                unsafe { nis_integrate(integ, Some(bump_c), std::ptr::null_mut(), evals, &mut c) };
            assert_eq!(status, NIS_OK, "{method}: {}", last_error());
            let r = rust.integrate(&bump, evals).unwrap();
            assert!(
                same(c.value, r.value) && same(c.std_err, r.std_err),
                "{method}: {c:?} vs {r:?}"
            );
            assert!(same(c.chi2_per_dof, r.chi2_per_dof) && c.n_eval == r.n_eval);
            assert!(same(c.rel_var_per_eval, r.rel_var_per_eval));
            assert!(same(c.unweighting_efficiency, r.unweighting_efficiency));
            assert_eq!(c.components, 1);
            assert!(c.seconds > 0.0);
        }
        unsafe { nis_free(integ) };
    }
}

/// A section that names one field of the flow keeps the integrator's other defaults (not
/// `FlowConfig`'s own, which are a larger flow): the code masks through C are the library's.
#[test]
fn a_partial_flow_section_changes_only_what_it_names() {
    let integ =
        create(r#"{"method": "nis", "dim": 5, "seed": 3, "nis": {"flow": {"masks": "codes"}}}"#);
    let mut s = Settings::default().seed(3);
    s.nis.flow.masks = nis::flow::mask::Masks::Codes;
    let mut rust = integrator(Method::Nis, 5, &s).unwrap();
    let mut c = nis_result::default();
    let status =
        unsafe { nis_integrate(integ, Some(bump_c), std::ptr::null_mut(), 20_000, &mut c) };
    assert_eq!(status, NIS_OK, "{}", last_error());
    let r = rust.integrate(&bump, 20_000).unwrap();
    assert!(
        same(c.value, r.value) && same(c.std_err, r.std_err),
        "{c:?} vs {r:?}"
    );
    unsafe { nis_free(integ) };
}

#[test]
fn vector_results_are_bit_identical_with_their_covariance() {
    for (method, components_in_config) in [(Method::Nis, true), (Method::Vegas, false)] {
        let k_field = if components_in_config {
            r#", "components": 2"#
        } else {
            ""
        };
        let json = format!(
            r#"{{"method": "{method}", "dim": 2, "seed": 5, "train_on": "sum_abs"{k_field}, "nis": {{"batch": 256}}}}"#
        );
        let integ = create(&json);
        let mut c = nis_result::default();
        let status = unsafe {
            if components_in_config {
                nis_integrate(integ, Some(pair_c), std::ptr::null_mut(), 10_000, &mut c)
            } else {
                nis_integrate_vector(integ, Some(pair_c), std::ptr::null_mut(), 2, 10_000, &mut c)
            }
        };
        assert_eq!(status, NIS_OK, "{}", last_error());
        assert_eq!(c.components, 2);
        let s = settings(r#"{"nis": {"batch": 256}}"#)
            .seed(5)
            .train_on(nis::integrate::TrainOn::SumAbs);
        let r = integrator(method, 2, &s)
            .unwrap()
            .integrate(&VectorFn::new(2, pair), 10_000)
            .unwrap();
        let e = r.estimates();
        let (mut mean, mut err, mut cov) = ([0.0; 2], [0.0; 2], [0.0; 4]);
        let status = unsafe {
            nis_result_estimates(
                integ,
                mean.as_mut_ptr(),
                err.as_mut_ptr(),
                cov.as_mut_ptr(),
                2,
            )
        };
        assert_eq!(status, NIS_OK);
        assert_eq!(
            (mean.to_vec(), err.to_vec(), cov.to_vec()),
            (e.mean, e.std_err, e.cov)
        );
        assert!(same(c.value, r.value));
        unsafe { nis_free(integ) };
    }
}

#[test]
fn the_callback_is_never_entered_twice_at_once_by_default() {
    for method in Method::ALL {
        let integ = create(&format!(r#"{{"method": "{method}", "dim": 2, "seed": 1}}"#));
        let watch = Overlap::default();
        let user = &watch as *const Overlap as *mut c_void;
        let status =
            unsafe { nis_integrate(integ, Some(watched_c), user, 30_000, std::ptr::null_mut()) };
        assert_eq!(status, NIS_OK, "{}", last_error());
        assert_eq!(
            watch.most.load(Ordering::SeqCst),
            1,
            "{method}: calls overlapped"
        );
        assert!(watch.calls.load(Ordering::SeqCst) > 1);
        unsafe { nis_free(integ) };
    }
}

#[test]
fn concurrent_callbacks_get_chunks_and_change_no_bit() {
    let base =
        r#""method": "nis", "dim": 2, "seed": 3, "nis": {"batch": 4096, "final_iterations": 2}"#;
    let serial = create(&format!("{{{base}}}"));
    let concurrent = create(&format!(r#"{{{base}, "concurrent_callback": true}}"#));
    let watch = Overlap::default();
    let user = &watch as *const Overlap as *mut c_void;
    let (mut a, mut b) = (nis_result::default(), nis_result::default());
    unsafe {
        assert_eq!(
            nis_integrate(serial, Some(bump_c), std::ptr::null_mut(), 40_000, &mut a),
            NIS_OK
        );
        assert_eq!(
            nis_integrate(concurrent, Some(watched_c), user, 40_000, &mut b),
            NIS_OK
        );
        nis_free(serial);
        nis_free(concurrent);
    }
    assert!(watch.largest_batch.load(Ordering::SeqCst) <= NIS_CONCURRENT_CHUNK);
    assert!(same(a.value, b.value) && same(a.std_err, b.std_err));
}

#[test]
fn samples_unweighted_points_and_saved_integrators_match_the_library() {
    let json = r#"{"method": "nis", "dim": 2, "seed": 8, "nis": {"batch": 512}}"#;
    let integ = create(json);
    let mut rust =
        NisIntegrator::new(2, settings(r#"{"nis": {"batch": 512}}"#).seed(8).nis).unwrap();
    let null = std::ptr::null_mut();
    assert_eq!(
        unsafe { nis_integrate(integ, Some(bump_c), null, 20_000, null.cast()) },
        NIS_OK
    );
    rust.integrate(&bump, 20_000).unwrap();

    // Unweighted points: the same bits as the library's from the same state.
    let n = 300;
    let (mut x, mut w) = (vec![0.0; 2 * n], vec![0.0; n]);
    let status = unsafe {
        nis_unweighted(
            integ,
            Some(bump_c),
            null,
            n,
            1e-3,
            x.as_mut_ptr(),
            w.as_mut_ptr(),
        )
    };
    assert_eq!(status, NIS_OK, "{}", last_error());
    let u = rust.unweighted(&bump, n, 1e-3).unwrap();
    assert_eq!((x, w), (u.points, u.weights));

    // Weighted samples: points in the cube with their density, weights f/q.
    let (mut x, mut pdf) = (vec![0.0; 2 * n], vec![0.0; n]);
    assert_eq!(
        unsafe { nis_sample(integ, n, x.as_mut_ptr(), pdf.as_mut_ptr()) },
        NIS_OK
    );
    assert!(x.iter().all(|v| (0.0..=1.0).contains(v)) && pdf.iter().all(|q| *q > 0.0));
    let (mut x2, mut w2) = (vec![0.0; 2 * n], vec![0.0; n]);
    assert_eq!(unsafe { nis_set_seed(integ, 8) }, NIS_OK);
    assert_eq!(
        unsafe { nis_sample(integ, n, x.as_mut_ptr(), pdf.as_mut_ptr()) },
        NIS_OK
    );
    assert_eq!(unsafe { nis_set_seed(integ, 8) }, NIS_OK);
    let status = unsafe {
        nis_sample_weighted(
            integ,
            Some(bump_c),
            null,
            n,
            x2.as_mut_ptr(),
            w2.as_mut_ptr(),
        )
    };
    assert_eq!(status, NIS_OK);
    assert_eq!(x, x2, "the same stream gives the same points");
    for ((p, q), w) in x.chunks(2).zip(&pdf).zip(&w2) {
        assert!((w - bump(p) / q).abs() <= 1e-12 * w.abs());
    }
    // The mean weight estimates the integral, ∫ = (π·0.02)·Φ-cut ≈ 0.0628 in 2-d.
    let mean = w2.iter().sum::<f64>() / n as f64;
    assert!((mean / 0.0628 - 1.0).abs() < 0.2, "mean weight {mean}");

    // Save, load on both sides, estimate again: the same bits.
    let dir = std::env::temp_dir().join(format!("nis-c-abi-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("bump.safetensors");
    let cpath = CString::new(path.to_str().unwrap()).unwrap();
    assert_eq!(
        unsafe { nis_save(integ, cpath.as_ptr()) },
        NIS_OK,
        "{}",
        last_error()
    );
    let mut loaded = std::ptr::null_mut();
    assert_eq!(
        unsafe { nis_load(cpath.as_ptr(), &mut loaded) },
        NIS_OK,
        "{}",
        last_error()
    );
    assert_eq!(unsafe { nis_dim(loaded) }, 2);
    let mut c = nis_result::default();
    assert_eq!(
        unsafe { nis_integrate(loaded, Some(bump_c), null, 10_000, &mut c) },
        NIS_OK
    );
    let r = NisIntegrator::load(&path)
        .unwrap()
        .integrate(&bump, 10_000)
        .unwrap();
    assert!(same(c.value, r.value) && same(c.std_err, r.std_err));
    unsafe {
        nis_free(loaded);
        nis_free(integ);
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_failing_callback_reports_its_status_and_keeps_the_last_result() {
    unsafe extern "C" fn refuse(
        _: *const f64,
        _: usize,
        _: usize,
        _: *mut f64,
        _: *mut c_void,
    ) -> c_int {
        -42
    }
    let integ = create(r#"{"method": "vegas", "dim": 2}"#);
    let null = std::ptr::null_mut();
    unsafe {
        assert_eq!(
            nis_integrate(integ, Some(bump_c), null, 5_000, null.cast()),
            NIS_OK
        );
        assert_eq!(
            nis_integrate(integ, Some(refuse), null, 5_000, null.cast()),
            NIS_ERR_CALLBACK
        );
        assert_eq!(nis_last_callback_status(), -42);
        assert!(last_error().contains("-42"), "{}", last_error());
        let mut mean = 0.0;
        let status = nis_result_estimates(integ, &mut mean, null.cast(), null.cast(), 1);
        assert_eq!(status, NIS_OK);
        assert!(mean > 0.0);
        nis_free(integ);
    }
}

#[test]
fn runs_to_a_target_match_the_library_and_say_why_they_stopped() {
    use nis::integrate::Target;
    // Plain MC and VEGAS+ plan from counts alone without a time limit: bit-identical.
    for method in [Method::Uniform, Method::Vegas] {
        let integ = create(&format!(r#"{{"method": "{method}", "dim": 3, "seed": 5}}"#));
        let mut rust = integrator(method, 3, &Settings::default().seed(5)).unwrap();
        let mut c = nis_result::default();
        let status = unsafe {
            nis_integrate_to(
                integ,
                Some(bump_c),
                std::ptr::null_mut(),
                1e-2,
                0.0,
                0,
                0.0,
                &mut c,
            )
        };
        assert_eq!(status, NIS_OK, "{method}: {}", last_error());
        let r = rust.integrate_to(&bump, &Target::rel(1e-2)).unwrap();
        assert!(
            same(c.value, r.value) && same(c.std_err, r.std_err),
            "{c:?} vs {r:?}"
        );
        assert!(c.std_err <= 1e-2 * c.value);
        assert_eq!(unsafe { nis_result_stop(integ) }, NIS_STOP_TARGET);
        // A limit: not an error, a stop reason and a warning that names it.
        let status = unsafe {
            nis_integrate_to(
                integ,
                Some(bump_c),
                std::ptr::null_mut(),
                1e-6,
                0.0,
                30_000,
                0.0,
                &mut c,
            )
        };
        assert_eq!(status, NIS_OK, "{method}: {}", last_error());
        assert_eq!(unsafe { nis_result_stop(integ) }, NIS_STOP_MAX_EVALS);
        assert_eq!(
            unsafe { nis_result_answered_by(integ) },
            NIS_ANSWERED_BY_OWN
        );
        let len = unsafe { nis_result_warnings(integ, std::ptr::null_mut(), 0) };
        let mut text = vec![0 as std::ffi::c_char; len + 1];
        unsafe { nis_result_warnings(integ, text.as_mut_ptr(), text.len()) };
        let text = unsafe { CStr::from_ptr(text.as_ptr()) }.to_string_lossy();
        assert!(text.contains("max_evals = 30000"), "{text}");
        unsafe { nis_free(integ) };
    }
    // NIS's training length depends on measured times: only the outcome is compared.
    let integ = create(r#"{"method": "nis", "dim": 3, "seed": 5}"#);
    let mut c = nis_result::default();
    let status = unsafe {
        nis_integrate_to(
            integ,
            Some(bump_c),
            std::ptr::null_mut(),
            0.0,
            1e-4,
            0,
            0.0,
            &mut c,
        )
    };
    assert_eq!(status, NIS_OK, "{}", last_error());
    assert!(c.std_err <= 1e-4);
    assert_eq!(unsafe { nis_result_stop(integ) }, NIS_STOP_TARGET);
    // A smooth bump: NIS leaves it to VEGAS+ when that meets the target first, unwarned.
    let by = unsafe { nis_result_answered_by(integ) };
    let warned = unsafe { nis_result_warnings(integ, std::ptr::null_mut(), 0) } > 0;
    assert!(by == NIS_ANSWERED_BY_OWN || (by == NIS_ANSWERED_BY_VEGAS && !warned));
    assert_eq!(
        unsafe { nis_result_answered_by(std::ptr::null()) },
        NIS_ANSWERED_BY_OWN
    );
    // Bad targets: NIS_ERR_INVALID before the callback is called, the last result kept.
    let calls = AtomicUsize::new(0);
    unsafe extern "C" fn counting(
        x: *const f64,
        n: usize,
        dim: usize,
        out: *mut f64,
        user: *mut c_void,
    ) -> c_int {
        unsafe { &*(user as *const AtomicUsize) }.fetch_add(1, Ordering::Relaxed);
        unsafe { bump_c(x, n, dim, out, user) }
    }
    let user = &calls as *const AtomicUsize as *mut c_void;
    for (rel, abs, max_evals, seconds) in [
        (0.0, 0.0, 0, 0.0),
        (-1e-3, 0.0, 0, 0.0),
        (f64::NAN, 0.0, 0, 0.0),
        (1e-3, 0.0, 10, 0.0),
        (1e-3, 0.0, 0, -1.0),
        (0.0, 0.0, 1000, 0.0),
    ] {
        let status = unsafe {
            nis_integrate_to(
                integ,
                Some(counting),
                user,
                rel,
                abs,
                max_evals,
                seconds,
                &mut c,
            )
        };
        let expected = if max_evals == 10 {
            NIS_ERR_CONFIG
        } else {
            NIS_ERR_INVALID_ARGUMENT
        };
        assert_eq!(status, expected, "{rel} {abs} {max_evals} {seconds}");
        assert!(
            last_error().contains("precision target"),
            "{}",
            last_error()
        );
    }
    assert_eq!(calls.load(Ordering::Relaxed), 0);
    assert_eq!(unsafe { nis_result_stop(integ) }, NIS_STOP_TARGET);
    unsafe { nis_free(integ) };
}

/// Two Cauchy peaks in x₀ (at 0.2 and 0.7, width γ), flat in x₁, and a channel per peak.
const GAMMA: f64 = 1e-3;

fn peak(x: f64, c: f64) -> f64 {
    GAMMA / (GAMMA * GAMMA + (x - c).powi(2))
}

fn angles(c: f64) -> (f64, f64) {
    ((-c / GAMMA).atan(), ((1.0 - c) / GAMMA).atan())
}

unsafe extern "C" fn peaks_c(
    x: *const f64,
    n: usize,
    dim: usize,
    out: *mut f64,
    _: *mut c_void,
) -> c_int {
    unsafe { each_point(x, n, dim, out, |p| peak(p[0], 0.2) + 0.5 * peak(p[0], 0.7)) }
}

/// The channel's centre is the f64 behind `user`.
unsafe extern "C" fn cauchy_sample(
    u: *const f64,
    n: usize,
    dim: usize,
    x: *mut f64,
    user: *mut c_void,
) -> c_int {
    let c = unsafe { *(user as *const f64) };
    let (lo, hi) = angles(c);
    let u = unsafe { std::slice::from_raw_parts(u, n * dim) };
    let x = unsafe { std::slice::from_raw_parts_mut(x, n * dim) };
    for (x, u) in x.chunks_exact_mut(dim).zip(u.chunks_exact(dim)) {
        x[0] = (c + GAMMA * (lo + u[0] * (hi - lo)).tan()).clamp(0.0, 1.0);
        x[1] = u[1];
    }
    0
}

unsafe extern "C" fn cauchy_density(
    x: *const f64,
    n: usize,
    dim: usize,
    g: *mut f64,
    user: *mut c_void,
) -> c_int {
    let c = unsafe { *(user as *const f64) };
    let (lo, hi) = angles(c);
    unsafe { each_point(x, n, dim, g, |x| peak(x[0], c) / (hi - lo)) }
}

/// A sample callback that leaves the cube.
unsafe extern "C" fn outside(
    _: *const f64,
    n: usize,
    dim: usize,
    x: *mut f64,
    _: *mut c_void,
) -> c_int {
    unsafe { std::slice::from_raw_parts_mut(x, n * dim) }.fill(1.5);
    0
}

/// `nis_multichannel_create` from the JSON `json` with `channels` (NULL and 0 when there are
/// none) and no sign setting: its status and the integrator it made.
fn create_mc(json: &str, channels: &[nis_channel]) -> (c_int, *mut nis_multichannel) {
    let json = CString::new(json).unwrap();
    let ptr = if channels.is_empty() {
        std::ptr::null()
    } else {
        channels.as_ptr()
    };
    let mut mc = std::ptr::null_mut();
    let status = unsafe {
        nis_multichannel_create(
            json.as_ptr(),
            ptr,
            channels.len(),
            std::ptr::null(),
            &mut mc,
        )
    };
    (status, mc)
}

/// The peak itself, unnormalised: a channel's enhancement.
unsafe extern "C" fn cauchy_peak(
    x: *const f64,
    n: usize,
    dim: usize,
    w: *mut f64,
    user: *mut c_void,
) -> c_int {
    let c = unsafe { *(user as *const f64) };
    unsafe { each_point(x, n, dim, w, |x| peak(x[0], c)) }
}

unsafe extern "C" fn failing(
    _: *const f64,
    _: usize,
    _: usize,
    _: *mut f64,
    _: *mut c_void,
) -> c_int {
    7
}

/// The peaks of [`peaks_c`]; a channel's `user` points at its own.
static CENTRES: [f64; 2] = [0.2, 0.7];

/// ∫ [`peaks_c`] over the square.
fn peaks_exact() -> f64 {
    let mass = |c: f64| angles(c).1 - angles(c).0;
    mass(CENTRES[0]) + 0.5 * mass(CENTRES[1])
}

/// A Cauchy channel per peak, each with `enhancement`.
fn channels(enhancement: nis_channel_fn) -> Vec<nis_channel> {
    CENTRES
        .iter()
        .map(|c| nis_channel {
            sample: Some(cauchy_sample),
            density: Some(cauchy_density),
            user: c as *const f64 as *mut c_void,
            prior: 0.0,
            enhancement,
        })
        .collect()
}

/// Makes a multi-channel integrator from `json` and `channels` (which must succeed) and
/// integrates [`peaks_c`] with `evals`: the integrator (to free), the status and the result.
fn integrate_peaks(
    json: &str,
    channels: &[nis_channel],
    evals: u64,
) -> (*mut nis_multichannel, c_int, nis_result) {
    let (status, mc) = create_mc(json, channels);
    assert_eq!(status, NIS_OK, "{}", last_error());
    let mut r = nis_result::default();
    let status = unsafe {
        nis_multichannel_integrate(mc, Some(peaks_c), std::ptr::null_mut(), evals, &mut r)
    };
    (mc, status, r)
}

#[test]
fn channels_with_enhancements_through_c_keep_the_integral() {
    let exact = peaks_exact();
    for method in ["uniform", "nis"] {
        let json = format!(r#"{{"method": "{method}", "dim": 2, "seed": 4}}"#);
        let (mc, status, r) = integrate_peaks(&json, &channels(Some(cauchy_peak)), 100_000);
        assert_eq!(status, NIS_OK, "{method}: {}", last_error());
        assert!(
            (r.value - exact).abs() < 5.0 * r.std_err,
            "{method}: {r:?} vs {exact}"
        );
        unsafe { nis_multichannel_free(mc) };
    }
    // A failing enhancement stops the run with an error naming the channel and the callback.
    let json = r#"{"method": "uniform", "dim": 2}"#;
    let (mc, status, _) = integrate_peaks(json, &channels(Some(failing)), 10_000);
    assert_ne!(status, NIS_OK);
    assert!(last_error().contains("enhancement"), "{}", last_error());
    unsafe { nis_multichannel_free(mc) };
}

#[test]
fn channels_are_an_argument_of_the_ordinary_functions() {
    // nis_create_with_channels makes a nis_integrator that nis_integrate and nis_result_* take,
    // with the numbers of the old names (kept as aliases for one release), bit for bit.
    let channels = channels(None);
    for method in ["uniform", "vegas", "nis"] {
        let json = format!(r#"{{"method": "{method}", "dim": 2, "seed": 4}}"#);
        let (old, status, want) = integrate_peaks(&json, &channels, 100_000);
        assert_eq!(status, NIS_OK, "{method}: {}", last_error());
        let json = CString::new(json).unwrap();
        let mut integ = std::ptr::null_mut();
        let status = unsafe {
            nis_create_with_channels(
                json.as_ptr(),
                channels.as_ptr(),
                channels.len(),
                std::ptr::null(),
                &mut integ,
            )
        };
        assert_eq!(status, NIS_OK, "{method}: {}", last_error());
        assert_eq!(unsafe { nis_dim(integ) }, 2);
        let mut r = nis_result::default();
        let status =
            unsafe { nis_integrate(integ, Some(peaks_c), std::ptr::null_mut(), 100_000, &mut r) };
        assert_eq!(status, NIS_OK, "{method}: {}", last_error());
        assert_eq!(r.value.to_bits(), want.value.to_bits(), "{method}");
        assert_eq!(r.std_err.to_bits(), want.std_err.to_bits(), "{method}");
        let (mut m, mut m_old) = ([0.0; 2], [0.0; 2]);
        let (null, no_evals) = (std::ptr::null_mut(), std::ptr::null_mut());
        let status = unsafe { nis_result_channels(integ, null, m.as_mut_ptr(), null, no_evals, 2) };
        assert_eq!(status, NIS_OK);
        let status =
            unsafe { nis_multichannel_channels(old, null, m_old.as_mut_ptr(), null, no_evals, 2) };
        assert_eq!(status, NIS_OK);
        assert_eq!(m, m_old, "{method}");
        unsafe { nis_free(integ) };
        unsafe { nis_multichannel_free(old) };
    }
}

#[test]
fn channels_through_c_integrate_and_report_each_channel() {
    let exact = peaks_exact();
    let channels = channels(None);
    // The three methods, and NIS with a flow per channel besides the default shared one.
    let per_channel = r#""multichannel": {"shared_flow": false}"#;
    for (method, extra) in [
        ("uniform", ""),
        ("vegas", ""),
        ("nis", ""),
        ("nis", per_channel),
    ] {
        let comma = if extra.is_empty() { "" } else { ", " };
        let json = format!(r#"{{"method": "{method}", "dim": 2, "seed": 4{comma}{extra}}}"#);
        let (mc, status, r) = integrate_peaks(&json, &channels, 200_000);
        assert_eq!(status, NIS_OK, "{method}: {}", last_error());
        assert!(
            (r.value - exact).abs() < 5.0 * r.std_err,
            "{method}: {r:?} vs {exact}"
        );
        let (mut w, mut m, mut s, mut e) = ([0.0; 2], [0.0; 2], [0.0; 2], [0u64; 2]);
        let status = unsafe {
            nis_multichannel_channels(
                mc,
                w.as_mut_ptr(),
                m.as_mut_ptr(),
                s.as_mut_ptr(),
                e.as_mut_ptr(),
                2,
            )
        };
        assert_eq!(status, NIS_OK);
        assert!((w[0] + w[1] - 1.0).abs() < 1e-12 && e.iter().all(|n| *n > 0));
        assert!((m[0] + m[1] - r.value).abs() < 1e-9 * r.value.abs());
        // Not split by sign: no signs to read.
        let status = unsafe {
            nis_multichannel_signs(
                mc,
                std::ptr::null_mut(),
                std::ptr::null_mut(),
                std::ptr::null_mut(),
                std::ptr::null_mut(),
                std::ptr::null_mut(),
            )
        };
        assert_eq!(status, NIS_ERR_NO_RESULT);
        unsafe { nis_multichannel_free(mc) };
    }
    // Multi-channel settings that do not exist: a config error.
    let json = r#"{"method": "nis", "dim": 2, "multichannel": {"shared": 1}}"#;
    let (status, mc) = create_mc(json, &channels);
    assert_eq!(status, NIS_ERR_CONFIG);
    assert!(
        mc.is_null() && last_error().contains("multichannel"),
        "{}",
        last_error()
    );
    // A channel that leaves the cube: an error naming it.
    let bad = [nis_channel {
        sample: Some(outside),
        density: Some(cauchy_density),
        user: &CENTRES[0] as *const f64 as *mut c_void,
        prior: 1.0,
        enhancement: None,
    }];
    let (status, mc) = create_mc(r#"{"method": "uniform", "dim": 2}"#, &bad);
    assert_eq!(status, NIS_OK);
    let status = unsafe {
        nis_multichannel_integrate(
            mc,
            Some(peaks_c),
            std::ptr::null_mut(),
            100_000,
            std::ptr::null_mut(),
        )
    };
    assert_eq!(status, NIS_ERR_INVALID_ARGUMENT);
    assert!(last_error().contains("channel 0"), "{}", last_error());
    unsafe { nis_multichannel_free(mc) };
    // Zero channels given, a bad sign mode, a vector integrand: errors, nothing handed out.
    for (ptr, count, signs, json) in [
        (bad.as_ptr(), 0, None, r#"{"method": "uniform", "dim": 2}"#),
        (
            std::ptr::null(),
            0,
            Some("both"),
            r#"{"method": "uniform", "dim": 2}"#,
        ),
        (
            bad.as_ptr(),
            1,
            None,
            r#"{"method": "uniform", "dim": 2, "components": 2}"#,
        ),
    ] {
        let json = CString::new(json).unwrap();
        let signs = signs.map(|s| CString::new(s).unwrap());
        let mut mc = std::ptr::null_mut();
        let status = unsafe {
            nis_multichannel_create(
                json.as_ptr(),
                ptr,
                count,
                signs.as_ref().map_or(std::ptr::null(), |s| s.as_ptr()),
                &mut mc,
            )
        };
        assert_eq!(status, NIS_ERR_INVALID_ARGUMENT, "{}", last_error());
        assert!(mc.is_null());
    }
}

/// f = x₀ − 0.3: F⁺ = 0.245, F⁻ = 0.045.
unsafe extern "C" fn signed_c(
    x: *const f64,
    n: usize,
    dim: usize,
    out: *mut f64,
    _: *mut c_void,
) -> c_int {
    unsafe { each_point(x, n, dim, out, |p| p[0] - 0.3) }
}

#[test]
fn a_signed_integrand_splits_without_channels() {
    let (status, mc) = create_mc(r#"{"method": "vegas", "dim": 2, "seed": 1}"#, &[]);
    assert_eq!(status, NIS_OK, "{}", last_error());
    let mut r = nis_result::default();
    let status = unsafe {
        nis_multichannel_integrate(mc, Some(signed_c), std::ptr::null_mut(), 200_000, &mut r)
    };
    assert_eq!(status, NIS_OK, "{}", last_error());
    let (mut p, mut pe, mut m, mut me, mut frac) = (0.0, 0.0, 0.0, 0.0, 0.0);
    let status = unsafe { nis_multichannel_signs(mc, &mut p, &mut pe, &mut m, &mut me, &mut frac) };
    assert_eq!(status, NIS_OK);
    assert!(
        (p - 0.245).abs() < 5.0 * pe && (m - 0.045).abs() < 5.0 * me,
        "{p} ± {pe}, {m} ± {me}"
    );
    assert!((r.value - 0.2).abs() < 5.0 * r.std_err);
    assert!((frac - 0.045 / 0.29).abs() < 0.01);
    assert_eq!(unsafe { nis_multichannel_stop(mc) }, NIS_STOP_NONE);
    // To a target: met, and the stop says so; a bad target is refused before f is called.
    let status = unsafe {
        nis_multichannel_integrate_to(
            mc,
            Some(signed_c),
            std::ptr::null_mut(),
            1e-3,
            0.0,
            0,
            0.0,
            &mut r,
        )
    };
    assert_eq!(status, NIS_OK, "{}", last_error());
    assert_eq!(unsafe { nis_multichannel_stop(mc) }, NIS_STOP_TARGET);
    assert!(r.std_err <= 1e-3 * r.value.abs() && (r.value - 0.2).abs() < 5.0 * r.std_err);
    for (rel, evals, code) in [
        (-1.0, 0, NIS_ERR_INVALID_ARGUMENT),
        (1e-3, 10, NIS_ERR_CONFIG),
    ] {
        let status = unsafe {
            nis_multichannel_integrate_to(
                mc,
                Some(signed_c),
                std::ptr::null_mut(),
                rel,
                0.0,
                evals,
                0.0,
                std::ptr::null_mut(),
            )
        };
        assert_eq!(status, code, "{}", last_error());
    }
    unsafe { nis_multichannel_free(mc) };
}
