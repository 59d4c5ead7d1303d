//! How a call's evaluations are shared between the parts: Neyman's allocation by each part's σ,
//! in whole numbers that add up to the budget.

/// Neyman's allocation: each part's share of the points, σ_p/Σσ (equal shares when every σ is 0).
pub(super) fn neyman(sd: &[f64]) -> Vec<f64> {
    let total: f64 = sd.iter().sum();
    sd.iter()
        .map(|s| {
            if total > 0.0 {
                s / total
            } else {
                1.0 / sd.len() as f64
            }
        })
        .collect()
}

/// `total` evaluations in whole numbers by `shares` (summing to one), each part at least `floor`:
/// `floor` plus its share of the rest rounded down, and the units the rounding left to the parts
/// with the largest remainders, so that they add up to `total` (to more when the floors do).
pub(super) fn allocate(total: u64, floor: u64, shares: &[f64]) -> Vec<u64> {
    let spare = total.saturating_sub(floor * shares.len() as u64);
    let exact: Vec<f64> = shares.iter().map(|s| spare as f64 * s).collect();
    let mut n: Vec<u64> = exact.iter().map(|e| *e as u64).collect();
    let mut left = spare.saturating_sub(n.iter().sum());
    let mut by_remainder: Vec<usize> = (0..n.len()).collect();
    by_remainder.sort_by(|&i, &j| (exact[j] - n[j] as f64).total_cmp(&(exact[i] - n[i] as f64)));
    while left > 0 && !n.is_empty() {
        for &i in &by_remainder {
            if left == 0 {
                break;
            }
            n[i] += 1;
            left -= 1;
        }
    }
    n.iter().map(|n| floor + n).collect()
}
