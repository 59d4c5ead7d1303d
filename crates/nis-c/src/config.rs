//! The JSON config `nis_create` reads: the method, the dimension, the seed, the integrand's
//! component count, whether the callback may run concurrently, and each method's own settings
//! (partial: missing fields keep their defaults). Unknown fields are errors at every level.

use nis::integrate::nis::NisConfig;
use nis::integrate::uniform::PlainMcConfig;
use nis::integrate::vegas::VegasConfig;
use nis::integrate::{Method, Settings, TrainOn};
use serde::Deserialize;

/// `{"method": "nis", "dim": 4, "seed": 1, "nis": {"batch": 2048}}` and friends.
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct Config {
    /// `"nis"`, `"vegas"` or `"uniform"`.
    pub method: Method,
    /// The dimension of [0, 1]^dim.
    pub dim: usize,
    /// Seeds every method (for NIS the flow's initialisation and the random streams); without
    /// it each method's section keeps its own `seed` (default 0).
    #[serde(default)]
    pub seed: Option<u64>,
    /// Values per point the callback writes (default 1; `nis_integrate_vector` overrides it).
    #[serde(default = "one")]
    pub components: usize,
    /// Whether the callback may be called from several threads at once (default false).
    #[serde(default)]
    pub concurrent_callback: bool,
    /// What an adaptive method adapts to: `{"component": j}` or `"sum_abs"` (default component 0).
    #[serde(default)]
    pub train_on: Option<TrainOn>,
    #[serde(default)]
    pub nis: NisConfig,
    #[serde(default)]
    pub vegas: VegasConfig,
    #[serde(default)]
    pub uniform: PlainMcConfig,
}

fn one() -> usize {
    1
}

impl Config {
    /// The library's settings this config stands for.
    pub(crate) fn settings(&self) -> Settings {
        let mut s = Settings {
            nis: self.nis.clone(),
            vegas: self.vegas.clone(),
            uniform: self.uniform.clone(),
        };
        if let Some(seed) = self.seed {
            s = s.seed(seed);
        }
        if let Some(t) = self.train_on {
            s = s.train_on(t);
        }
        s
    }
}
