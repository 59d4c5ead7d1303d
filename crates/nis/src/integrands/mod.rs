//! The built-in test suite: integrands on [0, 1]^d with exact values, each with its source
//! (docs/INTEGRANDS.md lists them with the derivations; every value is re-derived in the tests
//! below and in `correlated`'s).

pub(crate) mod builtin;
mod correlated;
mod physics;

use std::f64::consts::PI;

pub use self::builtin::{Builtin, SuiteEntry};
use crate::channels::examples;
pub use crate::channels::examples::MULTI_CHANNEL;
use crate::error::{Error, Result};

/// The suite the benchmark runs, with its dimensions; `by_name` also knows [`COSTLY`].
pub const SUITE: &[SuiteEntry] = &[
    SuiteEntry {
        name: "gauss",
        dims: &[2, 4, 8, 16],
        description: "normalised Gaussian at the centre, width α = 0.2 (i-flow)",
    },
    SuiteEntry {
        name: "gauss-sharp",
        dims: &[2, 4, 8, 16],
        description: "the same with α = 0.1",
    },
    SuiteEntry {
        name: "camel",
        dims: &[2, 4, 8, 16],
        description: "two Gaussians on the diagonal at 1/3 and 2/3, α = 0.2 (i-flow)",
    },
    SuiteEntry {
        name: "camel-sharp",
        dims: &[2, 4, 8, 16],
        description: "the same with α = 0.1 (VEGAS documentation)",
    },
    SuiteEntry {
        name: "circles",
        dims: &[2],
        description: "two entangled thin circles (i-flow Eq. 14)",
    },
    SuiteEntry {
        name: "annulus",
        dims: &[2],
        description: "indicator of 0.2 < |x − ½| < 0.45 (i-flow)",
    },
    SuiteEntry {
        name: "triangle",
        dims: &[2],
        description: "scalar one-loop triangle, Feynman-parametrised (i-flow; negative)",
    },
    SuiteEntry {
        name: "box",
        dims: &[3],
        description: "scalar one-loop box, Feynman-parametrised (i-flow)",
    },
    SuiteEntry {
        name: "product-peak",
        dims: &[4, 8],
        description: "Genz product peak, c = 10",
    },
    SuiteEntry {
        name: "corner-peak",
        dims: &[4, 8],
        description: "Genz corner peak, c = 1",
    },
    SuiteEntry {
        name: "oscillatory",
        dims: &[2, 4],
        description: "Genz oscillatory, changes sign",
    },
    SuiteEntry {
        name: "sphere",
        dims: &[2, 4, 8],
        description: "volume of the ball of radius 0.45 at the centre",
    },
    SuiteEntry {
        name: "product",
        dims: &[2, 4, 8, 16],
        description: "Π 2x_i (MadNIS documentation)",
    },
    SuiteEntry {
        name: "gauss-diagonal",
        dims: &[2, 4, 8],
        description: "Gaussian at the centre elongated along the diagonal (non-separable)",
    },
    SuiteEntry {
        name: "peaks",
        dims: &[2, 4, 8],
        description: "four Gaussian peaks, α = 0.05, at scattered off-diagonal centres",
    },
    SuiteEntry {
        name: "ridge",
        dims: &[2, 4, 8],
        description: "a peak on a thin curved ridge x_i = g_i(x₁) (non-separable)",
    },
];

/// An integrand as slow as a matrix element: `camel` (α = 0.2) times a factor that costs
/// [`COSTLY_ROUNDS`] rounds of transcendental arithmetic per point (for scaling measurements).
pub const COSTLY: SuiteEntry = SuiteEntry {
    name: "costly",
    dims: &[4],
    description: "camel (α = 0.2) at ~100 µs per point (transcendental rounds; scaling tests)",
};

/// Rounds of [`costly`] in the built-in `costly`, chosen for about 100 µs per point on the
/// development machine (docs/results/scaling.md, "MPI: strong scaling on this machine", measures
/// it).
pub const COSTLY_ROUNDS: usize = 4_500;

/// `camel` (α = 0.2) in `dim` dimensions, each point also paying for `rounds` rounds of
/// transcendental arithmetic: the factor (1/R)·Σ_j (sin² t_j + cos² t_j) with t_j = Σx + 0.618·j
/// is 1 in exact arithmetic and within a few R·ε of it in floating point, so the integral is
/// camel's to ~1e-12 while every point costs what a real matrix element might.
pub fn costly(dim: usize, rounds: usize) -> Builtin {
    let camel = camel(dim, 0.2);
    let rounds = rounds.max(1);
    Builtin {
        name: format!("costly({rounds} rounds)"),
        dim,
        exact: camel.exact,
        exact_err: camel.exact * 1e-12,
        source: "camel (i-flow) × a factor equal to 1 that costs transcendental rounds",
        f: Box::new(move |x| {
            let t0: f64 = x.iter().sum();
            let mut s = 0.0;
            for j in 0..rounds {
                let (sin, cos) = (t0 + 0.618 * j as f64).sin_cos();
                s += sin * sin + cos * cos;
            }
            camel.value(x) * (s / rounds as f64)
        }),
    }
}

