//! The CPU harness of the GPU kernels: kernels/flow.cuh's per-thread bodies compiled for the CPU
//! by the build script, checked here against nis's own transforms, encoding and flow.

use std::os::raw::c_int;

extern "C" {
    pub fn nis_cpu_uniform(seed: u64, i: u64) -> f32;
    pub fn nis_cpu_one_blob(s: f32, k: c_int, j: c_int) -> f32;
    pub fn nis_cpu_pq(p: *const f32, k: c_int, t: f32, inverse: c_int, log_det: *mut f64) -> f32;
    pub fn nis_cpu_rq(p: *const f32, k: c_int, t: f64, inverse: c_int, log_det: *mut f64) -> f64;
    pub fn nis_cpu_pq_backward(
        p: *const f32,
        k: c_int,
        x: f32,
        g_y: f32,
        g_ld: f32,
        g_p: *mut f32,
    ) -> f32;
    pub fn nis_cpu_rq_backward(
        p: *const f32,
        k: c_int,
        x: f64,
        g_y: f64,
        g_ld: f64,
        g_p: *mut f32,
    ) -> f64;
    pub fn nis_cpu_one_blob_backward(s: f32, k: c_int, e: *const f32, g_e: *const f32) -> f32;
    #[allow(clippy::too_many_arguments)]
    pub fn nis_cpu_adam(
        p: *mut f32,
        g: *const f32,
        m: *mut f32,
        v: *mut f32,
        n: i64,
        lr_t: f32,
        beta1: f32,
        beta2: f32,
        eps: f32,
        grad_scale: f32,
    );
    #[allow(clippy::too_many_arguments)]
    pub fn nis_cpu_coupling_backward(
        kind: c_int,
        bins: c_int,
        out: *const f32,
        input: *const f32,
        g_u: *mut f32,
        g_ld: *const f32,
        g_out: *mut f32,
        rows: i64,
        dim: c_int,
        b: *const c_int,
        nb: c_int,
    );
    #[allow(clippy::too_many_arguments)]
    pub fn nis_cpu_coupling(
        kind: c_int,
        bins: c_int,
        inverse: c_int,
        out: *const f32,
        u: *mut f32,
        log_q: *mut f64,
        rows: i64,
        dim: c_int,
        b: *const c_int,
        nb: c_int,
    );
}

#[cfg(test)]
mod plan_tests;
#[cfg(test)]
mod tests;
