//! Saving a multi-channel NIS integrator: a directory with every part's flow (`part-<i>.nis`, as
//! [`NisIntegrator::save`] writes one) and, written last, `channels.json`: the format, the
//! dimension, the channels' count and weights, each part's channel and sign, the settings and the
//! weight network when one was kept.
//! The maps themselves are the user's code: loading takes them again and checks that their count
//! and dimension match.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::{MultiChannel, MultiChannelConfig, Part, Sign, WeightNet};
use crate::channels::ChannelSet;
use crate::comm::Comm;
use crate::error::{Error, Result};
use crate::integrate::nis::NisIntegrator;
use crate::integrate::{Integrator, Method, Settings};

/// The manifest's format tag.
const FORMAT: &str = "nis multi-channel 1";
/// The manifest's file name.
const MANIFEST: &str = "channels.json";

#[derive(Serialize, Deserialize)]
struct Manifest {
    format: String,
    dim: usize,
    channels: usize,
    /// The weights' bit patterns (`f64::to_bits`): JSON's decimal floats may not read back to
    /// the same bits.
    weight_bits: Vec<u64>,
    parts: Vec<(usize, Sign)>,
    config: MultiChannelConfig,
    settings: Settings,
    /// The weight network, when one was kept.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    weight_net: Option<WeightNet>,
}

fn part_path(dir: &Path, i: usize) -> PathBuf {
    dir.join(format!("part-{i}.nis"))
}

impl MultiChannel {
    /// [`Integrator::save`]: the parts' flows and the weights into the directory `dir`.
    pub(super) fn save_parts(&self, dir: &Path) -> Result<()> {
        if self.method != Method::Nis {
            return Err(Error::Config(format!(
                "{} keeps no trained state to save",
                self.method.name()
            )));
        }
        if self.parts.is_empty() {
            return Err(Error::Config(
                "nothing to save yet: integrate once to make and train the parts".into(),
            ));
        }
        std::fs::create_dir_all(dir).map_err(|source| Error::Io {
            path: dir.to_path_buf(),
            source,
        })?;
        for (i, p) in self.parts.iter().enumerate() {
            p.integrator
                .as_ref()
                .ok_or_else(super::no_sampler)?
                .save(&part_path(dir, i))?;
        }
        let manifest = Manifest {
            format: FORMAT.into(),
            dim: self.set.dim(),
            channels: self.set.len(),
            weight_bits: self.weights.iter().map(|w| w.to_bits()).collect(),
            parts: self.parts_index(),
            config: self.config.clone(),
            settings: self.settings.clone(),
            weight_net: self.net.clone(),
        };
        let json = serde_json::to_vec_pretty(&manifest).expect("serialisable");
        crate::io::write_atomic(&dir.join(MANIFEST), &json)
    }

    /// Loads what [`Integrator::save`] wrote into `dir`, for the channels `set` (the same maps,
    /// in the same order): an error naming the file when it is not a saved multi-channel
    /// integrator or its channels' count or dimension differ from `set`'s.
    pub fn load(dir: &Path, set: ChannelSet) -> Result<MultiChannel> {
        let path = dir.join(MANIFEST);
        let bad = |reason: String| Error::Model {
            path: path.clone(),
            reason,
        };
        let bytes = std::fs::read(&path).map_err(|source| Error::Io {
            path: path.clone(),
            source,
        })?;
        let m: Manifest = serde_json::from_slice(&bytes)
            .map_err(|e| bad(format!("not a multi-channel manifest: {e}")))?;
        if m.format != FORMAT {
            return Err(bad(format!("format {:?}, expected {FORMAT:?}", m.format)));
        }
        if m.channels != set.len() || m.dim != set.dim() {
            return Err(bad(format!(
                "saved for {} channels in {} dimensions, given {} channels in {}",
                m.channels,
                m.dim,
                set.len(),
                set.dim()
            )));
        }
        let weights: Vec<f64> = m.weight_bits.iter().map(|b| f64::from_bits(*b)).collect();
        if weights.len() != m.channels
            || !weights.iter().all(|w| w.is_finite() && *w > 0.0)
            || m.parts.iter().any(|(k, _)| *k >= m.channels)
        {
            return Err(bad("weights or parts do not fit the channels".into()));
        }
        m.config.validate()?;
        if let Some(net) = &m.weight_net {
            if !net.fits(m.dim, m.channels) {
                return Err(bad("the weight network does not fit the channels".into()));
            }
        }
        let mut parts = Vec::with_capacity(m.parts.len());
        for (i, &(channel, sign)) in m.parts.iter().enumerate() {
            let nis = NisIntegrator::load(&part_path(dir, i))?;
            if Integrator::dim(&nis) != m.dim {
                return Err(bad(format!("part {i} has another dimension")));
            }
            parts.push(Part {
                channel,
                sign,
                integrator: Some(Box::new(nis) as Box<dyn Integrator>),
            });
        }
        Ok(MultiChannel {
            set,
            method: Method::Nis,
            settings: m.settings,
            config: m.config,
            weights,
            shared: None,
            net: m.weight_net,
            parts,
            comm: Comm::default(),
            progress: None,
            event_draws: 0,
        })
    }
}
