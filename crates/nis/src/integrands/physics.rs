//! Integrands from i-flow's test script (Gao, Isaacson, Krause 2020, `iflow_test.py`): the
//! entangled circles and the Feynman-parametrised scalar one-loop triangle and box.

use super::Builtin;

/// Two thin circles whose thickness and height change along them (i-flow Eq. 14).
///
/// The second term carries (1 − x₂)^a as in the i-flow paper and `../shared/INTEGRANDS.md`; the
/// published script has 1 − x₂^a there instead, whose integral is 0.0294, not the quoted
/// 0.0136848(1) (checked by a 4000² midpoint grid, which gives 0.0136848 for this form).
pub fn entangled_circles() -> Builtin {
    let (dx, dy, r, w, a) = (0.4, 0.6, 0.25, 250.0, 3.0);
    Builtin {
        name: String::new(),
        dim: 2,
        exact: 0.013_684_8,
        exact_err: 1e-7,
        source: "i-flow Eq. 14; value 0.0136848(1) quoted there (numerical)",
        f: Box::new(move |x| {
            let (x1, x2) = (x[0], x[1]);
            x2.powf(a) * (-w * ((x2 - dy).powi(2) + (x1 - dx).powi(2) - r * r).abs()).exp()
                + (1.0 - x2).powf(a)
                    * (-w * ((x2 - 1.0 + dy).powi(2) + (x1 - 1.0 + dx).powi(2) - r * r).abs()).exp()
        }),
    }
}

/// Scalar one-loop triangle: external masses² (0, 0, 125²), internal 175² each.
pub fn triangle() -> Builtin {
    let ext = [0.0, 0.0, 125.0f64 * 125.0];
    let int = [175.0f64 * 175.0; 3];
    let f = move |t1: f64, t2: f64, p: [usize; 3]| {
        -ext[p[0]] * t1 - ext[p[1]] * t1 * t2 - ext[p[2]] * t2
            + (1.0 + t1 + t2) * (t1 * int[p[0]] + t2 * int[p[1]] + int[p[2]])
    };
    Builtin {
        name: String::new(),
        dim: 2,
        exact: -1.707_216_825_377_675e-5,
        exact_err: 0.0,
        source: "i-flow TriangleIntegral; value −1.70721682537767509e-5 quoted there (f64-rounded)",
        f: Box::new(move |x| {
            let num = 1.0 / (1.0 + x[0] + x[1]);
            -num / f(x[0], x[1], [1, 2, 0])
                - num / f(x[0], x[1], [2, 0, 1])
                - num / f(x[0], x[1], [0, 1, 2])
        }),
    }
}

/// Scalar one-loop box: s₁₂ = 130², s₂₃ = −130²/2, external masses² (0, 0, 0, 125²), internal
/// 175² each.
pub fn box_integral() -> Builtin {
    let ext = [0.0, 0.0, 0.0, 125.0f64 * 125.0];
    let int = [175.0f64 * 175.0; 4];
    let (s12, s23) = (130.0f64 * 130.0, -130.0f64 * 130.0 / 2.0);
    let f = move |s12: f64, s23: f64, t: &[f64], p: [usize; 4]| {
        let (t1, t2, t3) = (t[0], t[1], t[2]);
        -s12 * t2
            - s23 * t1 * t3
            - ext[p[0]] * t1
            - ext[p[1]] * t1 * t2
            - ext[p[2]] * t2 * t3
            - ext[p[3]] * t3
            + (1.0 + t1 + t2 + t3) * (t1 * int[p[0]] + t2 * int[p[1]] + t3 * int[p[2]] + int[p[3]])
    };
    Builtin {
        name: String::new(),
        dim: 3,
        exact: 1.936_964_023_868_193e-10,
        exact_err: 0.0,
        source: "i-flow BoxIntegral; value 1.93696402386819321e-10 quoted there (f64-rounded)",
        f: Box::new(move |x| {
            f(s23, s12, x, [1, 2, 3, 0]).powi(-2)
                + f(s12, s23, x, [2, 3, 0, 1]).powi(-2)
                + f(s23, s12, x, [3, 0, 1, 2]).powi(-2)
                + f(s12, s23, x, [0, 1, 2, 3]).powi(-2)
        }),
    }
}
