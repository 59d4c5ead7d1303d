//! Multi-channel integration and sign splitting from C: a channel is two batch callbacks and a
//! user pointer ([`nis_channel`]); [`nis_create_with_channels`] makes an ordinary
//! `nis_integrator` that integrates through them (a sampler of the method per channel and sign),
//! which [`nis_integrate`](crate::nis_integrate) and [`nis_integrate_to`](crate::nis_integrate_to)
//! run like any other; [`nis_result_channels`] / [`nis_result_signs`] read what each channel and
//! sign contributed. The `nis_multichannel_*` functions of the previous release remain, for one
//! more release, as thin aliases of these.

use std::ffi::{c_char, c_int, c_void};
use std::sync::Mutex;

use nis::channels::{Channel, ChannelSet};
use nis::integrate::multichannel::{MultiChannel, MultiChannelConfig, Signs};
use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;

use super::config::Config;
use super::target::{nis_integrate_to, nis_result_stop, nis_result_warnings};
use super::{
    hand_out, nis_integrand_fn, nis_integrate, nis_integrator, nis_result, text, SAMPLE_STREAM,
};
use crate::status::{guard, Failure, Outcome, NIS_ERR_CONFIG, NIS_ERR_NO_RESULT};

/// A channel's map or density: reads `n` points `in` (row-major, `dim` coordinates each) and
/// writes `out` (the mapped points, n × dim, for `sample`; the densities, n values, for
/// `density`); returns 0, or non-zero to stop the integration with `NIS_ERR_INVALID_ARGUMENT`.
pub type nis_channel_fn = Option<
    unsafe extern "C" fn(
        input: *const f64,
        n: usize,
        dim: usize,
        out: *mut f64,
        user: *mut c_void,
    ) -> c_int,
>;

/// A channel: `sample` maps uniform points u of the unit cube to x = φ(u) in it, `density` gives
/// the density g(x) of those points at any x of the cube (0 where φ does not reach), `user` is
/// handed to all callbacks, `prior` is its a-priori weight (0: 1). `enhancement`, optional (NULL:
/// none), gives w(x) ≥ 0 at any x (n values), large where the channel's peak is (its diagram's
/// |M|², its propagator): the channel weights are then a_k w_k/Σ_j a_j w_j instead of
/// a_k g_k/Σ_j a_j g_j (single-diagram enhancement). The callbacks of one channel are never
/// called from two threads at once.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct nis_channel {
    pub sample: nis_channel_fn,
    pub density: nis_channel_fn,
    pub user: *mut c_void,
    pub prior: f64,
    pub enhancement: nis_channel_fn,
}

/// The handle of the previous release's `nis_multichannel_*` functions (opaque): an ordinary
/// integrator made by [`nis_create_with_channels`]. Deprecated: use `nis_integrator`.
pub struct nis_multichannel {
    integ: nis_integrator,
}

type RawFn = unsafe extern "C" fn(*const f64, usize, usize, *mut f64, *mut c_void) -> c_int;

/// A C channel as the library's [`Channel`].
struct CChannel {
    index: usize,
    dim: usize,
    sample: RawFn,
    density: RawFn,
    enhancement: Option<RawFn>,
    user: *mut c_void,
    lock: Mutex<()>,
}

// SAFETY: `user` is only handed back to the channel's own callbacks, and the lock makes their
// calls exclusive.
unsafe impl Send for CChannel {}
unsafe impl Sync for CChannel {}

impl CChannel {
    fn call(&self, f: RawFn, what: &str, input: &[f64], out: &mut [f64]) -> nis::Result<()> {
        let n = input.len() / self.dim;
        let _exclusive = self.lock.lock().unwrap_or_else(|e| e.into_inner());
        // SAFETY: `input` holds n·dim values and `out` what the callback writes (the caller's
        // contract of nis_channel_fn).
        let status = unsafe { f(input.as_ptr(), n, self.dim, out.as_mut_ptr(), self.user) };
        if status == 0 {
            return Ok(());
        }
        Err(nis::Error::Channel {
            channel: self.index,
            point: input[..self.dim.min(input.len())].to_vec(),
            reason: format!("its {what} callback returned {status} on a batch from this point"),
        })
    }
}

impl Channel for CChannel {
    fn dim(&self) -> usize {
        self.dim
    }
    fn sample(&self, u: &[f64], x: &mut [f64]) -> nis::Result<()> {
        self.call(self.sample, "sample", u, x)
    }
    fn density(&self, x: &[f64], g: &mut [f64]) -> nis::Result<()> {
        self.call(self.density, "density", x, g)
    }
    fn has_enhancement(&self) -> bool {
        self.enhancement.is_some()
    }
    fn enhancement(&self, x: &[f64], w: &mut [f64]) -> nis::Result<()> {
        match self.enhancement {
            Some(e) => self.call(e, "enhancement", x, w),
            None => self.density(x, w),
        }
    }
}

