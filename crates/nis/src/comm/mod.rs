//! Processes that integrate together: the few collective operations the integrators and the
//! renderer need to run data-parallel over MPI ranks ([`Communicator`]), a handle to them
//! ([`Comm`]), and the single-process implementation every run uses unless told otherwise.
//!
//! The integrators' code is the same with one process and with many: each rank draws its share of
//! every batch from its own random stream ([`Comm::stream_seed`]), evaluates the integrand on it,
//! and the sums the estimate and the training need (gradients, sums of weights, map statistics)
//! are reduced with [`Communicator::sum_f64`] and [`Communicator::sum_f32`], whose order of
//! summation is fixed by the rank count alone. Floating-point addition is not associative, so an
//! all-reduce whose order the MPI library chooses (MPI_Allreduce's may depend on message timing
//! or topology) would let the same seed give different numbers on different runs; a fixed order
//! makes every rank hold bit-identical flows after every step, and one seed and rank count give
//! one result. With one process every reduction is the identity, so results are bit-identical to
//! those of a build without MPI.
//!
//! The MPI implementation (`mpi::MpiComm`, feature `mpi`) sums with a binomial tree whose
//! pairing depends only on the ranks: at step s = 1, 2, 4, …, rank r with r mod 2s = s sends its
//! partial sum to rank r − s, which adds it after its own; rank 0 then broadcasts the total.

#[cfg(feature = "mpi")]
pub mod mpi;

use std::sync::Arc;

use crate::error::{Error, Result};

/// The collective operations of a group of processes (MPI ranks). Every rank must call the same
/// operations in the same order with slices of the same length.
pub trait Communicator: Send + Sync {
    /// This process's rank, 0 ≤ rank < size.
    fn rank(&self) -> usize;
    /// Processes in the group.
    fn size(&self) -> usize;
    /// Element-wise sum over the ranks, in an order fixed by the rank count; every rank gets the
    /// same result.
    fn sum_f64(&self, values: &mut [f64]);
    /// [`Communicator::sum_f64`] for `f32` (gradients).
    fn sum_f32(&self, values: &mut [f32]);
    /// Element-wise maximum over the ranks (exact in any order), on every rank.
    fn max_f64(&self, values: &mut [f64]);
    /// Rank `root`'s `bytes` to every rank (resized to fit).
    fn broadcast_bytes(&self, root: usize, bytes: &mut Vec<u8>);
}

/// One process alone: every reduction is the identity.
#[derive(Clone, Copy, Debug, Default)]
pub struct SingleProcess;

impl Communicator for SingleProcess {
    fn rank(&self) -> usize {
        0
    }
    fn size(&self) -> usize {
        1
    }
    fn sum_f64(&self, _: &mut [f64]) {}
    fn sum_f32(&self, _: &mut [f32]) {}
    fn max_f64(&self, _: &mut [f64]) {}
    fn broadcast_bytes(&self, _: usize, _: &mut Vec<u8>) {}
}

/// A shared handle to a [`Communicator`], with the helpers the integrators use on top of it. The
/// default is [`SingleProcess`].
///
/// ```
/// use nis::comm::Comm;
/// let comm = Comm::default();
/// assert_eq!((comm.rank(), comm.size()), (0, 1));
/// assert_eq!(comm.share(10), 10); // one process draws the whole batch
/// let mut v = [1.0, 2.0];
/// comm.sum_f64(&mut v);
/// assert_eq!(v, [1.0, 2.0]);
/// ```
#[derive(Clone)]
pub struct Comm(Arc<dyn Communicator>);

impl Default for Comm {
    fn default() -> Comm {
        Comm(Arc::new(SingleProcess))
    }
}

impl std::fmt::Debug for Comm {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Comm {{ rank: {}, size: {} }}", self.rank(), self.size())
    }
}