/// The i-flow Gaussian, normalised on R^d: (α√π)^(−d)·exp(−Σ(x_i − ½)²/α²).
fn gauss(dim: usize, alpha: f64) -> Builtin {
    let pre = (alpha * PI.sqrt()).powi(-(dim as i32));
    Builtin {
        name: format!("gauss(α={alpha})"),
        dim,
        exact: libm::erf(1.0 / (2.0 * alpha)).powi(dim as i32),
        exact_err: 0.0,
        source: "i-flow (Gao, Isaacson, Krause 2020), iflow_test.py; exact erf(1/(2α))^d",
        f: Box::new(move |x| {
            let r2: f64 = x.iter().map(|v| (v - 0.5) * (v - 0.5)).sum();
            pre * (-r2 / (alpha * alpha)).exp()
        }),
    }
}

/// The i-flow camel: two Gaussians at (⅓,…) and (⅔,…), each of mass ½ on R^d.
fn camel(dim: usize, alpha: f64) -> Builtin {
    let pre = 0.5 * (alpha * PI.sqrt()).powi(-(dim as i32));
    Builtin {
        name: format!("camel(α={alpha})"),
        dim,
        exact: (0.5 * (libm::erf(1.0 / (3.0 * alpha)) + libm::erf(2.0 / (3.0 * alpha))))
            .powi(dim as i32),
        exact_err: 0.0,
        source: "i-flow (Gao, Isaacson, Krause 2020); exact [½(erf(1/(3α)) + erf(2/(3α)))]^d",
        f: Box::new(move |x| {
            let (mut a, mut b) = (0.0, 0.0);
            for v in x {
                a += (v - 1.0 / 3.0) * (v - 1.0 / 3.0);
                b += (v - 2.0 / 3.0) * (v - 2.0 / 3.0);
            }
            pre * ((-a / (alpha * alpha)).exp() + (-b / (alpha * alpha)).exp())
        }),
    }
}

/// Genz product peak with c_i = 10 and peak positions w_i spread by the golden ratio.
fn product_peak(dim: usize) -> Builtin {
    let c = 10.0;
    let w: Vec<f64> = (0..dim)
        .map(|i| (0.3 + 0.618_034 * i as f64).fract())
        .collect();
    let exact = w
        .iter()
        .map(|&wi| c * ((c * (1.0 - wi)).atan() + (c * wi).atan()))
        .product();
    Builtin {
        name: "product-peak".into(),
        dim,
        exact,
        exact_err: 0.0,
        source:
            "Genz 1984, product peak Π 1/(c⁻² + (x_i − w_i)²); exact Π c(atan(c(1−w)) + atan(cw))",
        f: Box::new(move |x| {
            x.iter()
                .zip(&w)
                .map(|(v, wi)| 1.0 / (1.0 / (c * c) + (v - wi) * (v - wi)))
                .product()
        }),
    }
}

/// Genz corner peak (1 + Σ c x_i)^(−(d+1)) with c = 1.
fn corner_peak(dim: usize) -> Builtin {
    let c = 1.0;
    Builtin {
        name: "corner-peak".into(),
        dim,
        exact: corner_peak_exact(dim, c),
        exact_err: 0.0,
        source: "Genz 1984, corner peak; exact (1/(d!·Πc)) Σ_v (−1)^|v| / (1 + c·v)",
        f: Box::new(move |x| (1.0 + c * x.iter().sum::<f64>()).powi(-(x.len() as i32 + 1))),
    }
}

/// The corner peak's alternating vertex sum, grouped by |v| (all c equal) and summed with
/// Neumaier's compensation, which keeps the cancellation's rounding at a few ulps of the terms.
fn corner_peak_exact(dim: usize, c: f64) -> f64 {
    let (mut sum, mut comp) = (0.0f64, 0.0f64);
    let mut binom = 1.0f64;
    for k in 0..=dim {
        let term = if k % 2 == 0 { binom } else { -binom } / (1.0 + c * k as f64);
        let t = sum + term;
        comp += if sum.abs() >= term.abs() {
            (sum - t) + term
        } else {
            (term - t) + sum
        };
        sum = t;
        binom = binom * (dim - k) as f64 / (k + 1) as f64;
    }
    let fact: f64 = (1..=dim).map(|i| i as f64).product();
    (sum + comp) / (fact * c.powi(dim as i32))
}

/// Genz oscillatory cos(2πu + Σ a_i x_i); exact Re[e^{2πiu} Π (e^{i a_i} − 1)/(i a_i)].
fn oscillatory(dim: usize) -> Builtin {
    let u = 0.3;
    let a: Vec<f64> = (0..dim)
        .map(|i| 3.0 + 2.0 * i as f64 / dim as f64)
        .collect();
    // Π (e^{ia} − 1)/(ia) = Π (sin a/a + i(1 − cos a)/a), multiplied as complex numbers.
    let (mut re, mut im) = ((2.0 * PI * u).cos(), (2.0 * PI * u).sin());
    for &ai in &a {
        let (zr, zi) = (ai.sin() / ai, (1.0 - ai.cos()) / ai);
        (re, im) = (re * zr - im * zi, re * zi + im * zr);
    }
    Builtin {
        name: "oscillatory".into(),
        dim,
        exact: re,
        exact_err: 0.0,
        source: "Genz 1984, oscillatory; exact from the product of 1-D complex integrals",
        f: Box::new(move |x| {
            (2.0 * PI * u + x.iter().zip(&a).map(|(v, ai)| v * ai).sum::<f64>()).cos()
        }),
    }
}

