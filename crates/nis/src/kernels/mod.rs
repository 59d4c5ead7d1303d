//! Hot CPU code. Dense layers run on the `gemm` crate; the loops around them (bias, activation,
//! one-blob encoding, Adam) are fused and compiled for several SIMD levels with runtime dispatch
//! (`multiversion`), never for the build machine only. Every kernel here is single-threaded:
//! callers split the batch into fixed chunks and run those in parallel, which keeps results
//! independent of the thread count.

pub mod conv;
pub mod dense;
pub mod elementwise;

/// Parameters per parallel work item of an optimiser's or an average's elementwise update
/// (large enough to pay for the hand-over to a thread); vectors of up to two blocks stay on the
/// calling thread.
pub const PAR_BLOCK: usize = 4096;

/// Whether an elementwise update of `len` parameters runs in parallel blocks of [`PAR_BLOCK`]
/// (more than two blocks) or on the calling thread.
pub(crate) fn in_parallel_blocks(len: usize) -> bool {
    len > 2 * PAR_BLOCK
}

/// The most vectors of parameter gradients a backward pass keeps at once: a batch's chunks are
/// cut into at most this many groups of consecutive chunks, each summing into its own vector
/// (a 256-point training step: 4 chunks, 4 groups; 16,384 points: 32 chunks, 16 groups of 2).
pub const GRADIENT_GROUPS: usize = 16;

/// The backward passes' reduction: `items` (one per chunk, in chunk order) cut into at most
/// [`GRADIENT_GROUPS`] groups of consecutive items, each group one parallel work item that
/// runs `f` on its items in order with a zeroed vector of `out.len()` gradients of its own to
/// add into; the groups' vectors are then summed into `out` in group order
/// ([`sum_in_order`]). The groups depend on the item count alone, so `out` does not depend on
/// the thread count. Returns what `f` returned per item, in item order.
pub(crate) fn sum_in_groups<I: Send, T: Send>(
    items: Vec<I>,
    out: &mut [f32],
    f: impl Fn(I, &mut [f32]) -> T + Sync + Send,
) -> Vec<T> {
    use rayon::prelude::*;
    let per_group = items.len().div_ceil(GRADIENT_GROUPS).max(1);
    let len = out.len();
    let groups: Vec<(Vec<f32>, Vec<T>)> = items
        .into_par_iter()
        .chunks(per_group)
        .map(|group| {
            let mut part = vec![0.0f32; len];
            let results = group.into_iter().map(|item| f(item, &mut part)).collect();
            (part, results)
        })
        .collect();
    let (parts, results): (Vec<_>, Vec<_>) = groups.into_iter().unzip();
    sum_in_order(&parts, out);
    results.into_iter().flatten().collect()
}

/// `out[i] = Σ_g parts[g][i]`, summed in the order of `parts` for every `i` (so the result does
/// not depend on scheduling); in parallel blocks of [`PAR_BLOCK`] for long vectors.
pub(crate) fn sum_in_order(parts: &[Vec<f32>], out: &mut [f32]) {
    use rayon::prelude::*;
    let block = |(b, out): (usize, &mut [f32])| {
        let (at, len) = (b * PAR_BLOCK, out.len());
        out.fill(0.0);
        for part in parts {
            for (o, p) in out.iter_mut().zip(&part[at..at + len]) {
                *o += p;
            }
        }
    };
    if in_parallel_blocks(out.len()) {
        out.par_chunks_mut(PAR_BLOCK).enumerate().for_each(block);
    } else {
        out.chunks_mut(PAR_BLOCK).enumerate().for_each(block);
    }
}

/// Runs `op` on a worker thread of rayon's pool. Called from outside the pool, every parallel
/// loop is handed to the pool under a lock and waited for with a wake-up; a training step runs
/// dozens of small loops (per coupling, per dense layer), and on a batch of a few hundred points
/// those hand-overs cost a fifth of the step. Inside, the loops are scheduled by work stealing.
pub fn in_pool<R: Send>(op: impl FnOnce() -> R + Send) -> R {
    rayon::scope(|_| op())
}

/// Points per parallel work item when evaluating a batch of `n` points: 256 for large batches,
/// and a sixteenth of a smaller one (a training batch of 256 points: 16 items of 16), so that an
/// expensive integrand keeps every core busy while the flow trains on small batches. Each value
/// is computed independently, so the split affects speed only, never the values.
pub fn points_per_task(n: usize) -> usize {
    n.div_ceil(16).clamp(1, 256)
}

/// Rows per parallel work item of a large batch. Fixed, so results do not depend on the number
/// of threads.
pub const CHUNK_ROWS: usize = 512;

/// The fewest rows per parallel work item ([`chunk_rows`]).
pub const MIN_CHUNK_ROWS: usize = 64;

/// Work items a batch is cut into when it is too small for [`CHUNK_ROWS`]-row chunks.
pub const MIN_CHUNKS: usize = 8;

/// Rows per parallel work item in a batch of `rows` rows: [`CHUNK_ROWS`] for large batches;
/// smaller batches are cut into [`MIN_CHUNKS`]/2 to [`MIN_CHUNKS`] items of a power of two of
/// rows, but never fewer than [`MIN_CHUNK_ROWS`] rows (a training batch of 1024 points: 8 items
/// of 128; of 256: 4 of 64), so the cores share a training step. A function of `rows` alone, so results do not depend
/// on the number of threads.
pub fn chunk_rows(rows: usize) -> usize {
    rows.div_ceil(MIN_CHUNKS)
        .next_power_of_two()
        .clamp(MIN_CHUNK_ROWS, CHUNK_ROWS)
}
