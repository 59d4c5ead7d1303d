//! The mean and covariance of an iteration's i.i.d. weights, added chunk by chunk and merged
//! over ranks in a fixed order (Chan, Golub and LeVeque 1979), and the iteration they make
//! ([`super::estimate::iid_iteration`] is the loop that draws them).

use super::iteration::{Iteration, Source};
use crate::comm::Comm;

/// Points drawn and evaluated at once: an iteration's memory, whatever the budget.
pub(crate) const CHUNK: usize = 1 << 16;

/// The moments of one iteration's i.i.d. weight vectors (`k` components), added chunk by chunk:
/// each chunk's mean and co-moments by two passes, merged into the running ones with the
/// pairwise update of Chan, Golub and LeVeque (1979), which keeps the accuracy of two passes
/// without holding the iteration. A single chunk gives the two-pass numbers exactly.
#[derive(Clone, Debug)]
pub struct Moments {
    k: usize,
    n: u64,
    mean: Vec<f64>,
    /// Σ (w_i − mean)(w_j − mean) over the weights so far, `k × k`.
    comoment: Vec<f64>,
    /// Σ |w| and max |w| of component 0 (for the unweighting efficiency).
    sum_abs_w: f64,
    max_abs_w: f64,
}

impl Moments {
    /// No weights yet, `k` components per weight.
    pub fn new(k: usize) -> Moments {
        Moments {
            k,
            n: 0,
            mean: vec![0.0; k],
            comoment: vec![0.0; k * k],
            sum_abs_w: 0.0,
            max_abs_w: 0.0,
        }
    }

    /// Weights so far.
    pub fn n(&self) -> u64 {
        self.n
    }

    /// Adds a chunk of weight vectors (`m × k`, row-major).
    pub fn add(&mut self, w: &[f64]) {
        let k = self.k;
        let m = w.len() / k;
        if m == 0 {
            return;
        }
        let mf = m as f64;
        let mut mean = vec![0.0; k];
        for row in w.chunks_exact(k) {
            for (a, v) in mean.iter_mut().zip(row) {
                *a += v;
            }
        }
        mean.iter_mut().for_each(|a| *a /= mf);
        let mut comoment = vec![0.0; k * k];
        for row in w.chunks_exact(k) {
            for i in 0..k {
                let di = row[i] - mean[i];
                for j in 0..k {
                    comoment[i * k + j] += di * (row[j] - mean[j]);
                }
            }
        }
        for row in w.chunks_exact(k) {
            self.sum_abs_w += row[0].abs();
            self.max_abs_w = self.max_abs_w.max(row[0].abs());
        }
        self.merge_central(m as u64, mean, comoment);
    }

    /// Merges the mean and co-moments of `nb` further weights (Chan, Golub and LeVeque).
    fn merge_central(&mut self, nb: u64, mean: Vec<f64>, comoment: Vec<f64>) {
        let k = self.k;
        if nb == 0 {
            return;
        }
        if self.n == 0 {
            (self.mean, self.comoment, self.n) = (mean, comoment, nb);
            return;
        }
        let (na, nb_f) = (self.n as f64, nb as f64);
        let n = na + nb_f;
        let delta: Vec<f64> = mean.iter().zip(&self.mean).map(|(b, a)| b - a).collect();
        for i in 0..k {
            for j in 0..k {
                self.comoment[i * k + j] +=
                    comoment[i * k + j] + delta[i] * delta[j] * na * nb_f / n;
            }
        }
        for (a, d) in self.mean.iter_mut().zip(&delta) {
            *a += d * nb_f / n;
        }
        self.n += nb;
    }

    /// Adds the weights `later` holds (after these): the pairwise merge of their moments.
    pub fn merge(&mut self, later: &Moments) {
        assert_eq!(self.k, later.k, "moments of as many components");
        self.sum_abs_w += later.sum_abs_w;
        self.max_abs_w = self.max_abs_w.max(later.max_abs_w);
        self.merge_central(later.n, later.mean.clone(), later.comoment.clone());
    }

    /// The moments of every rank's weights of `comm`, merged in rank order (this rank's being
    /// these), on every rank. Every rank must call it together; with one process, a copy.
    pub fn across(&self, comm: &Comm) -> Moments {
        Moments::across_each(std::slice::from_ref(self), comm)
            .pop()
            .expect("one")
    }

    /// [`Moments::across`] for many moments at once, in one gather (e.g. one per hypercube of a
    /// stratified iteration): each merged over the ranks in rank order. All must have the same
    /// number of components, and every rank must pass as many.
    pub(crate) fn across_each(parts: &[Moments], comm: &Comm) -> Vec<Moments> {
        if comm.size() == 1 {
            return parts.to_vec();
        }
        let k = parts.first().map_or(1, |m| m.k);
        let stride = 3 + k + k * k;
        let mut words = Vec::with_capacity(parts.len() * stride);
        for m in parts {
            assert_eq!(m.k, k, "moments of as many components");
            words.extend_from_slice(&[m.n as f64, m.sum_abs_w, m.max_abs_w]);
            words.extend_from_slice(&m.mean);
            words.extend_from_slice(&m.comoment);
        }
        let mut all = vec![Moments::new(k); parts.len()];
        for part in comm.all_gather_bytes(f64s_to_bytes(&words)) {
            for (a, w) in all
                .iter_mut()
                .zip(bytes_to_f64s(&part).chunks_exact(stride))
            {
                a.merge(&Moments {
                    k,
                    n: w[0] as u64,
                    sum_abs_w: w[1],
                    max_abs_w: w[2],
                    mean: w[3..3 + k].to_vec(),
                    comoment: w[3 + k..].to_vec(),
                });
            }
        }
        all
    }

