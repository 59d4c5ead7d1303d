//! VEGAS+'s adaptive stratification (Lepage 2021, Sec. 3), as G. P. Lepage's `vegas` package does
//! it: y-space is cut into hypercubes, n_s or n_s + 1 strata per axis; a quarter of each
//! iteration's points is spread evenly over them and the other three quarters in proportion to
//! d_h = σ_h^β, where σ_h² is the variance of hypercube h's contribution to the last iteration's
//! estimate (V_h²·Var(f·J)/n_h). Taking the variance of the contribution rather than of f·J keeps
//! a hypercube that got many points from drawing still more on the strength of them alone.

/// Share of each iteration's points allocated by the measured variances (the package's
/// `neval_frac`); the rest is spread evenly, at least `min_per_cube` per hypercube.
pub(crate) const ADAPTIVE_SHARE: f64 = 0.75;

/// The hypercubes of one call and their adapted weights d_h.
#[derive(Clone, Debug)]
pub(crate) struct Strata {
    /// Strata per axis (the first axes may have one more than the others).
    pub(crate) per_axis: Vec<usize>,
    /// Number of hypercubes, Π per_axis.
    pub(crate) cubes: usize,
    /// d_h = σ_h^β per hypercube (all 1 before the first iteration).
    weights: Vec<f64>,
}

impl Strata {
    /// As many hypercubes as leave `min_per_cube` points each in the evenly spread quarter of
    /// `per_iter` points: n_s = ⌊(N/4/min)^(1/d)⌋ per axis, then as many axes as fit with n_s + 1.
    pub(crate) fn plan(dim: usize, per_iter: usize, min_per_cube: usize) -> Strata {
        let even = (1.0 - ADAPTIVE_SHARE) * per_iter as f64 / min_per_cube as f64;
        let mut ns = (even.powf(1.0 / dim as f64).floor() as usize).max(1);
        // Guard the root's rounding: n_s^d must not exceed the budget, (n_s + 1)^d must.
        while ns > 1 && (ns as f64).powi(dim as i32) > even {
            ns -= 1;
        }
        while ((ns + 1) as f64).powi(dim as i32) <= even {
            ns += 1;
        }
        let mut per_axis = vec![ns; dim];
        let mut cubes = ns.pow(dim as u32);
        for s in per_axis.iter_mut() {
            if (cubes / ns * (ns + 1)) as f64 > even {
                break;
            }
            cubes = cubes / ns * (ns + 1);
            *s = ns + 1;
        }
        Strata {
            per_axis,
            cubes,
            weights: vec![1.0; cubes],
        }
    }

    /// Same hypercubes as `other` (then its adapted weights can be kept).
    pub(crate) fn same_cubes(&self, other: &Strata) -> bool {
        self.per_axis == other.per_axis
    }

    /// Points per hypercube for an iteration of `per_iter` points: an even base of
    /// ⌊N/4/cubes⌋ (at least `min_per_cube`) and the rest ∝ d_h, rounded cumulatively so the
    /// counts add up to exactly `per_iter`.
    pub(crate) fn allocate(&self, per_iter: usize, min_per_cube: usize) -> Vec<usize> {
        let cubes = self.cubes;
        let base = ((((1.0 - ADAPTIVE_SHARE) * per_iter as f64) / cubes as f64) as usize)
            .max(min_per_cube);
        let spare = per_iter.saturating_sub(cubes * base) as f64;
        let total: f64 = self.weights.iter().sum();
        let (mut cum, mut given) = (0.0, 0usize);
        self.weights
            .iter()
            .map(|w| {
                cum += if total > 0.0 {
                    spare * w / total
                } else {
                    spare / cubes as f64
                };
                let upto = cum.round() as usize;
                let extra = upto.saturating_sub(given);
                given += extra;
                base + extra
            })
            .collect()
    }

    /// The y-coordinates' lower corner, in strata, of hypercube `h`, written to `corner`.
    pub(crate) fn corner(&self, mut h: usize, corner: &mut [usize]) {
        for (c, &s) in corner.iter_mut().zip(&self.per_axis) {
            *c = h % s;
            h /= s;
        }
    }

    /// Replaces the weights by d_h = (σ_h²)^(β/2) from the variances of the hypercubes'
    /// contributions; all zero (a constant integrand) spreads points evenly again.
    pub(crate) fn adapt(&mut self, contribution_var: &[f64], beta: f64) {
        for (w, v) in self.weights.iter_mut().zip(contribution_var) {
            *w = v.abs().powf(beta / 2.0);
        }
        if !self.weights.iter().any(|w| *w > 0.0 && w.is_finite()) {
            self.weights.fill(1.0);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plans_fill_the_even_share_without_exceeding_it() {
        for (dim, per_iter) in [(1, 1000), (2, 50_000), (4, 50_000), (8, 50_000), (16, 1000)] {
            let s = Strata::plan(dim, per_iter, 2);
            let even = per_iter as f64 / 4.0 / 2.0;
            assert_eq!(s.cubes, s.per_axis.iter().product::<usize>());
            assert!(s.cubes as f64 <= even.max(1.0), "{dim} {per_iter}: {s:?}");
            // One more stratum on the next axis would not fit.
            let ns = s.per_axis[dim - 1];
            let more = s.cubes / ns * (ns + 1);
            assert!(more as f64 > even, "{dim} {per_iter}: {s:?}");
            let max = *s.per_axis.iter().max().unwrap();
            let min = *s.per_axis.iter().min().unwrap();
            assert!(max - min <= 1);
        }
        // 50 000 points in 2-d: 6250 cubes at most, 79 × 79 = 6241.
        assert_eq!(Strata::plan(2, 50_000, 2).per_axis, vec![79, 79]);
    }

    #[test]
    fn allocation_adds_up_and_follows_the_weights() {
        let mut s = Strata::plan(2, 1000, 2);
        assert_eq!(s.cubes, 121);
        let counts = s.allocate(1000, 2);
        assert_eq!(counts.iter().sum::<usize>(), 1000);
        assert!(counts.iter().all(|&c| c >= 2));
        // One cube with all the variance takes the adaptive three quarters.
        let mut var = vec![0.0; s.cubes];
        var[7] = 4.0;
        s.adapt(&var, 0.75);
        let counts = s.allocate(1000, 2);
        assert_eq!(counts.iter().sum::<usize>(), 1000);
        assert_eq!(counts[7], 1000 - 2 * 120);
        // A zero integrand: even again.
        s.adapt(&vec![0.0; s.cubes], 0.75);
        let counts = s.allocate(1000, 2);
        assert!(counts.iter().all(|&c| c == 8 || c == 9), "{counts:?}");
    }

    #[test]
    fn corners_enumerate_every_cube_once() {
        let s = Strata::plan(3, 400, 2);
        let mut seen = std::collections::HashSet::new();
        let mut c = vec![0; 3];
        for h in 0..s.cubes {
            s.corner(h, &mut c);
            assert!(c.iter().zip(&s.per_axis).all(|(a, b)| a < b));
            assert!(seen.insert(c.clone()));
        }
    }
}
