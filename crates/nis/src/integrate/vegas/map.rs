//! The VEGAS map (Lepage 1978; Lepage 2021, Sec. 2): per dimension a piecewise-linear map y ↦ x
//! with `n` increments of equal width in y, whose widths in x adapt after each iteration so that
//! every increment carries an equal share of the (smoothed, damped) average of (f·J)² projected on
//! that axis. The adaptation follows G. P. Lepage's `vegas` package (`AdaptiveMap.adapt`): the
//! training datum of an increment is the *average* of (V_h·f·J)² over the points that fell in it,
//! smoothed with weights (1, 6, 1)/8, normalised, floored at [`TINY`] and compressed by
//! ((1 − r)/ln(1/r))^α.

/// Floor of a normalised training datum: an increment no point has reached still keeps a width
/// (after the compression, (1/ln(1/TINY))^α ≈ 0.04 of an average one for α = ½), so the map never
/// closes a region for good (the package's `TINY`).
const TINY: f64 = 1e-257;
/// Shares above this are left uncompressed: (1 − r)/ln(1/r) → 1 as r → 1 and the formula loses
/// its digits there.
const NEARLY_ONE: f64 = 0.999_999_99;

use crate::comm::Comm;

/// The separable map: per dimension, `n + 1` edges from 0 to 1.
#[derive(Clone, Debug)]
pub(super) struct Map {
    dim: usize,
    pub(super) n: usize,
    pub(super) edges: Vec<f64>,
    /// Σ (V_h·f·J)² and the number of points, per dimension and increment, since the last adapt.
    sum: Vec<f64>,
    count: Vec<u64>,
}

impl Map {
    /// The identity map with `n` increments per dimension.
    pub(super) fn new(dim: usize, n: usize) -> Map {
        let edges = (0..dim)
            .flat_map(|_| (0..=n).map(move |i| i as f64 / n as f64))
            .collect();
        Map {
            dim,
            n,
            edges,
            sum: vec![0.0; dim * n],
            count: vec![0; dim * n],
        }
    }

    /// x(y) and the Jacobian dx/dy, plus each coordinate's increment index.
    pub(super) fn apply(&self, y: &[f64], x: &mut [f64], inc: &mut [usize]) -> f64 {
        let mut jac = 1.0;
        for d in 0..self.dim {
            let t = y[d] * self.n as f64;
            let i = (t as usize).min(self.n - 1);
            let e = &self.edges[d * (self.n + 1)..];
            let w = e[i + 1] - e[i];
            x[d] = e[i] + (t - i as f64) * w;
            inc[d] = i;
            jac *= self.n as f64 * w;
        }
        jac
    }

    /// Records one point's training datum (V_h·f·J)² in the increments `inc` it fell in.
    pub(super) fn add_training(&mut self, inc: &[usize], datum: f64) {
        for (d, &i) in inc.iter().enumerate() {
            self.sum[d * self.n + i] += datum;
            self.count[d * self.n + i] += 1;
        }
    }

    /// Sums the training data over the ranks of `comm` (sums and counts per increment), so that
    /// every rank adapts to all the points. With one process it changes nothing.
    pub(super) fn reduce_training(&mut self, comm: &Comm) {
        if comm.size() == 1 {
            return;
        }
        comm.sum_f64(&mut self.sum);
        // Counts stay far below 2^53: exact as f64.
        let mut count: Vec<f64> = self.count.iter().map(|&c| c as f64).collect();
        comm.sum_f64(&mut count);
        for (c, v) in self.count.iter_mut().zip(count) {
            *c = v as u64;
        }
    }

