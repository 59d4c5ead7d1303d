//! Which records of the neural guide's buffer a training step sees.
//!
//! Every gradient of the guide is a weighted sum over records, Σ_r w_r·∇ℓ_r, with the weights
//! built from F/p_s (see [`super`]). A step estimates it from a batch. Drawn uniformly,
//! the batch's records enter with their weights w_r, which span many orders of magnitude in a
//! rendered scene: most of a batch adds almost nothing and a few records carry the step. Drawn
//! with probability π_r ∝ s_r = (F/p_s)_r^α instead, a record enters with w_r / s_r, and the
//! expected batch sum is Σ_r π_r·(w_r/s_r)·∇ℓ_r ∝ Σ_r w_r·∇ℓ_r for every α: the same gradient
//! (the guide divides by the batch's mean weight, estimated the same way), with the batch spent
//! on the records that carry it. α = 0 is the uniform draw, α = 1 the draw by the KL weight
//! itself (every record then enters with weight 1 under the KL loss). In between, the
//! square root (α = ½) spreads the batch over more records than α = 1 while still favouring
//! the bright ones (docs/results/guiding.md, "Records drawn by weight").
//!
//! The draw is Walker's alias method (Vose's construction): one uniform number per pick and one
//! table cell (its threshold and alias side by side, one cache line) per pick. The numbers are
//! drawn in order from the phase's stream and resolved to records in parallel, so the batch
//! does not depend on the thread count; with a buffer of millions of records each lookup is a
//! cache miss, and the cores overlap them.

use rand::Rng;
use rayon::prelude::*;

/// Draws indices into a buffer of records by their weights F/p_s raised to `alpha`.
pub(super) struct RecordPicker {
    len: usize,
    alpha: f64,
    /// The alias table over s = (F/p_s)^α; `None`: uniform (α = 0, or no record with a finite,
    /// positive weight).
    table: Option<Vec<Cell>>,
}

/// One column of the alias table: a uniform position in it keeps its own record below `keep`
/// and goes to `alias` above.
#[derive(Clone, Copy, Debug)]
struct Cell {
    keep: f64,
    alias: u32,
}

impl RecordPicker {
    /// A picker over records with the weights `weights` (F/p_s of each record, in order).
    pub(super) fn new(
        weights: impl IndexedParallelIterator<Item = f64>,
        alpha: f64,
    ) -> RecordPicker {
        let len = weights.len();
        let table = if alpha != 0.0 {
            let s: Vec<f64> = weights.map(|w| scale(w, alpha)).collect();
            alias_table(&s)
        } else {
            None
        };
        RecordPicker { len, alpha, table }
    }

    /// Replaces `picks` by the indices of `n` records (the picker must hold at least one).
    pub(super) fn pick(&self, n: usize, rng: &mut impl Rng, picks: &mut Vec<usize>) {
        picks.clear();
        let Some(table) = &self.table else {
            picks.extend((0..n).map(|_| rng.random_range(0..self.len)));
            return;
        };
        let u: Vec<f64> = (0..n).map(|_| rng.random()).collect();
        let len = table.len() as f64;
        picks.par_extend(u.par_iter().map(|&u| {
            let x = u * len;
            let i = (x as usize).min(table.len() - 1);
            let cell = table[i];
            if x - (i as f64) < cell.keep {
                i
            } else {
                cell.alias as usize
            }
        }));
    }

    /// The factor s = (F/p_s)^α by which a record of weight `w` = F/p_s was favoured: its
    /// training weights are divided by it. 1 for the uniform draw.
    pub(super) fn scale(&self, w: f64) -> f64 {
        match self.table {
            Some(_) => scale(w, self.alpha),
            None => 1.0,
        }
    }
}

/// The exponent a training phase draws by: the configured `alpha` while the phase's `picks`
/// (steps × batch) read each of the buffer's `records` at most once on average, and
/// `alpha · records/picks` when they read it over and over. Drawn with replacement from a
/// small buffer by weight, the extra reads go to the same bright records again and again,
/// while a uniform draw spreads them over every record; the first training phases of a short
/// render read their buffer many times over, and the full α there raised two-rooms-door's MAPE
/// (docs/results/guiding.md, "Records drawn by weight"). Any α keeps the expected gradient.
pub(super) fn phase_alpha(alpha: f64, picks: usize, records: usize) -> f64 {
    if picks <= records {
        alpha
    } else {
        alpha * records as f64 / picks as f64
    }
}

