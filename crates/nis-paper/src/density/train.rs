//! Training a density model on images by maximum likelihood, with validation in bits/dim,
//! atomic checkpoints and resume.
//!
//! Every epoch visits the training images in an order drawn from (seed, epoch), dequantising them
//! with fresh noise from the same stream, so a resumed run takes exactly the steps the
//! uninterrupted one would have taken. A run stopped inside an epoch (by its time budget) records
//! how many of the epoch's batches it took; its resumption replays the epoch's stream up to
//! there (the noise of the skipped batches is drawn and dropped) and goes on with the next one. A step is the shared [`descend`] with weights 1/n: the
//! gradient of the mean negative log-likelihood, then [`Adam`]. Evaluation uses fixed noise, so
//! successive numbers differ only through the model.

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use rand::seq::SliceRandom;
use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;
use safetensors::tensor::{Dtype, SafeTensors, TensorView};
use serde::{Deserialize, Serialize};

use super::model::ModelConfig;
use super::{bits_per_dim, dequantize};
use crate::data::{Dataset, Images};
use crate::error::{Error, Result};
use nis::flow::Bijection;
use nis::io::{fnv1a, write_atomic, FNV_OFFSET};
use nis::nn::{Adam, AdamConfig};
use nis::train::descend;

const FORMAT: &str = "nis-density/1";
/// Each epoch's stream is seeded from (seed, epoch) through this odd multiplier (2⁶⁴/φ, Knuth's
/// multiplicative hash), so neighbouring seeds do not give overlapping epoch streams.
const EPOCH_SEED_MULTIPLIER: u64 = 0x9e37_79b9_7f4a_7c15;
/// The fixed seed of the evaluation's dequantisation noise: every evaluation sees the same noise,
/// so successive numbers differ only through the model.
const EVALUATION_SEED: u64 = 0x5eed_e7a1;
/// File names inside a training directory: the checkpoint and the per-epoch history (JSON).
pub const CHECKPOINT: &str = "checkpoint.safetensors";
pub const HISTORY: &str = "history.json";
/// Rows per evaluation pass (the model cuts them into parallel chunks itself).
const EVAL_ROWS: usize = 4096;
/// Training bits/dim are measured on at most this many training images (a fixed subset).
pub const TRAIN_EVAL_IMAGES: usize = 2000;

/// A training run's settings (stored in checkpoints).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DensityConfig {
    pub dataset: Dataset,
    pub model: ModelConfig,
    /// Images per step.
    pub batch: usize,
    pub learning_rate: f32,
    /// Clip the gradient's Euclidean norm to this (none when `None`).
    pub clip_norm: Option<f32>,
    /// Seed of batch order and dequantisation noise.
    pub seed: u64,
}

/// Where a run stands after an epoch.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EpochStats {
    /// Completed epochs (fractional when a time budget stopped one early).
    pub epochs: f64,
    /// Adam steps so far.
    pub steps: u64,
    /// Training seconds so far (evaluation excluded).
    pub seconds: f64,
    /// Bits/dim on (up to [`TRAIN_EVAL_IMAGES`]) training images and on the validation images.
    pub train_bpd: f64,
    pub valid_bpd: f64,
}

/// What [`Session::run`] reports as it goes.
pub enum Progress<'a> {
    /// After a step: step within the epoch, steps per epoch, bits/dim of this batch.
    Step {
        epoch: usize,
        step: usize,
        steps_per_epoch: usize,
        batch_bpd: f64,
    },
    /// After an epoch's evaluation.
    Epoch(&'a EpochStats),
}

/// A model with its optimiser and the state of its training run.
pub struct Session {
    config: DensityConfig,
    model: Box<dyn Bijection>,
    adam: Adam,
    /// Completed epochs.
    epoch: usize,
    /// Batches of the current epoch already taken (non-zero after a time budget stopped it).
    epoch_step: usize,
    /// Training seconds so far.
    seconds: f64,
    history: Vec<EpochStats>,
}

/// The resumable state stored beside the tensors.
#[derive(Serialize, Deserialize)]
struct State {
    epoch: usize,
    /// Absent from checkpoints written before runs could resume inside an epoch.
    #[serde(default)]
    epoch_step: usize,
    adam_steps: u64,
    seconds: f64,
    history: Vec<EpochStats>,
}

