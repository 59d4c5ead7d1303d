//! Multi-channel integration and sign splitting from C: a channel is two batch callbacks and a
//! user pointer ([`nis_channel`]); [`nis_multichannel_create`] makes the integrator (a sampler of
//! the method per channel and sign), [`nis_multichannel_integrate`] runs it, and
//! [`nis_multichannel_channels`] / [`nis_multichannel_signs`] read what each channel and sign
//! contributed.

use std::ffi::{c_char, c_int, c_void};
use std::sync::Mutex;

use nis::channels::{Channel, ChannelSet};
use nis::integrate::multichannel::{MultiChannel, MultiChannelConfig, Signs};
use nis::integrate::IntegrationResult;

use super::callback::Callback;
use super::config::Config;
use super::target::{copy_warnings, stop_code, target_of};
use super::{nis_integrand_fn, nis_result, text, write_result};
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

/// A multi-channel integrator (opaque).
pub struct nis_multichannel {
    integrator: MultiChannel,
    concurrent_callback: bool,
    last: Option<IntegrationResult>,
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

/// Creates a multi-channel integrator from the JSON config of `nis_create` (method, dim, seed,
/// the methods' sections; `"components"` must be 1) and `count` channels, and stores it in `*out`
/// (NULL on failure). `signs` is `"auto"` (split f into f > 0 and f < 0 when a pilot sees both),
/// `"split"`, `"whole"`, or NULL for auto. `count` 0 with `channels` NULL integrates without
/// channels (one identity channel), split by sign; `count` 0 with channels given is an error.
/// A key `"multichannel"` of the config patches the multi-channel settings, e.g.
/// `{"multichannel": {"shared_flow": false, "adapt_fraction": 0.3}}` (NIS with a flow per
/// channel instead of the default one flow shared by the channels).
///
/// # Safety
/// `json` and a non-NULL `signs` must be NUL-terminated; `channels` must hold `count` channels
/// whose callbacks and user pointers stay valid while the integrator lives; `out` writable.
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
        let mc_config = MultiChannelConfig { signs, ..mc_config };
        if count == 0 && !channels.is_null() {
            return Err(Failure::invalid(
                "zero channels given: pass channels NULL with count 0 to integrate without \
                 channels (split by sign)",
            ));
        }
        let integrator = if count == 0 {
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
        let mc = nis_multichannel {
            integrator,
            concurrent_callback: config.concurrent_callback,
            last: None,
        };
        // SAFETY: `out` was checked non-NULL.
        unsafe { *out = Box::into_raw(Box::new(mc)) };
        Ok(())
    })
}

/// Frees a multi-channel integrator (NULL is ignored).
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

/// The integrator behind a handle.
unsafe fn multichannel<'a>(mc: *mut nis_multichannel) -> Outcome<&'a mut nis_multichannel> {
    // SAFETY: NULL or live (caller's contract).
    unsafe { mc.as_mut() }.ok_or_else(|| Failure::null("the multi-channel integrator"))
}

/// Integrates `f` with `evals` evaluations through the channels (see `nis::integrate::multichannel`)
/// and writes the summary into `*result` (which may be NULL); the channels' and signs' parts are
/// then read with [`nis_multichannel_channels`] and [`nis_multichannel_signs`].
///
/// # Safety
/// `mc` must be live; `result` NULL or writable; `f` must honour `nis_integrand_fn`'s contract.
#[no_mangle]
pub unsafe extern "C" fn nis_multichannel_integrate(
    mc: *mut nis_multichannel,
    f: nis_integrand_fn,
    user: *mut c_void,
    evals: u64,
    result: *mut nis_result,
) -> c_int {
    guard(|| {
        let mc = unsafe { multichannel(mc) }?;
        unsafe { run(mc, f, user, result, |m, f| m.integrate(f, evals)) }
    })
}