    /// The largest |w| and Σ|w| of component 0.
    pub(crate) fn abs_w(&self) -> (f64, f64) {
        (self.max_abs_w, self.sum_abs_w)
    }

    /// The iteration these weights make (after [`Moments::across`]: over all ranks): their
    /// mean, its variance and, for more than one component, every component's.
    pub fn iteration(&self, source: Source) -> Iteration {
        let (mean, cov) = self.mean_and_cov_of_mean();
        Iteration::new(source, mean, cov, self.n, self.max_abs_w, self.sum_abs_w)
    }

    /// The mean and the covariance of the mean (`k × k`; zero for fewer than two weights).
    pub fn mean_and_cov_of_mean(&self) -> (Vec<f64>, Vec<f64>) {
        let n = self.n as f64;
        let cov = if self.n > 1 {
            self.comoment.iter().map(|c| c / (n - 1.0) / n).collect()
        } else {
            vec![0.0; self.k * self.k]
        };
        (self.mean.clone(), cov)
    }
}

/// Numbers as little-endian bytes, to cross processes.
pub(crate) fn f64s_to_bytes(v: &[f64]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

/// The numbers [`f64s_to_bytes`] made.
pub(crate) fn bytes_to_f64s(b: &[u8]) -> Vec<f64> {
    b.chunks_exact(8)
        .map(|c| f64::from_le_bytes(c.try_into().expect("8 bytes")))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    #[test]
    fn chunked_moments_equal_the_two_pass_ones() {
        // Weights with a large offset and a spread of 1e-3: a one-pass sum of squares would lose
        // about half the digits here; the merged two-pass moments keep them.
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(11);
        let k = 2;
        let w: Vec<f64> = (0..3001 * k)
            .map(|i| 1e4 * (1 + i % k) as f64 + 1e-3 * rng.random::<f64>())
            .collect();
        let mut whole = Moments::new(k);
        whole.add(&w);
        for chunk in [1, 7, 1000, 4096] {
            let mut parts = Moments::new(k);
            for c in w.chunks(chunk * k) {
                parts.add(c);
            }
            let ((m1, c1), (m2, c2)) = (whole.mean_and_cov_of_mean(), parts.mean_and_cov_of_mean());
            assert_eq!(parts.n(), 3001);
            for (a, b) in m1.iter().zip(&m2) {
                assert!(
                    (a - b).abs() <= 1e-12 * a.abs(),
                    "chunk {chunk}: mean {a} vs {b}"
                );
            }
            for (a, b) in c1.iter().zip(&c2) {
                assert!(
                    (a - b).abs() <= 1e-8 * c1[0].abs(),
                    "chunk {chunk}: cov {a} vs {b}"
                );
            }
        }
        // The variance of the mean of the uniform spread: (1e-3)²/12/n, to 10% (n = 3001).
        let var = whole.mean_and_cov_of_mean().1[0];
        assert!((var / (1e-6 / 12.0 / 3001.0) - 1.0).abs() < 0.1, "{var}");
    }

    #[test]
    fn moments_merged_from_parts_equal_the_two_pass_ones() {
        // What `Moments::across` does with the ranks' parts, in rank order: the pooled mean and
        // covariance of all the weights, to the accuracy of the chunked ones above.
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(12);
        let k = 2;
        let w: Vec<f64> = (0..2999 * k)
            .map(|i| 1e4 * (1 + i % k) as f64 + 1e-3 * rng.random::<f64>())
            .collect();
        let mut whole = Moments::new(k);
        whole.add(&w);
        let mut merged = Moments::new(k);
        for part in [
            &w[..2 * k],
            &w[2 * k..2 * k],
            &w[2 * k..1000 * k],
            &w[1000 * k..],
        ] {
            let mut m = Moments::new(k);
            m.add(part);
            merged.merge(&m);
        }
        assert_eq!(merged.n(), 2999);
        assert_eq!(
            merged.sum_abs_w.to_bits(),
            {
                let mut s = 0.0;
                for part in [&w[..2 * k], &w[2 * k..1000 * k], &w[1000 * k..]] {
                    s += part.iter().step_by(k).map(|v| v.abs()).sum::<f64>();
                }
                s
            }
            .to_bits()
        );
        assert_eq!(merged.max_abs_w, whole.max_abs_w);
        let ((m1, c1), (m2, c2)) = (whole.mean_and_cov_of_mean(), merged.mean_and_cov_of_mean());
        for (a, b) in m1.iter().zip(&m2) {
            assert!((a - b).abs() <= 1e-12 * a.abs(), "mean {a} vs {b}");
        }
        for (a, b) in c1.iter().zip(&c2) {
            assert!((a - b).abs() <= 1e-8 * c1[0].abs(), "cov {a} vs {b}");
        }
        // One process: `across` is the identity, bit for bit.
        let same = whole.across(&Comm::default());
        assert_eq!(same.mean_and_cov_of_mean(), whole.mean_and_cov_of_mean());
    }
}