impl Session {
    /// A fresh run: an untrained model (q ≡ 1) and a new optimiser.
    pub fn new(config: DensityConfig) -> Result<Session> {
        if config.batch == 0 {
            return Err(Error::Config(
                "the batch must hold at least one image".into(),
            ));
        }
        let model = config.model.build()?;
        let adam = Adam::new(adam_config(&config), model.param_count())?;
        Ok(Session {
            config,
            model,
            adam,
            epoch: 0,
            epoch_step: 0,
            seconds: 0.0,
            history: Vec::new(),
        })
    }

    pub fn config(&self) -> &DensityConfig {
        &self.config
    }

    /// The model being trained.
    pub fn model(&self) -> &dyn Bijection {
        &*self.model
    }

    /// Completed epochs.
    pub fn epoch(&self) -> usize {
        self.epoch
    }

    /// Training seconds so far.
    pub fn seconds(&self) -> f64 {
        self.seconds
    }

    /// Adam steps so far.
    pub fn steps(&self) -> u64 {
        self.adam.steps()
    }

    /// The statistics recorded after each epoch.
    pub fn history(&self) -> &[EpochStats] {
        &self.history
    }

    /// Bits/dim of the model on `images`, with fixed dequantisation noise.
    pub fn evaluate(&self, images: &Images) -> Result<f64> {
        evaluate(&*self.model, images)
    }

    /// One epoch over `train` (the rest of it, when an earlier call stopped inside it); stops
    /// early once the training time reaches `max_seconds`. Returns the fraction of the epoch
    /// done (1 unless stopped).
    pub fn train_epoch(
        &mut self,
        train: &Images,
        max_seconds: Option<f64>,
        on_step: &mut dyn FnMut(usize, usize, f64),
    ) -> Result<f64> {
        self.check_images(train)?;
        let n = train.len();
        let mut rng = Pcg64Mcg::seed_from_u64(
            self.config
                .seed
                .wrapping_mul(EPOCH_SEED_MULTIPLIER)
                .wrapping_add(self.epoch as u64),
        );
        let mut order: Vec<usize> = (0..n).collect();
        order.shuffle(&mut rng);
        let batches: Vec<&[usize]> = order.chunks(self.config.batch).collect();
        let (dim, levels) = (train.dim(), train.levels);
        for idx in &batches[..self.epoch_step.min(batches.len())] {
            // Batches taken before a stop: advance the stream past their noise.
            dequantize(train, idx, &mut rng);
        }
        for (b, idx) in batches.iter().enumerate().skip(self.epoch_step) {
            if max_seconds.is_some_and(|m| self.seconds >= m) {
                self.epoch_step = b;
                return Ok(b as f64 / batches.len() as f64);
            }
            let start = Instant::now();
            let x = dequantize(train, idx, &mut rng);
            let e = self.model.log_density_for_training(&x, None)?;
            let mean_nll = mean_nll(&e.log_q)?;
            let w = vec![1.0 / idx.len() as f32; idx.len()];
            descend(&mut *self.model, &mut self.adam, &e.tape, &w)?;
            self.seconds += start.elapsed().as_secs_f64();
            on_step(b + 1, batches.len(), bits_per_dim(mean_nll, dim, levels));
        }
        self.epoch += 1;
        self.epoch_step = 0;
        Ok(1.0)
    }

    /// Trains until `epochs` epochs are complete or the training time reaches `max_seconds`;
    /// after every epoch evaluates, records and (when `checkpoint` is given) saves.
    pub fn run(
        &mut self,
        train: &Images,
        valid: &Images,
        epochs: usize,
        max_seconds: Option<f64>,
        checkpoint: Option<&Path>,
        on: &mut dyn FnMut(Progress),
    ) -> Result<()> {
        let train_eval = train.select(&(0..train.len().min(TRAIN_EVAL_IMAGES)).collect::<Vec<_>>());
        while self.epoch < epochs && max_seconds.is_none_or(|m| self.seconds < m) {
            let epoch = self.epoch;
            let done = self.train_epoch(train, max_seconds, &mut |step, steps, bpd| {
                on(Progress::Step {
                    epoch,
                    step,
                    steps_per_epoch: steps,
                    batch_bpd: bpd,
                })
            })?;
            let stats = EpochStats {
                epochs: epoch as f64 + done,
                steps: self.steps(),
                seconds: self.seconds,
                train_bpd: self.evaluate(&train_eval)?,
                valid_bpd: self.evaluate(valid)?,
            };
            self.history.push(stats.clone());
            if let Some(path) = checkpoint {
                self.save(path)?;
            }
            on(Progress::Epoch(&stats));
        }
        Ok(())
    }

