//! Building a method by name: every method's settings ([`Settings`]) and the factories
//! [`integrator`] and [`rival`], above the methods they build.

use serde::{Deserialize, Serialize};

use super::race::Rival;
use super::{nis, uniform, vegas, Integrator, Method, TrainOn};
use crate::error::Result;

/// The settings of every method, for building one by name with [`integrator`].
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Settings {
    /// Used when the method is [`Method::Nis`].
    pub nis: nis::NisConfig,
    /// Used when the method is [`Method::Vegas`].
    pub vegas: vegas::VegasConfig,
    /// Used when the method is [`Method::Uniform`].
    pub uniform: uniform::PlainMcConfig,
}

impl Settings {
    /// Seeds every method (for NIS both the flow's initialisation and the sampling).
    pub fn seed(mut self, seed: u64) -> Settings {
        self.nis.seed = seed;
        self.nis.flow.seed = seed;
        self.vegas.seed = seed;
        self.uniform.seed = seed;
        self
    }

    /// The seed `method` runs with.
    pub fn seed_of(&self, method: Method) -> u64 {
        match method {
            Method::Nis => self.nis.seed,
            Method::Vegas => self.vegas.seed,
            Method::Uniform => self.uniform.seed,
        }
    }

    /// Makes every adaptive method adapt to `train_on`.
    pub fn train_on(mut self, train_on: TrainOn) -> Settings {
        self.nis.train_on = train_on;
        self.vegas.train_on = train_on;
        self
    }
}

/// Builds the integrator of `method` in `dim` dimensions from its part of `settings`.
///
/// ```
/// use nis::integrate::{integrator, Method, Settings};
/// let mut integ = integrator("uniform".parse::<Method>()?, 3, &Settings::default().seed(7))?;
/// let r = integ.integrate(&|x: &[f64]| x[0] + x[1] + x[2], 10_000)?;
/// assert!((r.value - 1.5).abs() < 5.0 * r.std_err);
/// # Ok::<(), nis::Error>(())
/// ```
pub fn integrator(method: Method, dim: usize, settings: &Settings) -> Result<Box<dyn Integrator>> {
    Ok(match method {
        Method::Nis => {
            let mut nis = nis::NisIntegrator::new(dim, settings.nis.clone())?;
            nis.set_rival(rival);
            Box::new(nis)
        }
        Method::Vegas => Box::new(vegas::Vegas::new(dim, settings.vegas.clone())?),
        Method::Uniform => Box::new(uniform::PlainMc::new(dim, settings.uniform.clone())?),
    })
}

/// The rival a learning method races to a target (`race.rs`), handed to the NIS integrators
/// [`integrator`] builds: VEGAS+ with its defaults but `seed` and `train_on`.
fn rival(dim: usize, seed: u64, train_on: TrainOn) -> Result<Box<dyn Rival>> {
    let config = vegas::VegasConfig {
        seed,
        train_on,
        ..vegas::VegasConfig::default()
    };
    Ok(Box::new(vegas::Vegas::new(dim, config)?))
}
