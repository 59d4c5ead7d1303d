//! How much less variance a sample stratified on a grid of the flow's latent would have than an
//! i.i.d. one, predicted from i.i.d. weights post-stratified on that grid (Cochran 1977, Sec.
//! 5A.9): the training batches kept for the estimate predict with it how much better than
//! theirs the stratified final phase's variance is, which sets their shares (`reuse.rs`).

/// i.i.d. weights `w` at latents `z` (`n × dim`, uniform on [0,1]^dim) post-stratified on the
/// grid `per_axis` (Cochran 1977, Sec. 5A.9): the sums that estimate how much less variance per
/// point a sample stratified on that grid would have than an i.i.d. one, both with points in
/// proportion to the hypercubes' volumes and with points where the variance is (see
/// [`PostStratified::gain`]). Hypercubes holding one point or none add nothing but to the total.
pub(super) fn post_stratified(z: &[f32], w: &[f64], per_axis: &[usize]) -> PostStratified {
    let dim = per_axis.len();
    let n = w.len();
    let mut cube: Vec<(usize, f64)> = z
        .chunks_exact(dim)
        .zip(w)
        .map(|(p, &v)| {
            let mut h = 0;
            for (&c, &s) in p.iter().zip(per_axis).rev() {
                let i = ((c as f64 * s as f64) as usize).min(s - 1);
                h = h * s + i;
            }
            (h, v)
        })
        .collect();
    // Sorted by hypercube (stable: equal cubes keep the points' order, so the sums are
    // deterministic).
    cube.sort_by_key(|&(h, _)| h);
    let mut sums = PostStratified::default();
    let mut start = 0;
    while start < cube.len() {
        let h = cube[start].0;
        let end = start + cube[start..].iter().take_while(|c| c.0 == h).count();
        let points = &cube[start..end];
        let m = points.len() as f64;
        if m >= 2.0 {
            let mean = points.iter().map(|c| c.1).sum::<f64>() / m;
            sums.within_ss += points.iter().map(|c| (c.1 - mean).powi(2)).sum::<f64>();
            sums.within_df += m - 1.0;
            // Disjoint pairs, so that they are independent.
            for pair in points.chunks_exact(2) {
                let d = pair[0].1 - pair[1].1;
                sums.pairs += 1.0;
                sums.pair_abs += d.abs();
                sums.pair_sq += d * d;
            }
        }
        start = end;
    }
    if n >= 2 {
        let mean = w.iter().sum::<f64>() / n as f64;
        sums.total_ss = w.iter().map(|v| (v - mean).powi(2)).sum();
        sums.total_df = n as f64 - 1.0;
    }
    sums
}

/// Sums of a post-stratified sample ([`post_stratified`]); they add up over samples (and ranks).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub(super) struct PostStratified {
    /// Σ over hypercubes of Σ (w − mean_h)², and Σ (n_h − 1), over those with two or more.
    pub(super) within_ss: f64,
    pub(super) within_df: f64,
    /// Σ (w − mean)² and n − 1.
    pub(super) total_ss: f64,
    pub(super) total_df: f64,
    /// Disjoint pairs of points sharing a hypercube: how many, Σ |w₁ − w₂| and Σ (w₁ − w₂)².
    pub(super) pairs: f64,
    pub(super) pair_abs: f64,
    pub(super) pair_sq: f64,
}

impl PostStratified {
    /// As numbers (for a sum over ranks), and back.
    pub(super) fn to_array(self) -> [f64; 7] {
        [
            self.within_ss,
            self.within_df,
            self.total_ss,
            self.total_df,
            self.pairs,
            self.pair_abs,
            self.pair_sq,
        ]
    }

    pub(super) fn from_array(a: [f64; 7]) -> PostStratified {
        PostStratified {
            within_ss: a[0],
            within_df: a[1],
            total_ss: a[2],
            total_df: a[3],
            pairs: a[4],
            pair_abs: a[5],
            pair_sq: a[6],
        }
    }

    /// The sums of both samples.
    pub(super) fn plus(self, other: PostStratified) -> PostStratified {
        let (mut a, b) = (self.to_array(), other.to_array());
        a.iter_mut().zip(b).for_each(|(a, b)| *a += b);
        PostStratified::from_array(a)
    }

    /// The i.i.d. variance per point over the stratified one with points in proportion to the
    /// volumes, E_h[σ_h²]: total over within-hypercube mean square (at least 1, such a
    /// stratified sample never being worse in expectation; 1 when either is not measured).
    pub(super) fn proportional_gain(&self) -> f64 {
        if self.within_df < 1.0 || self.total_df < 1.0 {
            return 1.0;
        }
        let total = self.total_ss / self.total_df;
        let within = self.within_ss / self.within_df;
        if within > 0.0 {
            (total / within).max(1.0)
        } else if total > 0.0 {
            f64::INFINITY
        } else {
            1.0
        }
    }

