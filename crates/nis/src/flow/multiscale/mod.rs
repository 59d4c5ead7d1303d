//! The multi-scale architecture of RealNVP (Dinh, Sohl-Dickstein, Bengio 2016, Sec. 3.6), on
//! [0, 1]^D with spline couplings and no batch normalisation, as the paper uses it for CelebA
//! (Müller et al. 2019, Sec. 5.1).
//!
//! At each scale: three couplings with checkerboard masks (alternating parity), a squeeze (every
//! 2×2×c block becomes a 1×1×4c pixel), three couplings with channel masks (alternating halves),
//! and half of the channels are factored out: they leave the flow — their latent is the current
//! value, uniform under the model, so they add nothing to ln q beyond the layers they passed. The
//! last scale (or the first whose sides are odd) has four checkerboard couplings. 8×8 digits:
//! 8×8×1 → 4×4×2 → 2×2×4; MNIST: 28×28×1 → 14×14×2 → 7×7×4.
//!
//! No data move: every coupling knows, for each entry (y, x, channel) of the tensor it acts on,
//! the entry's position in the flat image (`idx`), so squeezing and factoring out are index maps.
//! A coupling's conditioner is a small residual network of 3×3 convolutions
//! ([`crate::kernels::conv`]) on the unchanged half (checkerboard: the image with the changed half
//! zeroed plus the mask as a channel; channel masks: the unchanged channels), whose output gives
//! every changed scalar its spline parameters (zero-initialised last layer: a new flow is the
//! identity). Chunks of [`IMAGES_PER_CHUNK`] images run in parallel; gradients are summed in chunk
//! order, so results do not depend on the thread count.

use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::composed::{ChunkTape, Composed, Direction, Layer, LayerTape, Rows};
use crate::error::{Error, Result};
use crate::kernels;
use crate::transform::{with_transform, Transform, TransformKind};

pub use crate::nn::conv_net::{ConvNet, NetTape};

/// Images per parallel work item. Fixed, so results do not depend on the number of threads.
pub const IMAGES_PER_CHUNK: usize = 8;

/// Which half of a tensor a coupling leaves alone (A) and which it transforms (B).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mask {
    /// A: pixels with (y + x) mod 2 = parity, all channels.
    Checkerboard { parity: usize },
    /// A: the first half of the channels (or the second), at every pixel.
    Channel { a_first: bool },
}

/// One coupling of the multi-scale flow: the tensor it sees (h × w × c entries at flat positions
/// `idx`, in (y, x, channel) order), its mask and its conditioner.
#[derive(Clone, Debug)]
pub struct MsCoupling {
    pub h: usize,
    pub w: usize,
    pub c: usize,
    pub idx: Vec<usize>,
    pub mask: Mask,
    pub net: ConvNet,
    /// The 1-D transform of each changed entry.
    pub transform: TransformKind,
}

/// The gradients one chunk's reverse pass through a coupling reads and writes.
struct ChunkGrad<'a> {
    /// ∂L/∂output on entry, ∂L/∂input on exit.
    g_u: &'a mut [f32],
    /// ∂L/∂ln|det| of each row.
    g_log_det: &'a [f32],
    /// The coupling's slice of the parameter gradient.
    params: &'a mut [f32],
}

impl MsCoupling {
    /// Whether entry (pixel p = y·w + x, channel ch) is in the unchanged half A.
    fn in_a(&self, p: usize, ch: usize) -> bool {
        match self.mask {
            Mask::Checkerboard { parity } => (p / self.w + p % self.w) % 2 == parity,
            Mask::Channel { a_first } => (ch < self.c / 2) == a_first,
        }
    }

    /// Position of B entry (p, ch)'s parameters in its pixel's conditioner output.
    fn param_slot(&self, ch: usize) -> usize {
        match self.mask {
            Mask::Checkerboard { .. } => ch,
            Mask::Channel { .. } => ch % (self.c / 2),
        }
    }

