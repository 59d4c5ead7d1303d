//! Hot CPU code. Dense layers run on the `gemm` crate; the loops around them (bias, activation,
//! one-blob encoding, Adam) are fused and compiled for several SIMD levels with runtime dispatch
//! (`multiversion`), never for the build machine only. Every kernel here is single-threaded:
//! callers split the batch into fixed chunks and run those in parallel, which keeps results
//! independent of the thread count.

pub mod conv;
pub mod dense;
pub mod elementwise;

/// Rows per parallel work item. Fixed, so results do not depend on the number of threads.
pub const CHUNK_ROWS: usize = 512;
