//! The neural guide's training records: what it keeps of a path's [`GuideRecord`]
//! ([`Sample`]), a training pass's records ([`PassSamples`], the guide's
//! [`Guide::Statistics`]) and their wire format between processes.

use std::collections::VecDeque;

use super::CONTEXT_SCALARS;
use crate::guiding::GuideStatistics;
#[cfg(doc)]
use crate::guiding::{Guide, GuideRecord};
use serde::{Deserialize, Serialize};

/// What the neural guide keeps of a training record. A training pass's
/// [`Guide::Statistics`] are its samples, in the order they were made.
#[derive(Clone, Copy, Debug, Serialize, Deserialize)]
pub struct Sample {
    /// The vertex's context scalars (position, outgoing direction, normal).
    pub(super) context: [f32; CONTEXT_SCALARS],
    /// The direction in cylindrical coordinates.
    pub(super) x: [f32; 2],
    /// `F`: luminance of incident radiance × BSDF × cosine.
    pub(super) f: f32,
    /// Mixture density the direction was drawn with.
    pub(super) pdf: f32,
    /// The BSDF's density of the direction.
    pub(super) bsdf_pdf: f32,
    /// Solid-angle density per unit density on the square of the vertex's map.
    pub(super) jacobian: f32,
}

impl Sample {
    /// F/p_s: the record's weight in the KL gradient (in f64, where it cannot overflow).
    pub(super) fn kl_weight(&self) -> f64 {
        f64::from(self.f) / f64::from(self.pdf)
    }
}

/// The records of a training pass, in the order they were made, of which only the newest `cap`
/// are kept: the replay buffer would keep no more of them (see `NisGuide::train`), so a pass of
/// any number of paths holds at most a buffer's worth of records. `seen` counts them all (it
/// sets the number of steps), so training is the same as with every record kept.
#[derive(Debug, Default, Serialize, Deserialize)]
pub struct PassSamples {
    pub(super) samples: VecDeque<Sample>,
    pub(super) seen: usize,
    /// The replay buffer's size; `None` until the guide has accumulated into these statistics.
    pub(super) cap: Option<usize>,
}

impl PassSamples {
    pub(super) fn trim(&mut self) {
        if let Some(cap) = self.cap {
            let excess = self.samples.len().saturating_sub(cap);
            self.samples.drain(..excess);
        }
    }
}

impl GuideStatistics for PassSamples {
    fn merge(&mut self, later: Self) {
        self.cap = match (self.cap, later.cap) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        };
        self.seen += later.seen;
        self.samples.extend(later.samples);
        self.trim();
    }
}
