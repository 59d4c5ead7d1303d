//! Exact-on-a-grid divergences between a 2-D target and a flow: the curves of `nis fit-image`
//! are computed here, on a fixed midpoint grid, not estimated from training samples.
//!
//! With p = f/∫f tabulated at the midpoints of an nx×ny grid (cell area h² = 1/(nx·ny)) and the
//! flow's exact density q at the same points,
//! - D_KL(p‖q) = Σ p ln(p/q) h² (cells with p = 0 contribute 0),
//! - the relative variance of the one-sample estimator f/q, Var(f/q)/F² = Σ p²/q h² − 1
//!   (the χ² divergence; 0 when q = p).
//!
//! These are midpoint quadratures: exact for the grid's piecewise-constant p, and within O(h²)
//! of the continuous integrals. For an image target the grid is the pixel grid (capped at
//! [`MAX_GRID`] per side), so p is exactly the pixels' luminance there.

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::image::Target;
use nis::flow::{Density, Flow};

/// Largest number of grid cells per side (a larger image is resampled bilinearly).
pub const MAX_GRID: usize = 512;

/// Smallest number of grid cells per side (a smaller image is resampled bilinearly).
pub const MIN_GRID: usize = 64;

/// A target tabulated on a midpoint grid, normalised to a density.
#[derive(Clone, Debug)]
pub struct Grid {
    nx: usize,
    ny: usize,
    /// Midpoints, row-major n×2 (x, y), row 0 at the top (y near 1), as an image is stored.
    points: Vec<f32>,
    /// p = f/F at each midpoint, ∑ p h² = 1.
    p: Vec<f64>,
}

/// D_KL(p‖q) and Var(f/q)/F² of a flow against a grid's target.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct GridMetrics {
    /// D_KL(p‖q) in nats.
    pub kl: f64,
    /// Relative variance of the estimator f/q: Var(f/q)/F².
    pub rel_var: f64,
}

impl Grid {
    /// The grid that matches `target`: its pixel grid, each side clamped to
    /// [`MIN_GRID`]..=[`MAX_GRID`].
    pub fn for_target(target: &Target) -> Result<Grid> {
        let side = |n: usize| n.clamp(MIN_GRID, MAX_GRID);
        Grid::new(target, side(target.width()), side(target.height()))
    }

    /// `target` tabulated at the midpoints of an nx×ny grid.
    pub fn new(target: &Target, nx: usize, ny: usize) -> Result<Grid> {
        if nx == 0 || ny == 0 {
            return Err(Error::Config(format!("an empty {nx}×{ny} grid")));
        }
        let mut points = Vec::with_capacity(2 * nx * ny);
        for j in 0..ny {
            for i in 0..nx {
                points.push(((i as f64 + 0.5) / nx as f64) as f32);
                points.push((1.0 - (j as f64 + 0.5) / ny as f64) as f32);
            }
        }
        let f: Vec<f64> = points
            .chunks_exact(2)
            .map(|x| target.value(x[0] as f64, x[1] as f64))
            .collect();
        let integral = f.iter().sum::<f64>() / (nx * ny) as f64;
        if integral <= 0.0 || !integral.is_finite() {
            return Err(Error::Target {
                name: target.name().to_string(),
                reason: format!("its integral on the {nx}×{ny} grid is {integral}"),
            });
        }
        let p = f.iter().map(|v| v / integral).collect();
        Ok(Grid { nx, ny, points, p })
    }

    /// Cells per side: (nx, ny).
    pub fn size(&self) -> (usize, usize) {
        (self.nx, self.ny)
    }

    /// The normalised target p at the midpoints (row-major, row 0 at the top).
    pub fn p(&self) -> &[f64] {
        &self.p
    }

    /// The flow's density q at the midpoints (row-major, row 0 at the top).
    pub fn q(&self, flow: &Flow) -> Result<Vec<f64>> {
        Ok(flow
            .log_density(&self.points, None)?
            .into_iter()
            .map(f64::exp)
            .collect())
    }

    /// D_KL(p‖q) and Var(f/q)/F² of `flow` on this grid.
    pub fn metrics(&self, flow: &Flow) -> Result<GridMetrics> {
        let log_q = flow.log_density(&self.points, None)?;
        Ok(self.metrics_of_log_q(&log_q))
    }

    /// The metrics of a density given by its logarithm at the midpoints.
    pub fn metrics_of_log_q(&self, log_q: &[f64]) -> GridMetrics {
        let cell = 1.0 / (self.nx * self.ny) as f64;
        let (mut kl, mut chi) = (0.0, 0.0);
        for (&p, &lq) in self.p.iter().zip(log_q) {
            if p > 0.0 {
                kl += p * (p.ln() - lq);
                chi += p * p * (-lq).exp();
            }
        }
        GridMetrics {
            kl: kl * cell,
            rel_var: chi * cell - 1.0,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn uniform_q_gives_the_closed_form_divergences() {
        // A constant image has p = 1: KL = 0 and variance 0 against uniform q.
        let t = Target::from_luminance("flat", 3, 2, vec![2.0; 6]).unwrap();
        let g = Grid::for_target(&t).unwrap();
        assert_eq!(g.size(), (MIN_GRID, MIN_GRID));
        let m = g.metrics_of_log_q(&vec![0.0; MIN_GRID * MIN_GRID]);
        assert!(m.kl.abs() < 1e-12 && m.rel_var.abs() < 1e-12, "{m:?}");

        // Half the square black: p = 2 on the right half, KL = ln 2, Var = 1 against uniform.
        let t = Target::from_luminance("half", 2, 1, vec![0.0, 1.0]).unwrap();
        let g = Grid::new(&t, 2, 2).unwrap();
        let m = g.metrics_of_log_q(&[0.0; 4]);
        assert!((m.kl - 2f64.ln()).abs() < 1e-12, "{m:?}");
        assert!((m.rel_var - 1.0).abs() < 1e-12, "{m:?}");
        // And q = p gives zero for both.
        let lq = [f64::NEG_INFINITY, 2f64.ln(), f64::NEG_INFINITY, 2f64.ln()];
        let m = g.metrics_of_log_q(&lq);
        assert!(m.kl.abs() < 1e-12 && m.rel_var.abs() < 1e-12, "{m:?}");
    }

    #[test]
    fn an_untrained_flow_is_uniform_on_the_grid() {
        let t = crate::image::Target::builtin(crate::image::Builtin::Checkerboard, 60).unwrap();
        let g = Grid::new(&t, 60, 60).unwrap();
        let flow = Flow::new(nis::flow::FlowConfig::new(2)).unwrap();
        let m = g.metrics(&flow).unwrap();
        // p is 2 on half the cells and 0 elsewhere (up to anti-aliased edges): KL ≈ ln 2.
        assert!((m.kl - 2f64.ln()).abs() < 0.05, "{m:?}");
        assert!((m.rel_var - 1.0).abs() < 0.1, "{m:?}");
    }
}