/// Creates an integrator through channels from the JSON config of `nis_create` (method, dim, seed,
/// the methods' sections; `"components"` must be 1) and `count` channels, and stores it in `*out`
/// (NULL on failure): an ordinary `nis_integrator`, run with `nis_integrate` or
/// `nis_integrate_to` and freed with `nis_free`; [`nis_result_channels`] and
/// [`nis_result_signs`] read its parts. `signs` is `"auto"` (split f into f > 0 and f < 0 when
/// a pilot sees both), `"split"`, `"whole"`, or NULL for auto. `count` 0 with `channels` NULL integrates without
/// channels (one identity channel), split by sign; `count` 0 with channels given is an error.
/// A key `"multichannel"` of the config patches the multi-channel settings, e.g.
/// `{"multichannel": {"shared_flow": false, "adapt_fraction": 0.3}}` (NIS with a flow per
/// channel instead of the default one flow shared by the channels).
///
/// # Safety
/// `json` and a non-NULL `signs` must be NUL-terminated; `channels` must hold `count` channels
/// whose callbacks and user pointers stay valid while the integrator lives; `out` writable.
#[no_mangle]
pub unsafe extern "C" fn nis_create_with_channels(
    json: *const c_char,
    channels: *const nis_channel,
    count: usize,
    signs: *const c_char,
    out: *mut *mut nis_integrator,
) -> c_int {
    guard(|| {
        if out.is_null() {
            return Err(Failure::null("out"));
        }
        // SAFETY: checked non-NULL above.
        unsafe { *out = std::ptr::null_mut() };
        // SAFETY: forwarded under the same contract.
        let integ = unsafe { with_channels(json, channels, count, signs) }?;
        // SAFETY: `out` was checked non-NULL.
        unsafe { hand_out(out, integ) };
        Ok(())
    })
}

/// The integrator [`nis_create_with_channels`] hands out.
///
/// # Safety
/// As [`nis_create_with_channels`].
unsafe fn with_channels(
    json: *const c_char,
    channels: *const nis_channel,
    count: usize,
    signs: *const c_char,
) -> Outcome<nis_integrator> {
    let json = unsafe { text(json, "the JSON config") }?;
    let mut config: Config = serde_json::from_str(json)
        .map_err(|e| Failure::new(NIS_ERR_CONFIG, format!("JSON config: {e}")))?;
    let patch = config.settings.remove("multichannel");
    let mc_config = match patch {
        None => MultiChannelConfig::default(),
        Some(v) => serde_json::from_value::<MultiChannelConfig>(v).map_err(|e| {
            Failure::new(
                NIS_ERR_CONFIG,
                format!("JSON config, \"multichannel\": {e}"),
            )
        })?,
    };
    if config.components != 1 {
        return Err(Failure::invalid(
            "multi-channel integration takes scalar integrands (components 1)",
        ));
    }
    let signs = if signs.is_null() {
        Signs::Auto
    } else {
        match unsafe { text(signs, "signs") }? {
            "auto" => Signs::Auto,
            "split" => Signs::Split,
            "whole" => Signs::Whole,
            s => {
                return Err(Failure::invalid(format!(
                    "signs {s:?}: expected auto, split or whole"
                )))
            }
        }
    };
    let settings = config.settings()?;
    let seed = settings.seed_of(config.method);
    let mc_config = MultiChannelConfig { signs, ..mc_config };
    if count == 0 && !channels.is_null() {
        return Err(Failure::invalid(
            "zero channels given: pass channels NULL with count 0 to integrate without \
                 channels (split by sign)",
        ));
    }
    let mc = if count == 0 {
        MultiChannel::single(config.dim, config.method, settings, mc_config)?
    } else {
        if channels.is_null() {
            return Err(Failure::null("channels"));
        }
        // SAFETY: `channels` holds `count` channels (caller's contract).
        let given = unsafe { std::slice::from_raw_parts(channels, count) };
        let mut list: Vec<Box<dyn Channel>> = Vec::with_capacity(count);
        let mut priors = Vec::with_capacity(count);
        for (index, c) in given.iter().enumerate() {
            let (Some(sample), Some(density)) = (c.sample, c.density) else {
                return Err(Failure::null(&format!("channel {index}'s callbacks")));
            };
            list.push(Box::new(CChannel {
                index,
                dim: config.dim,
                sample,
                density,
                enhancement: c.enhancement,
                user: c.user,
                lock: Mutex::new(()),
            }));
            priors.push(if c.prior == 0.0 { 1.0 } else { c.prior });
        }
        let set = ChannelSet::with_priors(list, priors)?;
        MultiChannel::new(set, config.method, settings, mc_config)?
    };
    Ok(nis_integrator {
        integrator: Box::new(mc),
        components: 1,
        concurrent_callback: config.concurrent_callback,
        sample_rng: Pcg64Mcg::seed_from_u64(seed ^ SAMPLE_STREAM),
        last: None,
    })
}