    fn check_images(&self, images: &Images) -> Result<()> {
        let m = &self.config.model;
        if images.width != m.width || images.height != m.height {
            return Err(Error::Config(format!(
                "the model is for {}×{} images, the data are {}×{}",
                m.width, m.height, images.width, images.height
            )));
        }
        if images.is_empty() {
            return Err(Error::Config("no training images".into()));
        }
        Ok(())
    }

    /// Writes the per-epoch statistics as JSON, atomically.
    pub fn write_history(&self, path: &Path) -> Result<()> {
        let json = serde_json::to_string_pretty(&self.history).expect("statistics serialise");
        Ok(write_atomic(path, json.as_bytes())?)
    }

    /// Writes the checkpoint (weights, Adam moments, epoch, history) atomically.
    pub fn save(&self, path: &Path) -> Result<()> {
        let (m, v) = self.adam.moments();
        let tensors: [(&str, &[f32]); 3] = [
            ("params", self.model.params()),
            ("adam.m", m),
            ("adam.v", v),
        ];
        let bytes: Vec<Vec<u8>> = tensors
            .iter()
            .map(|(_, t)| t.iter().flat_map(|p| p.to_le_bytes()).collect())
            .collect();
        let mut checksum = FNV_OFFSET;
        let mut views = Vec::new();
        for ((name, t), b) in tensors.iter().zip(&bytes) {
            checksum = fnv1a(checksum, b);
            let view = TensorView::new(Dtype::F32, vec![t.len()], b)
                .map_err(|e| Error::Config(format!("cannot describe tensor {name}: {e}")))?;
            views.push((name.to_string(), view));
        }
        let state = State {
            epoch: self.epoch,
            epoch_step: self.epoch_step,
            adam_steps: self.adam.steps(),
            seconds: self.seconds,
            history: self.history.clone(),
        };
        let mut meta = HashMap::new();
        meta.insert("format".to_string(), FORMAT.to_string());
        meta.insert(
            "config".into(),
            serde_json::to_string(&self.config).expect("serialises"),
        );
        meta.insert(
            "state".into(),
            serde_json::to_string(&state).expect("serialises"),
        );
        meta.insert("checksum".into(), format!("{checksum:016x}"));
        let file = safetensors::serialize(views, Some(meta))
            .map_err(|e| Error::Config(format!("cannot serialise the checkpoint: {e}")))?;
        Ok(write_atomic(path, &file)?)
    }

    /// Reads a checkpoint written by [`Session::save`].
    pub fn load(path: &Path) -> Result<Session> {
        let bytes = std::fs::read(path).map_err(|source| Error::Io {
            path: path.to_path_buf(),
            source,
        })?;
        from_bytes(&bytes).map_err(|reason| {
            Error::Nis(nis::Error::Model {
                path: PathBuf::from(path),
                reason,
            })
        })
    }
}

fn adam_config(config: &DensityConfig) -> AdamConfig {
    AdamConfig {
        learning_rate: config.learning_rate,
        clip_norm: config.clip_norm,
        ..AdamConfig::default()
    }
}

fn mean_nll(log_q: &[f64]) -> Result<f64> {
    if let Some(i) = log_q.iter().position(|l| !l.is_finite()) {
        return Err(Error::Nis(nis::Error::NonFinite {
            what: "log-density",
            index: i,
            value: log_q[i],
        }));
    }
    Ok(-log_q.iter().sum::<f64>() / log_q.len().max(1) as f64)
}

/// Bits/dim of `model` on `images` with dequantisation noise from a fixed seed.
pub fn evaluate(model: &dyn Bijection, images: &Images) -> Result<f64> {
    let mut rng = Pcg64Mcg::seed_from_u64(EVALUATION_SEED);
    let idx: Vec<usize> = (0..images.len()).collect();
    let mut sum = 0.0;
    for chunk in idx.chunks(EVAL_ROWS) {
        let x = dequantize(images, chunk, &mut rng);
        sum += mean_nll(&model.log_density(&x, None)?)? * chunk.len() as f64;
    }
    Ok(bits_per_dim(
        sum / images.len().max(1) as f64,
        images.dim(),
        images.levels,
    ))
}