    /// Conditioner input channel of A entry (p, ch).
    fn input_slot(&self, ch: usize) -> usize {
        self.param_slot(ch)
    }

    /// The conditioner input of `n` rows of `u`: A entries as 2u − 1, B entries 0 (and, for
    /// checkerboards, the mask as a last channel).
    fn input(&self, u: &[f32], n: usize, dim: usize) -> Vec<f32> {
        let (hw, ci) = (self.h * self.w, self.net.c_in);
        let mut x = vec![0.0; n * hw * ci];
        for r in 0..n {
            for p in 0..hw {
                let row = &mut x[(r * hw + p) * ci..(r * hw + p + 1) * ci];
                for ch in 0..self.c {
                    if self.in_a(p, ch) {
                        row[self.input_slot(ch)] =
                            2.0 * u[r * dim + self.idx[p * self.c + ch]] - 1.0;
                    }
                }
                if let Mask::Checkerboard { .. } = self.mask {
                    row[self.c] = if self.in_a(p, 0) { 1.0 } else { 0.0 };
                }
            }
        }
        x
    }

    /// Reverse mode through this coupling for one chunk: `input` is the coupling's input (x side),
    /// `g_u` holds ∂L/∂output on entry and ∂L/∂input on exit (the A part only when
    /// `want_input`), `g_log_det[r]` is ∂L/∂ln|det| of row r; writes the conditioner's parameter
    /// gradient into `grads` (its slice).
    fn backward(
        &self,
        params: &[f32],
        layer: &LayerTape<NetTape>,
        dim: usize,
        grad: ChunkGrad<'_>,
        want_input: bool,
    ) {
        let (tape, input) = (&layer.record, &layer.input);
        let ChunkGrad {
            g_u,
            g_log_det,
            params: grads,
        } = grad;
        let n = g_log_det.len();
        let (hw, co) = (self.h * self.w, self.net.c_out);
        let np = self.transform.param_count();
        let mut g_out = vec![0.0f32; n * hw * co];
        with_transform!(self.transform, s => {
            for r in 0..n {
                for p in 0..hw {
                    let row = (r * hw + p) * co;
                    for ch in 0..self.c {
                        if self.in_a(p, ch) {
                            continue;
                        }
                        let at = row + self.param_slot(ch) * np;
                        let k = r * dim + self.idx[p * self.c + ch];
                        let g_x = s.backward(
                            &tape.out[at..at + np],
                            input[k] as f64,
                            g_u[k] as f64,
                            g_log_det[r] as f64,
                            &mut g_out[at..at + np],
                        );
                        g_u[k] = g_x as f32;
                    }
                }
            }
        });
        let net_params = &params[self.net.offset..self.net.offset + self.net.param_count()];
        let g_in = self.net.backward(
            net_params,
            tape,
            &g_out,
            grads,
            (n, self.h, self.w),
            want_input,
        );
        if let Some(g_in) = g_in {
            let ci = self.net.c_in;
            for r in 0..n {
                for p in 0..hw {
                    for ch in 0..self.c {
                        if self.in_a(p, ch) {
                            let k = r * dim + self.idx[p * self.c + ch];
                            g_u[k] += 2.0 * g_in[(r * hw + p) * ci + self.input_slot(ch)];
                        }
                    }
                }
            }
        }
    }
}

/// The tensor one coupling acts on: `h × w × c` entries at flat image positions `idx` (in
/// (y, x, channel) order), and which half of it the coupling leaves alone.
#[derive(Clone, Debug, PartialEq)]
struct Tensor {
    h: usize,
    w: usize,
    c: usize,
    idx: Vec<usize>,
    mask: Mask,
}