/// (F/p_s)^α (a square root for the default ½), 0 where the weight is not finite and positive
/// (such a record adds nothing to a gradient, so it is never drawn).
fn scale(w: f64, alpha: f64) -> f64 {
    if !(w.is_finite() && w > 0.0) {
        0.0
    } else if alpha == 0.5 {
        w.sqrt()
    } else {
        w.powf(alpha)
    }
}

/// The alias table drawing index i with probability s_i / Σ s (Vose 1991), or `None` when no
/// weight is positive (or there are more records than a cell can name).
fn alias_table(s: &[f64]) -> Option<Vec<Cell>> {
    let n = s.len();
    let total: f64 = s.iter().sum();
    if !(total > 0.0 && total.is_finite()) || u32::try_from(n).is_err() {
        return None;
    }
    // Each column holds a probability mass of 1 in units of the mean.
    let mut mass: Vec<f64> = s.iter().map(|&v| v * n as f64 / total).collect();
    let mut table: Vec<Cell> = (0..n as u32)
        .map(|i| Cell {
            keep: 1.0,
            alias: i,
        })
        .collect();
    let (mut small, mut large): (Vec<u32>, Vec<u32>) =
        (0..n as u32).partition(|&i| mass[i as usize] < 1.0);
    while let (Some(&l), Some(j)) = (large.last(), small.pop()) {
        let (l, j) = (l as usize, j as usize);
        // Column j keeps its own mass and gives the rest of its unit to l.
        table[j] = Cell {
            keep: mass[j],
            alias: l as u32,
        };
        mass[l] -= 1.0 - mass[j];
        if mass[l] < 1.0 {
            large.pop();
            small.push(l as u32);
        }
    }
    // What is left holds a mass of 1 up to rounding: it keeps its own column (set above).
    Some(table)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_pcg::Pcg64Mcg;

    #[test]
    fn a_phase_that_rereads_its_buffer_draws_closer_to_uniform() {
        // Read at most once: the configured exponent.
        assert_eq!(phase_alpha(0.5, 40 * 4096, 227_250), 0.5);
        assert_eq!(phase_alpha(0.5, 4096, 4096), 0.5);
        // Read 40 times over (two-rooms-door's first phase): a fortieth of it.
        assert_eq!(phase_alpha(0.5, 40 * 3640, 3640), 0.5 / 40.0);
        // The uniform draw stays uniform.
        assert_eq!(phase_alpha(0.0, 40 * 3640, 3640), 0.0);
    }

    /// The weighted mean Σ w·h / Σ w over a buffer, estimated from picks that enter with
    /// w/s (the ratio of their sums, as a step normalises by its batch's mean weight), is the
    /// same for every α within 4 standard errors (delta method), and the picks favour the
    /// heavy records. Leaving out the division by s would give Σ s·w·h / Σ s·w instead, many
    /// standard errors away.
    #[test]
    fn drawing_by_weight_keeps_the_weighted_mean() {
        // Weights over four orders of magnitude, and a quantity h to average that grows with
        // them (so weighting by another power of w moves the mean).
        let n_records = 200;
        let w: Vec<f64> = (0..n_records)
            .map(|i| 10f64.powf(-2.0 + 4.0 * ((i * 37) % n_records) as f64 / n_records as f64))
            .collect();
        let h: Vec<f64> = w
            .iter()
            .zip(0..)
            .map(|(w, i)| w.ln() + (i as f64).sin())
            .collect();
        let weighted_mean = |s: &dyn Fn(f64) -> f64| {
            let num: f64 = w.iter().zip(&h).map(|(w, h)| s(*w) * w * h).sum();
            num / w.iter().map(|w| s(*w) * w).sum::<f64>()
        };
        let exact = weighted_mean(&|_| 1.0);
        let heaviest = (0..n_records)
            .max_by(|&a, &b| w[a].total_cmp(&w[b]))
            .unwrap();
        for alpha in [0.0, 0.5, 1.0] {
            let picker = RecordPicker::new(w.par_iter().copied(), alpha);
            let mut rng = Pcg64Mcg::seed_from_u64(5);
            let mut picks = Vec::new();
            picker.pick(200_000, &mut rng, &mut picks);
            let n = picks.len() as f64;
            let a: Vec<(f64, f64)> = picks
                .iter()
                .map(|&i| {
                    let weight = w[i] / picker.scale(w[i]);
                    (weight * h[i], weight)
                })
                .collect();
            let (num, den) = a.iter().fold((0.0, 0.0), |(x, y), (p, q)| (x + p, y + q));
            let ratio = num / den;
            let mean_den = den / n;
            let var = a.iter().map(|(p, q)| (p - ratio * q).powi(2)).sum::<f64>() / (n - 1.0);
            let se = (var / n).sqrt() / mean_den;
            assert!(
                (ratio - exact).abs() < 4.0 * se,
                "α = {alpha}: {ratio} against {exact} (standard error {se})"
            );
            if alpha > 0.0 {
                let uncorrected = weighted_mean(&|w| w.powf(alpha));
                assert!(
                    (uncorrected - exact).abs() > 10.0 * se,
                    "α = {alpha}: test too weak"
                );
            }
            // The heaviest record is drawn with probability w^α / Σ w^α (5 binomial
            // standard errors).
            let p = w[heaviest].powf(alpha) / w.iter().map(|w| w.powf(alpha)).sum::<f64>();
            let hits = picks.iter().filter(|&&i| i == heaviest).count() as f64;
            let sd = (n * p * (1.0 - p)).sqrt();
            assert!(
                (hits - n * p).abs() < 5.0 * sd,
                "α = {alpha}: {hits} against {}",
                n * p
            );
        }
    }

    #[test]
    fn records_without_a_finite_positive_weight_are_never_drawn() {
        let w = [0.0, f64::NAN, 2.0, f64::INFINITY, -1.0, 1.0];
        let picker = RecordPicker::new(w.par_iter().copied(), 0.5);
        let mut rng = Pcg64Mcg::seed_from_u64(1);
        let mut counts = [0usize; 6];
        let mut picks = Vec::new();
        picker.pick(30000, &mut rng, &mut picks);
        for i in picks {
            counts[i] += 1;
        }
        assert_eq!([counts[0], counts[1], counts[3], counts[4]], [0, 0, 0, 0]);
        // √2 : 1, within 5 binomial standard errors.
        let p = 2f64.sqrt() / (2f64.sqrt() + 1.0);
        let sd = (30000.0 * p * (1.0 - p)).sqrt();
        assert!(
            (counts[2] as f64 - 30000.0 * p).abs() < 5.0 * sd,
            "{counts:?}"
        );
        // Nothing drawable: uniform, as α = 0.
        let none = RecordPicker::new([0.0, f64::NAN].into_par_iter(), 0.5);
        assert!(none.table.is_none());
        assert_eq!(none.scale(3.0), 1.0);
    }

    /// Each index's probability read off the table (its own column's `keep` plus what other
    /// columns give it) is its share of the weights, to rounding.
    #[test]
    fn the_alias_table_holds_the_weights_exactly() {
        let mut rng = Pcg64Mcg::seed_from_u64(9);
        for n in [1, 2, 3, 17, 1000] {
            let s: Vec<f64> = (0..n)
                .map(|i| {
                    if i % 7 == 3 {
                        0.0
                    } else {
                        10f64.powf(rng.random_range(-4.0..4.0))
                    }
                })
                .collect();
            let table = alias_table(&s).expect("positive weights");
            let mut p = vec![0.0; n];
            for (j, c) in table.iter().enumerate() {
                p[j] += c.keep;
                p[c.alias as usize] += 1.0 - c.keep;
            }
            let total: f64 = s.iter().sum();
            for i in 0..n {
                let exact = s[i] / total;
                assert!((p[i] / n as f64 - exact).abs() < 1e-12, "n = {n}, i = {i}");
            }
        }
        assert!(alias_table(&[0.0, 0.0]).is_none());
        assert!(alias_table(&[]).is_none());
    }
}