/// Deprecated alias of [`nis_create_with_channels`] (kept for one release): the same integrator
/// behind the previous release's handle, freed with [`nis_multichannel_free`].
///
/// # Safety
/// As [`nis_create_with_channels`].
#[no_mangle]
pub unsafe extern "C" fn nis_multichannel_create(
    json: *const c_char,
    channels: *const nis_channel,
    count: usize,
    signs: *const c_char,
    out: *mut *mut nis_multichannel,
) -> c_int {
    guard(|| {
        if out.is_null() {
            return Err(Failure::null("out"));
        }
        // SAFETY: checked non-NULL above.
        unsafe { *out = std::ptr::null_mut() };
        // SAFETY: forwarded under the same contract.
        let integ = unsafe { with_channels(json, channels, count, signs) }?;
        // SAFETY: `out` was checked non-NULL.
        unsafe { *out = Box::into_raw(Box::new(nis_multichannel { integ })) };
        Ok(())
    })
}

/// Copies the last result's per-channel figures (an integrator made by
/// [`nis_create_with_channels`]): the weights a_k, each channel's contribution
/// and its standard error, and its evaluations in the estimate. Any buffer may be NULL; `k` must
/// equal the number of channels (1 without channels).
///
/// # Safety
/// `integ` must be live; non-NULL buffers must hold `k` values.
#[no_mangle]
pub unsafe extern "C" fn nis_result_channels(
    integ: *const nis_integrator,
    weights: *mut f64,
    means: *mut f64,
    std_errs: *mut f64,
    evals: *mut u64,
    k: usize,
) -> c_int {
    guard(|| {
        // SAFETY: NULL or live (caller's contract).
        let integ = unsafe { integ.as_ref() }.ok_or_else(|| Failure::null("the integrator"))?;
        let report = integ
            .last
            .as_ref()
            .and_then(|r| r.channels.as_ref())
            .ok_or_else(|| Failure::new(NIS_ERR_NO_RESULT, "no multi-channel result yet"))?;
        if k != report.means.len() {
            return Err(Failure::invalid(format!(
                "k = {k}, but the result has {} channels",
                report.means.len()
            )));
        }
        for (p, v) in [
            (weights, &report.weights),
            (means, &report.means),
            (std_errs, &report.std_errs),
        ] {
            if !p.is_null() {
                // SAFETY: `p` holds k values (caller's contract).
                unsafe { std::slice::from_raw_parts_mut(p, k) }.copy_from_slice(v);
            }
        }
        if !evals.is_null() {
            // SAFETY: `evals` holds k values (caller's contract).
            unsafe { std::slice::from_raw_parts_mut(evals, k) }.copy_from_slice(&report.evals);
        }
        Ok(())
    })
}

/// Copies the last result's positive and negative parts, F = F⁺ − F⁻, with their standard errors
/// and the share of negative weights F⁻/(F⁺ + F⁻) (any pointer may be NULL); `NIS_ERR_NO_RESULT`
/// when the last result was not split by sign.
///
/// # Safety
/// `integ` must be live; non-NULL pointers writable.
#[no_mangle]
pub unsafe extern "C" fn nis_result_signs(
    integ: *const nis_integrator,
    positive: *mut f64,
    positive_err: *mut f64,
    negative: *mut f64,
    negative_err: *mut f64,
    negative_fraction: *mut f64,
) -> c_int {
    guard(|| {
        // SAFETY: NULL or live (caller's contract).
        let integ = unsafe { integ.as_ref() }.ok_or_else(|| Failure::null("the integrator"))?;
        let s = integ
            .last
            .as_ref()
            .and_then(|r| r.channels.as_ref())
            .and_then(|c| c.signs)
            .ok_or_else(|| {
                Failure::new(NIS_ERR_NO_RESULT, "the last result was not split by sign")
            })?;
        for (p, v) in [
            (positive, s.positive),
            (positive_err, s.positive_err),
            (negative, s.negative),
            (negative_err, s.negative_err),
            (negative_fraction, s.negative_fraction),
        ] {
            // SAFETY: NULL or writable (caller's contract).
            if let Some(p) = unsafe { p.as_mut() } {
                *p = v;
            }
        }
        Ok(())
    })
}