/// The tensors the couplings act on, in data-to-latent order.
fn architecture(width: usize, height: usize, scales: usize) -> Vec<Tensor> {
    let (mut h, mut w, mut c) = (height, width, 1);
    let mut idx: Vec<usize> = (0..h * w).collect();
    let mut layers = Vec::new();
    let mut s = 0;
    loop {
        let last = s == scales || h % 2 == 1 || w % 2 == 1;
        for i in 0..if last { 4 } else { 3 } {
            layers.push(Tensor {
                h,
                w,
                c,
                idx: idx.clone(),
                mask: Mask::Checkerboard { parity: i % 2 },
            });
        }
        if last {
            return layers;
        }
        let (h2, w2, c2) = (h / 2, w / 2, 4 * c);
        let mut sq = vec![0; h2 * w2 * c2];
        for y in 0..h2 {
            for x in 0..w2 {
                for ch in 0..c {
                    for dy in 0..2 {
                        for dx in 0..2 {
                            sq[(y * w2 + x) * c2 + ch * 4 + dy * 2 + dx] =
                                idx[((2 * y + dy) * w + 2 * x + dx) * c + ch];
                        }
                    }
                }
            }
        }
        for i in 0..3 {
            layers.push(Tensor {
                h: h2,
                w: w2,
                c: c2,
                idx: sq.clone(),
                mask: Mask::Channel {
                    a_first: i % 2 == 0,
                },
            });
        }
        let keep = c2 / 2;
        idx = (0..h2 * w2)
            .flat_map(|p| sq[p * c2..p * c2 + keep].to_vec())
            .collect();
        (h, w, c, s) = (h2, w2, keep, s + 1);
    }
}

/// The shape of a multi-scale flow, weights aside (serde: stored beside the weights).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MultiScaleConfig {
    /// Image width and height in pixels (D = width·height).
    pub width: usize,
    pub height: usize,
    /// The coupling transform.
    pub transform: TransformKind,
    /// Number of squeezes (each followed by factoring out half of the channels).
    pub scales: usize,
    /// Channels and residual blocks of every convolutional conditioner.
    pub features: usize,
    pub blocks: usize,
    /// Seed of the weight initialisation.
    pub seed: u64,
}

impl MultiScaleConfig {
    /// Rejects shapes that describe no valid flow, or one with more than
    /// [`crate::flow::config::MAX_PARAMS`] parameters (checked before anything is allocated).
    pub fn validate(&self) -> Result<()> {
        self.transform.validate()?;
        let (width, height, features, blocks) =
            (self.width, self.height, self.features, self.blocks);
        if width < 2
            || height < 2
            || width.checked_mul(height).is_none_or(|d| d > 1 << 16)
            || features == 0
            || features > 1024
            || blocks > 32
        {
            return Err(Error::Config(format!(
                "multi-scale flow: {width}×{height} images, {features} features, {blocks} blocks is no valid shape"
            )));
        }
        let n = self.param_count();
        if n > crate::flow::config::MAX_PARAMS {
            return Err(Error::Config(format!(
                "the multi-scale flow would have {n} parameters, more than the limit of {}",
                crate::flow::config::MAX_PARAMS
            )));
        }
        Ok(())
    }

    /// The number of parameters of the flow this shape builds, without building it. Meaningful
    /// once the bounds of [`MultiScaleConfig::validate`] on the image and the nets hold.
    pub fn param_count(&self) -> usize {
        architecture(self.width, self.height, self.scales)
            .into_iter()
            .map(|t| conditioner(t.c, t.mask, self, 0).param_count())
            .sum()
    }
}

/// The convolutional conditioner of a coupling on a tensor of `c` channels.
fn conditioner(c: usize, mask: Mask, config: &MultiScaleConfig, offset: usize) -> ConvNet {
    let np = config.transform.param_count();
    let (c_in, c_out) = match mask {
        Mask::Checkerboard { .. } => (c + 1, c * np),
        Mask::Channel { .. } => (c / 2, c / 2 * np),
    };
    ConvNet {
        c_in,
        features: config.features,
        blocks: config.blocks,
        c_out,
        offset,
    }
}

/// The multi-scale flow: a [`Composed`] stack of [`MsCoupling`] layers.
pub type MultiScale = Composed<MsCoupling>;

