//! A piecewise-constant density over the upper hemisphere (z ≥ 0) for sampling the sky: a grid
//! of cells equal in zenith angle θ and azimuth φ, each drawn in proportion to the largest
//! importance seen at its corners and centre times its solid angle (plus a floor, so that every
//! direction of the hemisphere has density), then a direction uniformly in the cell's solid
//! angle (uniform in φ and in cos θ), so the density of a direction is
//! `p(cell) / Ω(cell)` (the envmap's construction, Pharr et al., *PBR* 4th ed., §12.5.2, on
//! equal-area sampling inside each cell).

use std::f32::consts::{FRAC_PI_2, PI, TAU};

use glam::{Vec2, Vec3};

use crate::sampling::Distribution2D;

/// Cells in azimuth.
const COLUMNS: usize = 512;
/// Cells in zenith angle, over 0 to π/2.
const ROWS: usize = 128;
/// The floor of a cell's importance, relative to the hemisphere's mean.
const FLOOR: f64 = 1e-3;

/// The sky's sampling table.
#[derive(Clone, Debug)]
pub struct HemisphereTable {
    cells: Distribution2D,
    /// `cos θ` at the rows' edges, from 1 (zenith) down to 0 (horizon).
    cos_edges: Vec<f32>,
    /// Solid angle of a cell of each row.
    cell_solid_angle: Vec<f32>,
    /// ∫ importance dω, as the table sees it (its largest-corner weights).
    total: f64,
}

/// Local direction of zenith angle cosine `z` and azimuth `phi`.
fn direction(z: f32, phi: f32) -> Vec3 {
    let r = (1.0 - z * z).max(0.0).sqrt();
    let (s, c) = phi.sin_cos();
    Vec3::new(r * c, r * s, z)
}

impl HemisphereTable {
    /// A table for the non-negative `importance` of local directions; `None` when it is zero
    /// over the whole hemisphere.
    pub fn new(importance: impl Fn(Vec3) -> f32) -> Option<HemisphereTable> {
        let d_theta = FRAC_PI_2 as f64 / ROWS as f64;
        let d_phi = TAU as f64 / COLUMNS as f64;
        let phi_at = |x: f64| (-std::f64::consts::PI + x * d_phi) as f32;
        let cos_edges: Vec<f32> = (0..=ROWS)
            .map(|j| (j as f64 * d_theta).cos() as f32)
            .map(|c| c.max(0.0))
            .collect();
        let cell_solid_angle: Vec<f32> = (0..ROWS)
            .map(|j| ((f64::from(cos_edges[j]) - f64::from(cos_edges[j + 1])) * d_phi) as f32)
            .collect();
        let at = |theta: f64, phi: f32| {
            f64::from(importance(direction(theta.cos() as f32, phi)).max(0.0))
        };
        // Importance at the corners (shared between cells) and at the centres.
        let corners: Vec<Vec<f64>> = (0..=ROWS)
            .map(|j| {
                (0..COLUMNS)
                    .map(|i| at(j as f64 * d_theta, phi_at(i as f64)))
                    .collect()
            })
            .collect();
        let mut weights = vec![vec![0.0f64; COLUMNS]; ROWS];
        let mut mean = 0.0f64;
        for j in 0..ROWS {
            for i in 0..COLUMNS {
                let centre = at((j as f64 + 0.5) * d_theta, phi_at(i as f64 + 0.5));
                let i1 = (i + 1) % COLUMNS;
                let m = [
                    corners[j][i],
                    corners[j][i1],
                    corners[j + 1][i],
                    corners[j + 1][i1],
                ]
                .into_iter()
                .fold(centre, f64::max);
                weights[j][i] = m;
                mean += m * f64::from(cell_solid_angle[j]);
            }
        }
        mean /= TAU as f64;
        if !(mean > 0.0 && mean.is_finite()) {
            return None;
        }
        // The floor gives every row weight, so every cell can be drawn.
        let rows: Vec<Vec<f32>> = weights
            .iter()
            .zip(&cell_solid_angle)
            .map(|(row, &omega)| {
                row.iter()
                    .map(|&m| ((m + FLOOR * mean) * f64::from(omega)) as f32)
                    .collect()
            })
            .collect();
        let total = rows
            .iter()
            .map(|r| r.iter().map(|&v| f64::from(v)).sum::<f64>())
            .sum();
        Some(HemisphereTable {
            cells: Distribution2D::new(&rows)?,
            cos_edges,
            cell_solid_angle,
            total,
        })
    }

    /// ∫ importance dω over the hemisphere, as the table weighs it (an upper estimate).
    pub fn total(&self) -> f64 {
        self.total
    }

    /// A local direction drawn from two uniform numbers (`None` only for a row of no weight,
    /// which the floor rules out).
    pub fn sample(&self, u: Vec2) -> Option<Vec3> {
        let (j, i, f) = self.cells.sample(u)?;
        let z = self.cos_edges[j] + f.y * (self.cos_edges[j + 1] - self.cos_edges[j]);
        let phi = -PI + (i as f32 + f.x) * (TAU / COLUMNS as f32);
        Some(direction(z, phi))
    }

    /// Solid-angle density of [`HemisphereTable::sample`] at unit local direction `d`.
    pub fn pdf(&self, d: Vec3) -> f32 {
        if d.z < 0.0 {
            return 0.0;
        }
        let theta = (d.x * d.x + d.y * d.y).sqrt().atan2(d.z);
        let j = ((theta / (FRAC_PI_2 / ROWS as f32)) as usize).min(ROWS - 1);
        let phi = d.y.atan2(d.x);
        let i = (((phi + PI) / (TAU / COLUMNS as f32)) as usize).min(COLUMNS - 1);
        self.cells.pmf(j, i) / self.cell_solid_angle[j]
    }
}
