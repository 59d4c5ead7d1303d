//! The check an estimator runs on every batch a channel sampled: shapes, the points inside the
//! cube, and the channel's own density finite and positive there (a point a channel can produce
//! has g > 0; g = 0, negative or NaN there means `density` is not the density of `sample`).

use crate::error::{Error, Result};

/// The number of points in a batch of `len` coordinates of dimension `dim`, or the error that
/// says the batch is not whole points.
pub(crate) fn points(what: &'static str, dim: usize, len: usize) -> Result<usize> {
    if dim == 0 {
        return Err(Error::Config("a channel needs dimension ≥ 1".into()));
    }
    if len % dim != 0 {
        return Err(Error::Dimension {
            what,
            expected: len.next_multiple_of(dim),
            got: len,
        });
    }
    Ok(len / dim)
}

/// The error of a slice of the wrong length.
pub(crate) fn same_len(what: &'static str, expected: usize, got: usize) -> Result<()> {
    if expected == got {
        Ok(())
    } else {
        Err(Error::Dimension {
            what,
            expected,
            got,
        })
    }
}

/// Checks a batch that channel `channel` (its index, for the message) sampled: `u` and `x` are
/// n × `dim` (row-major), `g` holds the channel's own density at the n points of `x`. Every x
/// must lie in [0, 1]^d and every g be finite and > 0; the first violation is an
/// [`Error::Channel`] naming the channel, the point and the value.
///
/// ```
/// use nis::channels::check_sampled;
/// assert!(check_sampled(0, 1, &[0.5], &[0.25], &[1.0]).is_ok());
/// let e = check_sampled(1, 1, &[0.5], &[1.5], &[1.0]).unwrap_err();
/// assert!(e.to_string().contains("channel 1"));
/// ```
pub fn check_sampled(channel: usize, dim: usize, u: &[f64], x: &[f64], g: &[f64]) -> Result<()> {
    let n = points("channel sample u", dim, u.len())?;
    same_len("channel sample x", u.len(), x.len())?;
    same_len("channel density g", n, g.len())?;
    for (i, (p, &gi)) in x.chunks_exact(dim).zip(g).enumerate() {
        let at = |reason: String| Error::Channel {
            channel,
            point: p.to_vec(),
            reason: format!(
                "{reason} (point {i} of the batch, from u = {:?})",
                &u[i * dim..(i + 1) * dim]
            ),
        };
        if let Some(j) = p.iter().position(|v| !(0.0..=1.0).contains(v)) {
            return Err(at(format!(
                "sample left the unit cube: coordinate {j} is {}",
                p[j]
            )));
        }
        if !(gi.is_finite() && gi > 0.0) {
            return Err(at(format!(
                "its density there is {gi}; at a point it sampled it must be finite and > 0"
            )));
        }
    }
    Ok(())
}
