//! The 2-D experiment of Müller et al. 2019 (section 2.3, Figure 3): normalizing flows fitted to
//! densities given by images, to compare coupling transforms.
//!
//! - [`target`]: an image (PNG/JPEG) or a built-in pattern as a bilinear density on \[0,1\]².
//! - [`builtin`]: the built-in targets, generated in code.
//! - [`grid`]: the exact KL divergence and estimator variance of a flow, on a midpoint grid.
//! - [`mod@fit`]: training with the KL gradient on uniform (or the flow's own) samples.
//! - [`figure`]: false-colour densities, learning curves and the comparison montage as PNG.

pub mod builtin;
pub mod figure;
pub mod fit;
pub mod grid;
pub mod target;

pub use builtin::Builtin;
pub use fit::{fit, model_label, CurvePoint, Fit, FitConfig, FitSummary, Sampling};
pub use grid::{Grid, GridMetrics};
pub use target::Target;