    /// Moves the edges so each increment carries an equal share of the smoothed, compressed
    /// training data, then clears it. A dimension without data keeps its edges.
    pub(super) fn adapt(&mut self, alpha: f64) {
        let n = self.n;
        if n == 1 || alpha == 0.0 {
            self.clear();
            return;
        }
        let mut avg = vec![0.0; n];
        let mut s = vec![0.0; n];
        for d in 0..self.dim {
            for (i, a) in avg.iter_mut().enumerate() {
                let c = self.count[d * n + i];
                *a = if c > 0 {
                    self.sum[d * n + i] / c as f64
                } else {
                    0.0
                };
            }
            // Smooth with the neighbours, (1, 6, 1)/8 inside and (7, 1)/8 at the ends.
            s[0] = (7.0 * avg[0] + avg[1]) / 8.0;
            s[n - 1] = (7.0 * avg[n - 1] + avg[n - 2]) / 8.0;
            for i in 1..n - 1 {
                s[i] = (avg[i - 1] + 6.0 * avg[i] + avg[i + 1]) / 8.0;
            }
            let sum: f64 = s.iter().sum();
            if !(sum > 0.0 && sum.is_finite()) {
                continue;
            }
            // Compress: ((1 − r)/ln(1/r))^α with r the share, so no increment dominates and
            // none vanishes.
            for v in s.iter_mut() {
                let r = *v / sum + TINY;
                *v = if r <= NEARLY_ONE {
                    ((1.0 - r) / (-r.ln())).powf(alpha)
                } else {
                    r
                };
            }
            self.regrid(d, &s);
        }
        self.clear();
    }

    /// New edges of dimension `d` such that each increment holds an equal share of `weights`
    /// (one per old increment, spread evenly across it).
    fn regrid(&mut self, d: usize, weights: &[f64]) {
        let n = self.n;
        let total: f64 = weights.iter().sum();
        let per = total / n as f64;
        let old: Vec<f64> = self.edges[d * (n + 1)..(d + 1) * (n + 1)].to_vec();
        let new = &mut self.edges[d * (n + 1)..(d + 1) * (n + 1)];
        let (mut j, mut acc) = (0usize, 0.0f64);
        for (k, edge) in new.iter_mut().enumerate().take(n).skip(1) {
            let target = per * k as f64;
            while j < n - 1 && acc + weights[j] < target {
                acc += weights[j];
                j += 1;
            }
            let frac = ((target - acc) / weights[j]).clamp(0.0, 1.0);
            *edge = old[j] + frac * (old[j + 1] - old[j]);
        }
        new[0] = 0.0;
        new[n] = 1.0;
    }

    fn clear(&mut self) {
        self.sum.fill(0.0);
        self.count.fill(0);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_flat_integrand_leaves_the_map_uniform() {
        let mut m = Map::new(2, 10);
        for i in 0..10 {
            m.add_training(&[i, 9 - i], 4.0);
        }
        m.adapt(0.5);
        for (k, e) in m.edges[..11].iter().enumerate() {
            assert!((e - k as f64 / 10.0).abs() < 1e-12, "{e}");
        }
    }

    #[test]
    fn increments_shrink_where_the_data_is_large_and_never_close() {
        let mut m = Map::new(1, 8);
        // All weight in increment 2, none elsewhere (not even visited).
        m.add_training(&[2], 1.0);
        m.adapt(0.5);
        let widths: Vec<f64> = m.edges.windows(2).map(|w| w[1] - w[0]).collect();
        let widest = widths.iter().cloned().fold(0.0, f64::max);
        // Increment 2 of the old map ([0.25, 0.375]) now holds several new ones.
        let inside = m
            .edges
            .iter()
            .filter(|e| (0.25..=0.375).contains(*e))
            .count();
        assert!(inside >= 3, "{:?}", m.edges);
        // Unvisited regions still get increments of finite width: the unvisited [0.5, 1] is
        // not swallowed by one increment reaching back into the data.
        assert!(widths.iter().all(|&w| w > 0.0), "{widths:?}");
        assert!(widest < 0.6 && m.edges[7] > 0.4, "{widths:?}");
        // Training data is cleared by adapting: a second adapt changes nothing.
        let before = m.edges.clone();
        m.adapt(0.5);
        assert_eq!(before, m.edges);
    }

    #[test]
    fn the_training_datum_is_an_average_per_increment() {
        // Two increments with the same average but different counts give a uniform map.
        let mut m = Map::new(1, 2);
        m.add_training(&[0], 3.0);
        for _ in 0..5 {
            m.add_training(&[1], 3.0);
        }
        m.adapt(1.0);
        assert!((m.edges[1] - 0.5).abs() < 1e-12, "{:?}", m.edges);
    }
}
