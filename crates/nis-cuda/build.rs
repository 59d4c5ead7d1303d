//! Builds the CPU harness of the GPU kernels (kernels/harness.c over kernels/flow.cuh), so that
//! the tests run the kernels' bodies on any machine. The GPU compiles the same header at run
//! time through NVRTC.

fn main() {
    println!("cargo:rerun-if-changed=kernels/flow.cuh");
    println!("cargo:rerun-if-changed=kernels/harness.c");
    cc::Build::new()
        .file("kernels/harness.c")
        .flag_if_supported("-ffp-contract=off")
        // Knot arrays are filled up to the bin count, which gcc cannot see is at least one.
        .flag_if_supported("-Wno-maybe-uninitialized")
        .opt_level(2)
        .compile("nis_cuda_harness");
    // The kernels' libm functions (exp, log, sqrt).
    println!("cargo:rustc-link-lib=m");
}
