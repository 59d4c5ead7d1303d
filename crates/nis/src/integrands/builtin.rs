//! What the suite is made of: a [`Builtin`] integrand with its exact value and source, and a
//! [`SuiteEntry`] of the listing. The multi-channel examples (`channels::examples`) build theirs
//! from here too, so they need not import the suite (which lists them).

use crate::error::Result;
use crate::integrate::Integrand;

/// A point function of the suite.
type PointFn = Box<dyn Fn(&[f64]) -> f64 + Send + Sync>;

/// A built-in integrand with its exact value.
pub struct Builtin {
    /// Name as the CLI knows it.
    pub name: String,
    /// The dimension it is defined in.
    pub dim: usize,
    /// The exact integral over the unit hypercube.
    pub exact: f64,
    /// Uncertainty of `exact` where it is known only numerically (0 if exact).
    pub exact_err: f64,
    /// Where the integrand and its value come from.
    pub source: &'static str,
    pub(super) f: PointFn,
}

impl std::fmt::Debug for Builtin {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{} (d = {}, exact {})", self.name, self.dim, self.exact)
    }
}

impl Builtin {
    /// A built-in from its point function (the name is set by `by_name`).
    pub(crate) fn from_fn(
        dim: usize,
        exact: f64,
        exact_err: f64,
        source: &'static str,
        f: impl Fn(&[f64]) -> f64 + Send + Sync + 'static,
    ) -> Builtin {
        Builtin {
            name: String::new(),
            dim,
            exact,
            exact_err,
            source,
            f: Box::new(f),
        }
    }

    /// f(x) at one point.
    pub fn value(&self, x: &[f64]) -> f64 {
        (self.f)(x)
    }
}

impl Integrand for Builtin {
    fn dim(&self) -> Option<usize> {
        Some(self.dim)
    }
    fn eval_batch(&self, x: &[f64], dim: usize, out: &mut [f64]) -> Result<()> {
        (&*self.f).eval_batch(x, dim, out)
    }
}

/// One entry of the suite listing: a name, the dimensions it is run in, a description.
pub struct SuiteEntry {
    /// Name as `by_name` knows it.
    pub name: &'static str,
    /// The dimensions the benchmark runs it in.
    pub dims: &'static [usize],
    /// One line for `nis list`.
    pub description: &'static str,
}
