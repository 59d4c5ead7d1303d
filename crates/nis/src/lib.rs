//! # nis: neural importance sampling
//!
//! Monte Carlo integration on the unit hypercube whose sampling density is a normalizing flow
//! learned from the integrand itself (Müller, McWilliams, Rousselle, Gross, Novák 2019).

pub mod error;
pub mod spline;

pub use error::{Error, Result};