impl MultiScale {
    /// A new flow (the identity) for `width × height` images with `scales` squeezes, conditioners
    /// of `features` channels and `blocks` residual blocks, weights from `seed`.
    pub fn new(config: MultiScaleConfig) -> Result<MultiScale> {
        config.validate()?;
        let (width, height, transform, scales, seed) = (
            config.width,
            config.height,
            config.transform,
            config.scales,
            config.seed,
        );
        let mut offset = 0;
        let mut couplings = Vec::new();
        for Tensor { h, w, c, idx, mask } in architecture(width, height, scales) {
            let net = conditioner(c, mask, &config, offset);
            offset += net.param_count();
            couplings.push(MsCoupling {
                h,
                w,
                c,
                idx,
                mask,
                net,
                transform,
            });
        }
        let mut params = vec![0.0; offset];
        let mut rng = Pcg64Mcg::seed_from_u64(seed);
        for c in &couplings {
            c.net.init(
                &mut params[c.net.offset..c.net.offset + c.net.param_count()],
                &mut rng,
            );
        }
        Ok(Composed::from_parts(
            config,
            couplings,
            params,
            width * height,
            0,
        ))
    }
}

impl Layer for MsCoupling {
    type Record = NetTape;
    type Config = MultiScaleConfig;
    fn chunk_rows(_rows: usize) -> usize {
        IMAGES_PER_CHUNK
    }

    /// Runs the conditioner and transforms the B entries of `n` rows of `u` in place, adding
    /// each row's ln|det| to `log_det`.
    fn apply(&self, params: &[f32], rows: Rows<'_>, direction: Direction) -> NetTape {
        let Rows {
            u, dim, log_det, ..
        } = rows;
        let n = log_det.len();
        let net_params = &params[self.net.offset..self.net.offset + self.net.param_count()];
        let tape = self
            .net
            .forward(net_params, self.input(u, n, dim), n, self.h, self.w);
        let (hw, co) = (self.h * self.w, self.net.c_out);
        let np = self.transform.param_count();
        with_transform!(self.transform, s => {
            for r in 0..n {
                for p in 0..hw {
                    let out = &tape.out[(r * hw + p) * co..(r * hw + p + 1) * co];
                    for ch in 0..self.c {
                        if self.in_a(p, ch) {
                            continue;
                        }
                        let at = self.param_slot(ch) * np;
                        let k = r * dim + self.idx[p * self.c + ch];
                        let v = u[k] as f64;
                        let (v, ld) = match direction {
                            Direction::Forward => s.forward(&out[at..at + np], v),
                            Direction::Inverse => s.inverse(&out[at..at + np], v),
                        };
                        u[k] = v as f32;
                        log_det[r] += ld;
                    }
                }
            }
        });
        tape
    }

    /// Chunk by chunk: every chunk runs its whole reverse pass into its own gradient, and the
    /// chunks' gradients are summed in chunk order.
    fn backward_stack(
        stack: &MultiScale,
        chunks: &[ChunkTape<NetTape>],
        weights: &[f32],
        grads: &mut [f32],
    ) {
        let dim = stack.dim;
        let per_chunk: Vec<Vec<f32>> = chunks
            .par_iter()
            .enumerate()
            .map(|(c, layers)| {
                let r0 = c * IMAGES_PER_CHUNK;
                let n = layers[0].input.len() / dim;
                let g_ld: Vec<f32> = weights[r0..r0 + n].iter().map(|w| -w).collect();
                let mut g_u = vec![0.0f32; n * dim];
                let mut grads = vec![0.0f32; stack.params.len()];
                for (l, coupling) in stack.layers.iter().enumerate().rev() {
                    let range =
                        coupling.net.offset..coupling.net.offset + coupling.net.param_count();
                    let grad = ChunkGrad {
                        g_u: &mut g_u,
                        g_log_det: &g_ld,
                        params: &mut grads[range],
                    };
                    coupling.backward(&stack.params, &layers[l], dim, grad, l > 0);
                }
                grads
            })
            .collect();
        kernels::sum_in_order(&per_chunk, grads);
    }
}

#[cfg(test)]
mod tests;
