//! The MPI implementation of [`Communicator`] (feature `mpi`, the `mpi` crate over the system's
//! MPI library): [`MpiComm::init`] starts MPI, and MPI finalises when the last [`Comm`] clone of
//! it is dropped.
//!
//! Sums go up a binomial tree of point-to-point messages in a fixed pairing (see [`super`]), then
//! down by a broadcast: 2·⌈log₂ P⌉ messages of the vector's size on the longest path, and a
//! result that depends on the rank count only. Maxima use MPI_Allreduce (a maximum is exact in any
//! order).

use std::sync::Mutex;

use mpi::collective::SystemOperation;
use mpi::datatype::Equivalence;
use mpi::environment::Universe;
use mpi::topology::SimpleCommunicator;
use mpi::traits::Communicator as _;
use mpi::traits::*;
use mpi::Threading;

use super::{Comm, Communicator};
use crate::error::{Error, Result};

/// MPI's world communicator and the environment that keeps MPI initialised.
pub struct MpiComm {
    rank: usize,
    size: usize,
    state: Mutex<State>,
}

/// The MPI handles. They are plain handles into the process-wide MPI library; MPI was
/// initialised with `MPI_THREAD_SERIALIZED`, which allows calls from any thread as long as no
/// two overlap, and the `Mutex` around `State` guarantees that. Hence `Send`.
struct State {
    world: SimpleCommunicator,
    // Dropped last: finalises MPI.
    _universe: Universe,
}

// SAFETY: see `State`: every use is serialised by the mutex, as MPI_THREAD_SERIALIZED requires.
unsafe impl Send for State {}

impl MpiComm {
    /// Initialises MPI and returns the world communicator. An error when MPI was initialised
    /// already or the library does not provide serialised threading.
    pub fn init() -> Result<Comm> {
        let (universe, threading) = mpi::initialize_with_threading(Threading::Serialized)
            .ok_or_else(|| Error::Config("MPI is initialised already".into()))?;
        if threading < Threading::Serialized {
            return Err(Error::Config(format!(
                "the MPI library provides threading level {threading:?}, nis needs Serialized"
            )));
        }
        let world = universe.world();
        Ok(Comm::new(MpiComm {
            rank: world.rank() as usize,
            size: world.size() as usize,
            state: Mutex::new(State {
                world,
                _universe: universe,
            }),
        }))
    }

    fn with<T>(&self, f: impl FnOnce(&SimpleCommunicator) -> T) -> T {
        let state = self.state.lock().unwrap_or_else(|e| e.into_inner());
        f(&state.world)
    }

    /// The tree sum of [`super`]'s documentation, then a broadcast from rank 0.
    fn tree_sum<T>(&self, values: &mut [T])
    where
        T: Equivalence + Copy + Default + std::ops::AddAssign,
    {
        let (rank, size) = (self.rank, self.size);
        self.with(|world| {
            let mut received = vec![T::default(); values.len()];
            let mut step = 1;
            while step < size {
                if rank % (2 * step) == step {
                    world.process_at_rank((rank - step) as i32).send(&*values);
                    break;
                }
                if rank + step < size {
                    world
                        .process_at_rank((rank + step) as i32)
                        .receive_into(&mut received[..]);
                    for (v, r) in values.iter_mut().zip(&received) {
                        *v += *r;
                    }
                }
                step *= 2;
            }
            world.process_at_rank(0).broadcast_into(values);
        });
    }
}

impl Communicator for MpiComm {
    fn rank(&self) -> usize {
        self.rank
    }

    fn size(&self) -> usize {
        self.size
    }

    fn sum_f64(&self, values: &mut [f64]) {
        self.tree_sum(values);
    }

    fn sum_f32(&self, values: &mut [f32]) {
        self.tree_sum(values);
    }

    fn max_f64(&self, values: &mut [f64]) {
        self.with(|world| {
            let local = values.to_vec();
            world.all_reduce_into(&local[..], values, SystemOperation::max());
        });
    }

    fn broadcast_bytes(&self, root: usize, bytes: &mut Vec<u8>) {
        self.with(|world| {
            let root = world.process_at_rank(root as i32);
            let mut len = bytes.len() as u64;
            root.broadcast_into(&mut len);
            bytes.resize(len as usize, 0);
            // Every rank knows the length now; Open MPI rejects a broadcast of an empty buffer.
            if len > 0 {
                root.broadcast_into(&mut bytes[..]);
            }
        });
    }
}
