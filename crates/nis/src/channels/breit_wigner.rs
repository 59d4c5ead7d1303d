//! The Breit–Wigner mapping of event generators: a variable s (an invariant mass squared, or any
//! coordinate with a Cauchy-shaped peak) drawn between limits with the density
//! ∝ 1/((s − c)² + γ²), by s = c + γ·tan(y), y uniform between the limits' arctangents. For a
//! resonance of mass M and width Γ, c = M² and γ = MΓ (e.g. the MadGraph/MadEvent and Sherpa
//! phase-space generators; Kleiss & Pittau 1994 use it as their example channel).

use crate::error::{Error, Result};

/// A Cauchy density ∝ 1/((s − c)² + γ²) truncated to [lo, hi], with its inverse CDF.
///
/// ```
/// use nis::channels::BreitWigner;
/// // The Z in the invariant mass squared, between 60² and 120² GeV².
/// let z = BreitWigner::resonance(91.1876, 2.4952, 60.0f64.powi(2), 120.0f64.powi(2)).unwrap();
/// let s = z.sample(0.5);
/// assert!((z.cdf(s) - 0.5).abs() < 1e-12);
/// assert!(z.pdf(s) > 0.0);
/// ```
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BreitWigner {
    centre: f64,
    half_width: f64,
    lo: f64,
    hi: f64,
    y_lo: f64,
    y_span: f64,
}

/// atan(a) − atan(b) without the cancellation of two arctangents near the same asymptote.
fn atan_diff(a: f64, b: f64) -> f64 {
    if a * b > 0.0 {
        // Same sign: atan(a) − atan(b) = atan((a − b)/(1 + ab)), exact for ab > −1.
        ((a - b) / (1.0 + a * b)).atan()
    } else {
        a.atan() - b.atan()
    }
}

impl BreitWigner {
    /// The density ∝ 1/((s − centre)² + half_width²) on [lo, hi]. Errors: a half-width that is
    /// not finite and > 0, limits that are not finite with lo < hi, a centre not finite.
    pub fn new(centre: f64, half_width: f64, lo: f64, hi: f64) -> Result<BreitWigner> {
        if !(half_width.is_finite() && half_width > 0.0 && centre.is_finite()) {
            return Err(Error::Config(format!(
                "a Breit–Wigner needs a finite centre and half-width > 0, not {centre}, {half_width}"
            )));
        }
        if !(lo.is_finite() && hi.is_finite() && lo < hi) {
            return Err(Error::Config(format!(
                "a Breit–Wigner needs finite limits lo < hi, not [{lo}, {hi}]"
            )));
        }
        Ok(BreitWigner::unchecked(centre, half_width, lo, hi))
    }

    /// A resonance of mass `mass` and width `width` in the mass squared s ∈ [lo, hi]: centre M²,
    /// half-width MΓ.
    pub fn resonance(mass: f64, width: f64, lo: f64, hi: f64) -> Result<BreitWigner> {
        BreitWigner::new(mass * mass, mass * width, lo, hi)
    }

    /// `new` for arguments the caller has checked (lo < hi, half-width > 0).
    pub(crate) fn unchecked(centre: f64, half_width: f64, lo: f64, hi: f64) -> BreitWigner {
        let (a, b) = ((lo - centre) / half_width, (hi - centre) / half_width);
        BreitWigner {
            centre,
            half_width,
            lo,
            hi,
            y_lo: a.atan(),
            y_span: atan_diff(b, a),
        }
    }

    /// The point at the quantile u ∈ [0, 1] (clamped into [lo, hi] against rounding).
    pub fn sample(&self, u: f64) -> f64 {
        let s = self.centre + self.half_width * (self.y_lo + u * self.y_span).tan();
        s.clamp(self.lo, self.hi)
    }

    /// The quantile of s (0 below lo, 1 above hi): the inverse of [`BreitWigner::sample`].
    pub fn cdf(&self, s: f64) -> f64 {
        if s <= self.lo {
            return 0.0;
        }
        if s >= self.hi {
            return 1.0;
        }
        let (a, b) = (
            (s - self.centre) / self.half_width,
            (self.lo - self.centre) / self.half_width,
        );
        (atan_diff(a, b) / self.y_span).clamp(0.0, 1.0)
    }

    /// The density at s (0 outside [lo, hi]).
    pub fn pdf(&self, s: f64) -> f64 {
        if !(self.lo..=self.hi).contains(&s) {
            return 0.0;
        }
        let t = (s - self.centre) / self.half_width;
        1.0 / (self.half_width * self.y_span * (1.0 + t * t))
    }

    /// The limits [lo, hi].
    pub fn limits(&self) -> (f64, f64) {
        (self.lo, self.hi)
    }
}