/// Mixes a rank into a seed (SplitMix64's increment and finaliser, Steele et al. 2014), so that
/// every rank's streams are distinct and fixed by (seed, rank).
fn mix_rank(seed: u64, rank: usize) -> u64 {
    let mut z = seed.wrapping_add((rank as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15));
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

impl Comm {
    /// A handle to `communicator`.
    pub fn new(communicator: impl Communicator + 'static) -> Comm {
        Comm(Arc::new(communicator))
    }

    /// This process's rank.
    pub fn rank(&self) -> usize {
        self.0.rank()
    }

    /// Processes in the group.
    pub fn size(&self) -> usize {
        self.0.size()
    }

    /// Whether this is rank 0, the one that prints and writes files.
    pub fn is_root(&self) -> bool {
        self.rank() == 0
    }

    /// See [`Communicator::sum_f64`].
    pub fn sum_f64(&self, values: &mut [f64]) {
        if self.size() > 1 {
            self.0.sum_f64(values);
        }
    }

    /// See [`Communicator::sum_f32`].
    pub fn sum_f32(&self, values: &mut [f32]) {
        if self.size() > 1 {
            self.0.sum_f32(values);
        }
    }

    /// See [`Communicator::max_f64`].
    pub fn max_f64(&self, values: &mut [f64]) {
        if self.size() > 1 {
            self.0.max_f64(values);
        }
    }

    /// The sum of one number over the ranks.
    pub fn sum(&self, value: f64) -> f64 {
        let mut v = [value];
        self.sum_f64(&mut v);
        v[0]
    }

    /// The largest of one number over the ranks (e.g. the slowest rank's seconds, on which every
    /// rank then decides alike).
    pub fn max(&self, value: f64) -> f64 {
        let mut v = [value];
        self.max_f64(&mut v);
        v[0]
    }

    /// Whether `flag` holds on any rank.
    pub fn any(&self, flag: bool) -> bool {
        let mut v = [if flag { 1.0 } else { 0.0 }];
        self.max_f64(&mut v);
        v[0] > 0.0
    }

    /// This rank's share of `total` items split as evenly as the ranks allow (the first ranks
    /// get one fewer): Σ over the ranks is `total`, and with one process it is `total`.
    pub fn share(&self, total: u64) -> u64 {
        let (r, p) = (self.rank() as u128, self.size() as u128);
        let t = total as u128;
        (t * (r + 1) / p - t * r / p) as u64
    }

    /// The seed of this rank's random stream for `seed`: `seed` itself on rank 0 (so one process
    /// draws what it always drew), a distinct mix of both elsewhere.
    pub fn stream_seed(&self, seed: u64) -> u64 {
        match self.rank() {
            0 => seed,
            r => mix_rank(seed, r),
        }
    }

    /// The failure flag of one batch, reduced over the ranks: `Ok` on every rank when every rank
    /// is `Ok`; otherwise an error on every rank — its own on a rank that failed, and
    /// [`Error::Rank`] with the message of the lowest failing rank on the others — so that all
    /// ranks stop together and rank 0 can print why.
    pub fn check<T>(&self, result: Result<T>) -> Result<T> {
        if self.size() == 1 {
            return result;
        }
        let mut lowest = [match &result {
            Ok(_) => f64::NEG_INFINITY,
            Err(_) => -(self.rank() as f64),
        }];
        self.0.max_f64(&mut lowest);
        if lowest[0] == f64::NEG_INFINITY {
            return result;
        }
        let root = (-lowest[0]) as usize;
        let mut message = match &result {
            Err(e) if self.rank() == root => e.to_string().into_bytes(),
            _ => Vec::new(),
        };
        self.0.broadcast_bytes(root, &mut message);
        match result {
            Err(e) => Err(e),
            Ok(_) => Err(Error::Rank {
                rank: root,
                message: String::from_utf8_lossy(&message).into_owned(),
            }),
        }
    }

    /// Every rank's `bytes`, in rank order, on every rank.
    pub fn all_gather_bytes(&self, bytes: Vec<u8>) -> Vec<Vec<u8>> {
        if self.size() == 1 {
            return vec![bytes];
        }
        (0..self.size())
            .map(|root| {
                let mut b = if root == self.rank() {
                    bytes.clone()
                } else {
                    Vec::new()
                };
                self.0.broadcast_bytes(root, &mut b);
                b
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A communicator of `size` ranks seen from `rank` that never communicates: enough to check
    /// the arithmetic of shares and seeds.
    struct Seen {
        rank: usize,
        size: usize,
    }

    impl Communicator for Seen {
        fn rank(&self) -> usize {
            self.rank
        }
        fn size(&self) -> usize {
            self.size
        }
        fn sum_f64(&self, _: &mut [f64]) {}
        fn sum_f32(&self, _: &mut [f32]) {}
        fn max_f64(&self, _: &mut [f64]) {}
        fn broadcast_bytes(&self, _: usize, _: &mut Vec<u8>) {}
    }

    #[test]
    fn shares_cover_the_total_and_differ_by_at_most_one() {
        for size in 1..=7 {
            for total in [0u64, 1, 2, 5, 1000, 1001, u64::MAX / 3] {
                let shares: Vec<u64> = (0..size)
                    .map(|rank| Comm::new(Seen { rank, size }).share(total))
                    .collect();
                assert_eq!(
                    shares.iter().map(|&s| s as u128).sum::<u128>(),
                    total as u128
                );
                let (lo, hi) = (shares.iter().min().unwrap(), shares.iter().max().unwrap());
                assert!(hi - lo <= 1, "{shares:?}");
            }
        }
    }

    #[test]
    fn stream_seeds_are_the_seed_on_rank_zero_and_distinct_elsewhere() {
        let seeds: Vec<u64> = (0..64)
            .map(|rank| Comm::new(Seen { rank, size: 64 }).stream_seed(7))
            .collect();
        assert_eq!(seeds[0], 7);
        let mut sorted = seeds.clone();
        sorted.sort_unstable();
        sorted.dedup();
        assert_eq!(sorted.len(), 64);
    }

    #[test]
    fn one_process_passes_results_through() {
        let comm = Comm::default();
        assert!(matches!(
            comm.check::<()>(Err(Error::Config("x".into()))),
            Err(Error::Config(_))
        ));
        assert_eq!(comm.check(Ok(3)).unwrap(), 3);
        assert!(comm.any(true) && !comm.any(false));
        assert_eq!(comm.all_gather_bytes(vec![1, 2]), vec![vec![1, 2]]);
    }
}
