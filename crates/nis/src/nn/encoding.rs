//! Input encodings of the conditioners, separate modules in front of the network as in
//! tiny-cuda-nn.
//!
//! [`OneBlob`] (Müller et al. 2019, "Neural Importance Sampling", Sec. 4.3): each scalar
//! s ∈ [0, 1] becomes `bins` values e_j = exp(−(k²/2)·((j + ½)/k − s)²), a Gaussian blob of width
//! 1/k centred on s; the kernels are [`crate::kernels::elementwise::one_blob`] and its backward.

use crate::kernels::elementwise;

/// The one-blob encoding with `bins` bins per scalar.
///
/// ```
/// use nis::nn::encoding::OneBlob;
/// let enc = OneBlob { bins: 4 };
/// let mut e = [0.0; 4];
/// enc.encode(&[0.1], &mut e);
/// assert!(e[0] > e[1] && e[1] > e[2] && e[2] > e[3]); // the blob sits in the first bin
/// ```
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct OneBlob {
    pub bins: usize,
}

impl OneBlob {
    /// Encoded values per `n` scalars.
    pub fn width(&self, n: usize) -> usize {
        n * self.bins
    }

    /// Writes the `bins` values of every scalar in `s`, one scalar after another.
    pub fn encode(&self, s: &[f32], out: &mut [f32]) {
        elementwise::one_blob(s, self.bins, out);
    }

    /// Reverse mode: from the encoding `e` of `s` and ∂L/∂e, writes ∂L/∂s.
    pub fn backward(&self, s: &[f32], e: &[f32], g_e: &[f32], g_s: &mut [f32]) {
        elementwise::one_blob_backward(s, self.bins, e, g_e, g_s);
    }
}