/// The integrator behind an old handle (NULL for NULL).
fn inner(mc: *mut nis_multichannel) -> *mut nis_integrator {
    if mc.is_null() {
        return std::ptr::null_mut();
    }
    // SAFETY: non-NULL, and live (the callers' contract).
    unsafe { std::ptr::addr_of_mut!((*mc).integ) }
}

/// Frees an integrator made by [`nis_multichannel_create`] (NULL is ignored). Deprecated alias.
///
/// # Safety
/// `mc` must come from [`nis_multichannel_create`] and not be used afterwards.
#[no_mangle]
pub unsafe extern "C" fn nis_multichannel_free(mc: *mut nis_multichannel) {
    if !mc.is_null() {
        // SAFETY: made by Box::into_raw in nis_multichannel_create (caller's contract).
        drop(unsafe { Box::from_raw(mc) });
    }
}

/// Deprecated alias of [`nis_integrate`].
///
/// # Safety
/// As [`nis_integrate`].
#[no_mangle]
pub unsafe extern "C" fn nis_multichannel_integrate(
    mc: *mut nis_multichannel,
    f: nis_integrand_fn,
    user: *mut c_void,
    evals: u64,
    result: *mut nis_result,
) -> c_int {
    // SAFETY: forwarded under the same contract.
    unsafe { nis_integrate(inner(mc), f, user, evals, result) }
}

/// Deprecated alias of [`nis_integrate_to`].
///
/// # Safety
/// As [`nis_integrate_to`].
#[no_mangle]
pub unsafe extern "C" fn nis_multichannel_integrate_to(
    mc: *mut nis_multichannel,
    f: nis_integrand_fn,
    user: *mut c_void,
    rel_err: f64,
    abs_err: f64,
    max_evals: u64,
    max_seconds: f64,
    result: *mut nis_result,
) -> c_int {
    // SAFETY: forwarded under the same contract.
    unsafe {
        nis_integrate_to(
            inner(mc),
            f,
            user,
            rel_err,
            abs_err,
            max_evals,
            max_seconds,
            result,
        )
    }
}

/// Deprecated alias of [`nis_result_stop`].
///
/// # Safety
/// `mc` must be a live multi-channel integrator or NULL (then `NIS_STOP_NONE`).
#[no_mangle]
pub unsafe extern "C" fn nis_multichannel_stop(mc: *const nis_multichannel) -> c_int {
    // SAFETY: forwarded under the same contract.
    unsafe { nis_result_stop(inner(mc.cast_mut())) }
}

/// Deprecated alias of [`nis_result_channels`].
///
/// # Safety
/// As [`nis_result_channels`].
#[no_mangle]
pub unsafe extern "C" fn nis_multichannel_channels(
    mc: *const nis_multichannel,
    weights: *mut f64,
    means: *mut f64,
    std_errs: *mut f64,
    evals: *mut u64,
    k: usize,
) -> c_int {
    // SAFETY: forwarded under the same contract.
    unsafe { nis_result_channels(inner(mc.cast_mut()), weights, means, std_errs, evals, k) }
}

/// Deprecated alias of [`nis_result_signs`].
///
/// # Safety
/// As [`nis_result_signs`].
#[no_mangle]
pub unsafe extern "C" fn nis_multichannel_signs(
    mc: *const nis_multichannel,
    positive: *mut f64,
    positive_err: *mut f64,
    negative: *mut f64,
    negative_err: *mut f64,
    negative_fraction: *mut f64,
) -> c_int {
    // SAFETY: forwarded under the same contract.
    unsafe {
        nis_result_signs(
            inner(mc.cast_mut()),
            positive,
            positive_err,
            negative,
            negative_err,
            negative_fraction,
        )
    }
}

/// Deprecated alias of [`nis_result_warnings`].
///
/// # Safety
/// `mc` must be live; `buffer` NULL or writable for `capacity` bytes.
#[no_mangle]
pub unsafe extern "C" fn nis_multichannel_warnings(
    mc: *const nis_multichannel,
    buffer: *mut c_char,
    capacity: usize,
) -> usize {
    // SAFETY: forwarded under the same contract.
    unsafe { nis_result_warnings(inner(mc.cast_mut()), buffer, capacity) }
}