fn from_bytes(bytes: &[u8]) -> std::result::Result<Session, String> {
    let meta = nis::io::read_metadata(bytes, FORMAT, "a nis checkpoint")?;
    let config: DensityConfig = serde_json::from_str(meta.get("config").ok_or("no config")?)
        .map_err(|e| format!("config is not valid: {e}"))?;
    let state: State = serde_json::from_str(meta.get("state").ok_or("no state")?)
        .map_err(|e| format!("state is not valid: {e}"))?;
    // The weights and both Adam moments must be in the file: check the claim before allocating.
    let n = config.model.param_count().map_err(|e| e.to_string())?;
    if n.checked_mul(3 * 4).is_none_or(|b| b > bytes.len()) {
        return Err(format!(
            "the config needs 3 × {n} f32 values, the file has {} bytes in all",
            bytes.len()
        ));
    }
    let mut session = Session::new(config).map_err(|e| e.to_string())?;
    let tensors =
        SafeTensors::deserialize(bytes).map_err(|e| format!("truncated or corrupt ({e})"))?;
    let n = session.model.param_count();
    let mut checksum = FNV_OFFSET;
    let mut read = |name: &str| -> std::result::Result<Vec<f32>, String> {
        let t = tensors
            .tensor(name)
            .map_err(|_| format!("tensor {name} is missing"))?;
        if t.dtype() != Dtype::F32 || t.shape() != [n] {
            return Err(format!(
                "tensor {name} is {:?} {:?}, the config needs F32 [{n}]",
                t.dtype(),
                t.shape()
            ));
        }
        checksum = fnv1a(checksum, t.data());
        Ok(t.data()
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect())
    };
    let (params, m, v) = (read("params")?, read("adam.m")?, read("adam.v")?);
    if meta.get("checksum") != Some(&format!("{checksum:016x}")) {
        return Err("checksum mismatch: the checkpoint is corrupted".into());
    }
    if params.iter().chain(&m).chain(&v).any(|p| !p.is_finite()) {
        return Err("non-finite weights".into());
    }
    session.model.params_mut().copy_from_slice(&params);
    session.adam = Adam::from_state(adam_config(&session.config), m, v, state.adam_steps)
        .map_err(|e| e.to_string())?;
    session.epoch = state.epoch;
    session.epoch_step = state.epoch_step;
    session.seconds = state.seconds;
    session.history = state.history;
    Ok(session)
}

impl DensityConfig {
    /// The settings `nis density train` and `nis bench density` start from: the same conditioner
    /// for every coupling transform, sized to train in minutes on two cores.
    ///
    /// - MLP, digits (D = 64): 12 couplings (all binary masks), conditioners one-blob 8 → 2×64,
    ///   batch 64. MNIST (D = 784): 8 couplings, one-blob 4 → 2×64, batch 128.
    /// - Multi-scale: 2 scales (16 couplings), conditioners of 32 (digits) or 16 (MNIST) channels
    ///   with 2 or 1 residual blocks, batch 64.
    pub fn defaults(
        dataset: Dataset,
        arch: super::Arch,
        transform: nis::transform::TransformKind,
    ) -> DensityConfig {
        let (side, couplings, blob_bins, mut batch) = match dataset {
            Dataset::Digits => (8, 0, 8, 64),
            Dataset::Mnist => (28, 8, 4, 128),
        };
        let (features, blocks) = match dataset {
            Dataset::Digits => (32, 2),
            Dataset::Mnist => (16, 1),
        };
        if arch == super::Arch::MultiScale {
            batch = 64;
        }
        DensityConfig {
            dataset,
            model: ModelConfig {
                arch,
                width: side,
                height: side,
                transform,
                couplings,
                hidden_layers: 2,
                hidden_width: 64,
                blob_bins,
                scales: 2,
                features,
                blocks,
                seed: 0,
            },
            batch,
            learning_rate: 1e-3,
            clip_norm: Some(100.0),
            seed: 0,
        }
    }
}