/// Γ(d/2 + 1) for integer d.
fn gamma_half_plus_one(dim: usize) -> f64 {
    // Γ(n + 1) = n!; Γ(n + ½ + 1) = (n + ½)(n − ½)⋯(½)·√π.
    let mut g = if dim % 2 == 0 { 1.0 } else { PI.sqrt() };
    let mut t = dim as f64 / 2.0;
    while t > 0.0 {
        g *= t;
        t -= 1.0;
    }
    g
}

/// Builds a built-in integrand by name; `dim` defaults to the smallest of its suite dimensions.
pub fn by_name(name: &str, dim: Option<usize>) -> Result<Builtin> {
    let all = || SUITE.iter().chain([&COSTLY]).chain(MULTI_CHANNEL);
    let entry = all().find(|e| e.name == name).ok_or_else(|| {
        let names: Vec<&str> = all().map(|e| e.name).collect();
        Error::Config(format!(
            "unknown integrand {name:?}; built-ins: {}",
            names.join(", ")
        ))
    })?;
    let d = dim.unwrap_or(entry.dims[0]);
    let fixed = |want: usize| {
        if d == want {
            Ok(())
        } else {
            Err(Error::Dimension {
                what: "integrand dimension",
                expected: want,
                got: d,
            })
        }
    };
    if d == 0 || d > 64 {
        return Err(Error::Config(format!(
            "{name} is defined for 1 to 64 dimensions, not {d}"
        )));
    }
    let mut b = match name {
        "gauss" => gauss(d, 0.2),
        "gauss-sharp" => gauss(d, 0.1),
        "camel" => camel(d, 0.2),
        "camel-sharp" => camel(d, 0.1),
        "circles" => {
            fixed(2)?;
            physics::entangled_circles()
        }
        "annulus" => {
            fixed(2)?;
            Builtin {
                name: String::new(),
                dim: 2,
                exact: PI * (0.45 * 0.45 - 0.2 * 0.2),
                exact_err: 0.0,
                source: "i-flow ring; exact π(0.45² − 0.2²)",
                f: Box::new(|x| {
                    let r2 = (x[0] - 0.5).powi(2) + (x[1] - 0.5).powi(2);
                    if r2 > 0.2 * 0.2 && r2 < 0.45 * 0.45 {
                        1.0
                    } else {
                        0.0
                    }
                }),
            }
        }
        "triangle" => {
            fixed(2)?;
            physics::triangle()
        }
        "box" => {
            fixed(3)?;
            physics::box_integral()
        }
        "product-peak" => product_peak(d),
        "corner-peak" => corner_peak(d),
        "oscillatory" => oscillatory(d),
        "costly" => costly(d, COSTLY_ROUNDS),
        "sphere" => {
            let r: f64 = 0.45;
            Builtin {
                name: String::new(),
                dim: d,
                exact: r.powi(d as i32) * PI.powf(d as f64 / 2.0) / gamma_half_plus_one(d),
                exact_err: 0.0,
                source: "ZüNIS benchmarks; volume r^d π^(d/2)/Γ(d/2 + 1), r = 0.45",
                f: Box::new(move |x| {
                    let r2: f64 = x.iter().map(|v| (v - 0.5) * (v - 0.5)).sum();
                    if r2 < r * r {
                        1.0
                    } else {
                        0.0
                    }
                }),
            }
        }
        "product" => Builtin {
            name: String::new(),
            dim: d,
            exact: 1.0,
            exact_err: 0.0,
            source: "MadNIS documentation; Π 2x_i integrates to 1",
            f: Box::new(|x| x.iter().map(|v| 2.0 * v).product()),
        },
        "gauss-diagonal" | "peaks" | "ridge" if d < 2 => {
            return Err(Error::Config(format!(
                "{name} is defined for 2 to 64 dimensions, not {d}"
            )));
        }
        "gauss-pm" | "dalitz" | "resonances-4d" | "phase-space-8d" | "resonances-100" => {
            fixed(entry.dims[0])?;
            match name {
                "gauss-pm" => examples::gauss_pm(),
                "dalitz" => examples::dalitz(),
                "resonances-4d" => examples::resonances(),
                "resonances-100" => examples::many_resonances(),
                _ => examples::four_body(),
            }
        }
        "gauss-diagonal" => correlated::gauss_diagonal(d),
        "peaks" => correlated::peaks(d),
        "ridge" => correlated::ridge(d),
        _ => unreachable!("every suite entry is built above"),
    };
    b.name = name.to_string();
    Ok(b)
}

#[cfg(test)]
mod tests;
