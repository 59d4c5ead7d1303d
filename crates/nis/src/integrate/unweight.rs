//! Unweighted samples: points distributed as |f|/∫|f|, made from a trained sampler's weighted ones
//! by rejection (von Neumann): keep a point with probability min(1, |w|/w_max).
//!
//! The true maximum weight is unknown and, for a flow, set by rare outliers; rejecting against it
//! would waste almost every point. As in event generators, a *robust* maximum is used instead: the
//! smallest w_max whose overweight mass Σ max(0, |w| − w_max) is at most `overweight` of Σ|w| in a
//! calibration batch. Accepted points whose |w| exceeds w_max keep the excess as a weight
//! |w|/w_max > 1, so the sample stays exact as a weighted sample and is unweighted up to that share.

use rand::Rng;
use rand_pcg::Pcg64Mcg;

use super::nis::NisIntegrator;
use super::Integrand;
use crate::error::{Error, Result};
use crate::flow::Density;

/// Unweighted points with their (rare) residual weights.
#[derive(Clone, Debug)]
pub struct Unweighted {
    /// Coordinates per point.
    pub dim: usize,
    /// Row-major points, `n × dim`.
    pub points: Vec<f64>,
    /// Per point: sign(f) · max(1, |w|/w_max) — ±1 except for overweight points.
    pub weights: Vec<f64>,
    /// The robust maximum weight.
    pub w_max: f64,
    /// Accepted / proposed.
    pub efficiency: f64,
    /// Share of Σ|w| above w_max in the calibration batch.
    pub overweight: f64,
}

impl NisIntegrator {
    /// Draws `n` unweighted points of the target the flow learned (|f| of a scalar integrand)
    /// from this trained integrator, continuing its unweighting stream. `overweight` is the
    /// tolerated share of weight mass above the robust maximum (e.g. 1e-3).
    pub fn unweighted(
        &mut self,
        f: &dyn Integrand,
        n: usize,
        overweight: f64,
    ) -> Result<Unweighted> {
        let mut rng = self.take_unweight_rng();
        let u = unweighted_from(self, f, n, overweight, &mut rng);
        self.put_unweight_rng(rng);
        u
    }
}

fn unweighted_from(
    nis: &mut NisIntegrator,
    f: &dyn Integrand,
    n: usize,
    overweight: f64,
    rng: &mut Pcg64Mcg,
) -> Result<Unweighted> {
    if !(0.0..0.5).contains(&overweight) {
        return Err(Error::Config(format!(
            "overweight share must be in [0, 0.5), got {overweight}"
        )));
    }
    let dim = nis.flow().dim();
    let batch = 1 << 16;
    // Calibration: the robust maximum from one batch of weights.
    let (_, w) = nis.target_weights(f, batch, rng)?;
    let mut a: Vec<f64> = w.iter().map(|v| v.abs()).collect();
    a.sort_by(|x, y| y.total_cmp(x));
    let total: f64 = a.iter().sum();
    if total == 0.0 {
        return Err(Error::Config(
            "the integrand was zero at every calibration point: nothing to sample".into(),
        ));
    }
    // Walk down from the largest weight while the mass above the candidate stays within budget.
    let (mut w_max, mut above) = (a[0], 0.0);
    for k in 1..a.len() {
        // Raising the cut to a[k] adds k·(a[k−1] − a[k]) of overweight mass.
        let extra = k as f64 * (a[k - 1] - a[k]);
        if above + extra > overweight * total {
            w_max = a[k - 1] - (overweight * total - above) / k as f64;
            break;
        }
        above += extra;
        w_max = a[k];
    }
    let over = a.iter().map(|v| (v - w_max).max(0.0)).sum::<f64>() / total;
    let (mut points, mut weights) = (Vec::with_capacity(n * dim), Vec::with_capacity(n));
    let mut proposed = 0usize;
    while weights.len() < n {
        let (x, w) = nis.target_weights(f, batch, rng)?;
        proposed += w.len();
        for (p, &wi) in x.chunks_exact(dim).zip(&w) {
            if weights.len() < n && rng.random::<f64>() * w_max < wi.abs() {
                points.extend_from_slice(p);
                weights.push(wi.signum() * (wi.abs() / w_max).max(1.0));
            }
        }
        nis.report(weights.len() as u64, n as u64, "unweighting");
        if proposed > 1000 * n.max(1000) {
            return Err(Error::Config(format!(
                "unweighting efficiency below 1e-3 ({} of {proposed} accepted): train longer",
                weights.len()
            )));
        }
    }
    Ok(Unweighted {
        dim,
        points,
        weights,
        w_max,
        efficiency: n as f64 / proposed as f64,
        overweight: over,
    })
}

impl Unweighted {
    /// CSV: a header `x0,…,x{d−1},weight`, one point per line.
    pub fn to_csv(&self) -> String {
        let mut s: String = (0..self.dim).map(|i| format!("x{i},")).collect();
        s.push_str("weight\n");
        for (p, w) in self.points.chunks_exact(self.dim).zip(&self.weights) {
            for v in p {
                s.push_str(&format!("{v:.17e},"));
            }
            s.push_str(&format!("{w}\n"));
        }
        s
    }

    /// Binary: the magic `NISSMPL1`, dimension (u32 LE), count (u64 LE), then per point its
    /// `dim` coordinates and its weight as f64 LE.
    pub fn to_binary(&self) -> Vec<u8> {
        let mut b = b"NISSMPL1".to_vec();
        b.extend((self.dim as u32).to_le_bytes());
        b.extend((self.weights.len() as u64).to_le_bytes());
        for (p, w) in self.points.chunks_exact(self.dim).zip(&self.weights) {
            for v in p.iter().chain(std::iter::once(w)) {
                b.extend(v.to_le_bytes());
            }
        }
        b
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::integrate::nis::NisConfig;
    use crate::integrate::Integrator;

    #[test]
    fn unweighted_points_follow_the_integrand() {
        // f(x) = 2x₀ on [0,1]²: the x₀-marginal of unweighted points has mean 2/3, variance 1/18.
        let f = |x: &[f64]| 2.0 * x[0];
        let config = NisConfig::builder().batch(1024).build().unwrap();
        let mut nis = NisIntegrator::new(2, NisConfig { seed: 1, ..config }).unwrap();
        nis.integrate(&f, 100_000).unwrap();
        nis.set_seed(2);
        let n = 20_000;
        let u = nis.unweighted(&f, n, 1e-3).unwrap();
        assert_eq!(u.weights.len(), n);
        assert!(u.overweight <= 1.001e-3 && u.efficiency > 0.1);
        let mean = u.points.chunks(2).map(|p| p[0]).sum::<f64>() / n as f64;
        // 5σ with σ = √(1/18)/√n.
        assert!(
            (mean - 2.0 / 3.0).abs() < 5.0 * (1.0f64 / 18.0 / n as f64).sqrt(),
            "mean {mean}"
        );
        let csv = u.to_csv();
        assert!(csv.starts_with("x0,x1,weight\n") && csv.lines().count() == n + 1);
        let bin = u.to_binary();
        assert_eq!(bin.len(), 8 + 4 + 8 + n * 3 * 8);
        assert!(nis.unweighted(&f, 10, 0.7).is_err());
    }
}