    /// What putting points where the variance is (Neyman's n_h ∝ σ_h, which VEGAS+'s damped
    /// allocation approaches) gains over proportional points: E_h[σ_h²]/E_h[σ_h]². A pair's
    /// difference gives σ_h² without bias, (w₁ − w₂)²/2, but σ_h only through its shape: for a
    /// normal w within the hypercube E|w₁ − w₂| = 2σ_h/√π, so the estimate is
    /// (2/π)·mean(d²)/mean(|d|)², exact for normal ones and too large for skewed or two-valued
    /// ones (a Laplace difference: ×1.27; an edge of an indicator: ~×1.8), which errs towards
    /// the final phase. At least 1 (Neyman's is never worse); 1 without pairs.
    pub(super) fn allocation_gain(&self) -> f64 {
        if self.pairs < 1.0 || self.pair_abs <= 0.0 {
            return 1.0;
        }
        let (abs, sq) = (self.pair_abs / self.pairs, self.pair_sq / self.pairs);
        (2.0 / std::f64::consts::PI * sq / (abs * abs)).max(1.0)
    }

    /// The predicted gain of a stratified sample on the grid with an adapted allocation over an
    /// i.i.d. one: [`PostStratified::proportional_gain`] × [`PostStratified::allocation_gain`].
    pub(super) fn gain(&self) -> f64 {
        self.proportional_gain() * self.allocation_gain()
    }
}

#[cfg(test)]
mod tests {
    use rand::{Rng, SeedableRng};
    use rand_pcg::Pcg64Mcg;

    use super::*;

    /// Bands of `SIGMAS` standard deviations of the sampling distributions below.
    const SIGMAS: f64 = 4.0;

    #[test]
    fn post_stratification_measures_the_variance_a_stratified_sample_would_have() {
        // w = z₀ + 3·z₁ on an s₀ × s₁ grid: within a hypercube of sides 1/s₀, 1/s₁ its variance
        // is (1/s₀² + 9/s₁²)/12, against (1 + 9)/12 i.i.d.
        let grid = [8usize, 5];
        let within = (1.0 / 64.0 + 9.0 / 25.0) / 12.0;
        let mut rng = Pcg64Mcg::seed_from_u64(3);
        let mut pooled = PostStratified::default();
        for _ in 0..20 {
            let z: Vec<f32> = (0..2 * 300).map(|_| rng.random::<f32>()).collect();
            let w: Vec<f64> = z
                .chunks_exact(2)
                .map(|p| p[0] as f64 + 3.0 * p[1] as f64)
                .collect();
            pooled = pooled.plus(post_stratified(&z, &w, &grid));
        }
        // 20 batches of 300 points on 40 hypercubes: about 6000 − 800 degrees of freedom.
        assert!(pooled.within_df > 5000.0, "{pooled:?}");
        // Mean squares of a uniform variable's residuals: relative sd below √(2/df).
        let ms = pooled.within_ss / pooled.within_df;
        let tolerance = SIGMAS * (2.0 / pooled.within_df).sqrt();
        assert!((ms / within - 1.0).abs() < tolerance, "{ms} vs {within}");
        let total = pooled.total_ss / pooled.total_df;
        assert!((total / (10.0 / 12.0) - 1.0).abs() < SIGMAS * (2.0 / pooled.total_df).sqrt());
        let gain = (10.0 / 12.0) / within;
        assert!((pooled.proportional_gain() / gain - 1.0).abs() < 2.0 * tolerance);
        // Normal weights of spread 1 on the left half, 3 on the right: Neyman's allocation gains
        // E[σ²]/E[σ]² = 5/4 over proportional points, which the pairs' differences measure.
        let mut spread = PostStratified::default();
        for _ in 0..20 {
            let z: Vec<f32> = (0..2 * 1000).map(|_| rng.random::<f32>()).collect();
            let w: Vec<f64> = z
                .chunks_exact(2)
                .map(|p| {
                    let (u, v): (f64, f64) = (rng.random(), rng.random());
                    let normal = (-2.0 * (1.0 - u).ln()).sqrt() * (std::f64::consts::TAU * v).cos();
                    if p[0] < 0.5 {
                        normal
                    } else {
                        3.0 * normal
                    }
                })
                .collect();
            spread = spread.plus(post_stratified(&z, &w, &grid));
        }
        // ~10 000 pairs: mean |d| and mean d² within ~1.5% each.
        assert!(spread.pairs > 9000.0, "{spread:?}");
        let allocation = spread.allocation_gain();
        assert!((allocation - 1.25).abs() < 0.1, "{allocation}");
        // No spread to follow: no gain (the linear weights' spread is the same in every
        // hypercube, up to the pairs' noise).
        assert!(
            pooled.allocation_gain() < 1.1,
            "{}",
            pooled.allocation_gain()
        );
        // Hypercubes with a single point carry no within-variance; nothing measured is no gain.
        let lone = post_stratified(&[0.1, 0.1, 0.9, 0.9], &[1.0, 5.0], &grid);
        assert_eq!((lone.within_df, lone.total_df), (0.0, 1.0));
        assert_eq!(lone.gain(), 1.0);
        assert_eq!(PostStratified::default().gain(), 1.0);
        // A weight constant in each hypercube: stratifying removes all its variance.
        let steps = post_stratified(
            &[0.1, 0.1, 0.11, 0.1, 0.9, 0.9, 0.91, 0.9],
            &[1.0, 1.0, 5.0, 5.0],
            &grid,
        );
        assert_eq!(steps.gain(), f64::INFINITY);
    }
}
