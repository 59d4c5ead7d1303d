//! The shares of VEGAS+'s result iterations in its estimate, each fixed from the variances of
//! the iterations before it, so that the estimate stays unbiased (module docs of `vegas`).

/// The fastest fall of the variance per iteration (smallest ratio) the shares extrapolate.
const MAX_FALL: f64 = 0.25;
/// Iterations the trend of the variance is fitted over.
const TREND_SPAN: usize = 5;

/// How a share reads the trend of the variances before it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum Trend {
    /// The least-squares fall per iteration.
    Fitted,
    /// One standard error of that fit steeper: for the first result iteration, whose share rests
    /// on the warm-up's variances alone.
    Cautious,
}

/// The share a_i of the next result iteration in the final estimate Σ a_i·I_i, from the
/// variances of the iterations before it only, so E[a_i·I_i] = E[a_i]·I and the estimate is
/// unbiased; the shares add up to exactly one (the last takes what is `remaining`).
///
/// The package weighs iterations by their inverse variances, which matters because the map keeps
/// improving: on a sharp peak the variance keeps falling over the result iterations, and equal
/// shares are far worse than inverse-variance ones (docs/results/integration.md). Here the fall is
/// extrapolated: with ρ the ratio per iteration fitted to the last few (clamped to
/// [`MAX_FALL`], 1) the `left` iterations are expected to have variances ∝ ρ^m, so inverse-variance
/// shares of what remains give this one c = 1/Σ_{m<left} ρ^(−m).
///
/// A share that is too large costs far more than one that is too small: given to an iteration
/// whose variance turns out k times the last ones', it adds up to k/left² of theirs, while one too
/// small only leaves the others to carry its points. The first result iteration is where that
/// happens: its share rests on the warm-up alone, whose variances can be noise around no trend
/// before they start to fall (gauss d = 16: warm-up variances with no trend, then a steep fall
/// over the result iterations; the fitted flat trend gave the first one too large a share and σ²
/// far above the inverse-variance optimum on most seeds).
/// [`Trend::Cautious`] takes the fall one standard error of the slope steeper, so noise reads as
/// a possible fall; after the first, the result iterations' own variances are in the fit.
pub(super) fn next_share(remaining: f64, left: usize, history: &[f64], trend: Trend) -> f64 {
    if left <= 1 {
        return remaining;
    }
    // ρ from the least-squares slope of ln σ² over the last (up to) five iterations: the ratio of
    // two noisy variances would let one heavy-tailed iteration reset the trend.
    let recent: Vec<(f64, f64)> = history
        .iter()
        .rev()
        .take(TREND_SPAN)
        .enumerate()
        .filter(|(_, v)| **v > 0.0 && v.is_finite())
        .map(|(j, v)| (-(j as f64), v.ln()))
        .collect();
    let rho = if recent.len() >= 3 {
        let m = recent.len() as f64;
        let (mx, my) = recent
            .iter()
            .fold((0.0, 0.0), |(a, b), (x, y)| (a + x / m, b + y / m));
        let (sxy, sxx) = recent.iter().fold((0.0, 0.0), |(a, b), (x, y)| {
            (a + (x - mx) * (y - my), b + (x - mx) * (x - mx))
        });
        let slope = sxy / sxx;
        let steeper = match trend {
            Trend::Fitted => 0.0,
            Trend::Cautious => {
                let sse: f64 = recent
                    .iter()
                    .map(|(x, y)| (my + slope * (x - mx) - y).powi(2))
                    .sum();
                (sse / (m - 2.0) / sxx).sqrt()
            }
        };
        (slope - steeper).exp()
    } else {
        1.0
    };
    let rho = if rho.is_finite() {
        rho.clamp(MAX_FALL, 1.0)
    } else {
        1.0
    };
    let sum: f64 = (0..left).map(|m| rho.powi(-(m as i32))).sum();
    remaining / sum
}