/// Runs `call` on the integrator with `f` wrapped as an integrand, writes its summary into
/// `*result` (NULL or writable) and keeps it as the last result.
unsafe fn run(
    mc: &mut nis_multichannel,
    f: nis_integrand_fn,
    user: *mut c_void,
    result: *mut nis_result,
    call: impl FnOnce(&mut MultiChannel, &Callback) -> nis::Result<IntegrationResult>,
) -> Outcome<()> {
    let f = f.ok_or_else(|| Failure::null("the integrand callback"))?;
    let callback = Callback::new(f, user, mc.integrator.dim(), 1, mc.concurrent_callback);
    let r = call(&mut mc.integrator, &callback).map_err(|e| callback.failure(e))?;
    // SAFETY: NULL or writable (caller's contract).
    unsafe { write_result(result, &r) };
    mc.last = Some(r);
    Ok(())
}

/// Integrates `f` through the channels until the standard error is at most
/// max(`abs_err`, `rel_err`·|value|) or a limit is reached, with `nis_integrate_to`'s arguments
/// and checks (all before `f` is called); [`nis_multichannel_stop`] then says which ended it.
///
/// # Safety
/// As [`nis_multichannel_integrate`].
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
    guard(|| {
        let mc = unsafe { multichannel(mc) }?;
        if f.is_none() {
            return Err(Failure::null("the integrand callback"));
        }
        let target = target_of(rel_err, abs_err, max_evals, max_seconds)?;
        mc.integrator.check_target(&target)?;
        unsafe { run(mc, f, user, result, |m, f| m.integrate_to(f, &target)) }
    })
}

/// Why the last result's run stopped, as [`nis_result_stop`] says for one integrator.
///
/// # Safety
/// `mc` must be a live multi-channel integrator or NULL (then `NIS_STOP_NONE`).
#[no_mangle]
pub unsafe extern "C" fn nis_multichannel_stop(mc: *const nis_multichannel) -> c_int {
    // SAFETY: NULL or live (caller's contract).
    stop_code(unsafe { mc.as_ref() }.and_then(|m| m.last.as_ref()))
}

/// Copies the last result's per-channel figures: the weights a_k, each channel's contribution
/// and its standard error, and its evaluations in the estimate. Any buffer may be NULL; `k` must
/// equal the number of channels (1 without channels).
///
/// # Safety
/// `mc` must be live; non-NULL buffers must hold `k` values.
#[no_mangle]
pub unsafe extern "C" fn nis_multichannel_channels(
    mc: *const nis_multichannel,
    weights: *mut f64,
    means: *mut f64,
    std_errs: *mut f64,
    evals: *mut u64,
    k: usize,
) -> c_int {
    guard(|| {
        // SAFETY: NULL or live (caller's contract).
        let mc = unsafe { mc.as_ref() }.ok_or_else(|| Failure::null("the integrator"))?;
        let report = mc
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
/// `mc` must be live; non-NULL pointers writable.
#[no_mangle]
pub unsafe extern "C" fn nis_multichannel_signs(
    mc: *const nis_multichannel,
    positive: *mut f64,
    positive_err: *mut f64,
    negative: *mut f64,
    negative_err: *mut f64,
    negative_fraction: *mut f64,
) -> c_int {
    guard(|| {
        // SAFETY: NULL or live (caller's contract).
        let mc = unsafe { mc.as_ref() }.ok_or_else(|| Failure::null("the integrator"))?;
        let s = mc
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

/// Copies the last result's warnings as `nis_result_warnings` does.
///
/// # Safety
/// `mc` must be live; `buffer` NULL or writable for `capacity` bytes.
#[no_mangle]
pub unsafe extern "C" fn nis_multichannel_warnings(
    mc: *const nis_multichannel,
    buffer: *mut c_char,
    capacity: usize,
) -> usize {
    // SAFETY: NULL or live (caller's contract); the buffer forwarded under the same contract.
    unsafe { copy_warnings(mc.as_ref().and_then(|m| m.last.as_ref()), buffer, capacity) }
}
