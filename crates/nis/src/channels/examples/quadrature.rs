//! Adaptive Gauss–Kronrod quadrature (the 7-point Gauss, 15-point Kronrod pair of QUADPACK's
//! QK15, Piessens et al. 1983) with global bisection of the worst interval: the exact values of
//! the multi-channel examples are 1-D and nested 2-D integrals of smooth but peaked functions.

/// The Kronrod nodes on [−1, 1] (positive half, the centre last); odd indices are Gauss nodes.
const XGK: [f64; 8] = [
    0.991_455_371_120_812_6,
    0.949_107_912_342_758_5,
    0.864_864_423_359_769_1,
    0.741_531_185_599_394_4,
    0.586_087_235_467_691_1,
    0.405_845_151_377_397_2,
    0.207_784_955_007_898_5,
    0.0,
];
/// The Kronrod weights of `XGK`.
const WGK: [f64; 8] = [
    0.022_935_322_010_529_22,
    0.063_092_092_629_978_55,
    0.104_790_010_322_250_18,
    0.140_653_259_715_525_92,
    0.169_004_726_639_267_9,
    0.190_350_578_064_785_4,
    0.204_432_940_075_298_9,
    0.209_482_141_084_727_83,
];
/// The Gauss weights of the nodes `XGK[1], XGK[3], XGK[5], XGK[7]`.
const WG: [f64; 4] = [
    0.129_484_966_168_869_7,
    0.279_705_391_489_276_7,
    0.381_830_050_505_118_9,
    0.417_959_183_673_469_4,
];

/// Most intervals one integral is split into.
const MAX_INTERVALS: usize = 4000;

/// The Kronrod estimate on [a, b] and its error estimate |K15 − G7|.
fn kronrod(f: &mut impl FnMut(f64) -> f64, a: f64, b: f64) -> (f64, f64) {
    let (c, h) = (0.5 * (a + b), 0.5 * (b - a));
    let fc = f(c);
    let (mut k, mut g) = (WGK[7] * fc, WG[3] * fc);
    for j in 0..7 {
        let v = f(c - h * XGK[j]) + f(c + h * XGK[j]);
        k += WGK[j] * v;
        if j % 2 == 1 {
            g += WG[j / 2] * v;
        }
    }
    (k * h, ((k - g) * h).abs())
}

/// ∫_a^b f with the estimated error below max(`rel_tol`·|∫f|, 1e-300), bisecting the interval
/// of largest error; returns the value and the error estimate (which is larger than asked for
/// only if [`MAX_INTERVALS`] were not enough).
pub(crate) fn integrate(mut f: impl FnMut(f64) -> f64, a: f64, b: f64, rel_tol: f64) -> (f64, f64) {
    let (v, e) = kronrod(&mut f, a, b);
    let mut parts = vec![(a, b, v, e)];
    let (mut total, mut err) = (v, e);
    while err > (rel_tol * total.abs()).max(1e-300) && parts.len() < MAX_INTERVALS {
        let worst = (0..parts.len())
            .max_by(|&i, &j| parts[i].3.total_cmp(&parts[j].3))
            .unwrap_or(0);
        let (lo, hi, _, _) = parts.swap_remove(worst);
        let mid = 0.5 * (lo + hi);
        if !(lo < mid && mid < hi) {
            break;
        }
        parts.push((lo, mid, 0.0, 0.0));
        parts.push((mid, hi, 0.0, 0.0));
        let n = parts.len();
        for p in &mut parts[n - 2..] {
            let (v, e) = kronrod(&mut f, p.0, p.1);
            (p.2, p.3) = (v, e);
        }
        // Re-summed each time: the error estimates are not rounded away by cancellation.
        total = parts.iter().map(|p| p.2).sum();
        err = parts.iter().map(|p| p.3).sum();
    }
    (total, err)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quadrature_is_exact_for_polynomials_and_converges_on_peaks_and_endpoint_roots() {
        // Weights: Σ = 2 on [−1, 1] for both rules.
        let k: f64 = 2.0 * WGK[..7].iter().sum::<f64>() + WGK[7];
        let g: f64 = 2.0 * WG[..3].iter().sum::<f64>() + WG[3];
        assert!(
            (k - 2.0).abs() < 1e-15 && (g - 2.0).abs() < 1e-15,
            "{k} {g}"
        );
        // K15 integrates degree 22 exactly, one interval.
        let (v, _) = kronrod(&mut |x: f64| x.powi(22), 0.0, 1.0);
        assert!((v - 1.0 / 23.0).abs() < 1e-15);
        // A narrow Cauchy peak and a √x endpoint.
        let (v, e) = integrate(|x| 1e-3 / ((x - 0.3).powi(2) + 1e-6), 0.0, 1.0, 1e-13);
        let want = (0.7f64 / 1e-3).atan() + (0.3f64 / 1e-3).atan();
        assert!(
            (v / want - 1.0).abs() < 1e-12 && e < 1e-12 * want,
            "{v} {want} {e}"
        );
        let (v, _) = integrate(f64::sqrt, 0.0, 1.0, 1e-13);
        assert!((v - 2.0 / 3.0).abs() < 1e-12, "{v}");
    }
}
