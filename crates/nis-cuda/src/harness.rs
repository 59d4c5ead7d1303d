//! The CPU harness of the GPU kernels: kernels/flow.cuh's per-thread bodies compiled for the CPU
//! by the build script, checked here against nis's own transforms, encoding and flow.

use std::os::raw::c_int;

extern "C" {
    pub fn nis_cpu_uniform(seed: u64, i: u64) -> f32;
    pub fn nis_cpu_one_blob(s: f32, k: c_int, j: c_int) -> f32;
    pub fn nis_cpu_pq(p: *const f32, k: c_int, t: f32, inverse: c_int, log_det: *mut f64) -> f32;
    pub fn nis_cpu_rq(p: *const f32, k: c_int, t: f64, inverse: c_int, log_det: *mut f64) -> f64;
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
mod tests;
