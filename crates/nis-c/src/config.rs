//! The JSON config `nis_create` reads: the method, the dimension, the integrand's component
//! count and whether the callback may run concurrently, and the settings — `seed`, `train_on`
//! and each method's section — which the library's one reader of settings lays over the
//! defaults (`nis::integrate::Settings::patched`: partial sections keep the other defaults;
//! unknown fields are errors at every level, named by their path).

use nis::integrate::{Method, Settings};
use serde::Deserialize;
use serde_json::{Map, Value};

/// `{"method": "nis", "dim": 4, "seed": 1, "nis": {"batch": 2048}}` and friends.
#[derive(Clone, Debug, Deserialize)]
pub(crate) struct Config {
    /// `"nis"`, `"vegas"` or `"uniform"`.
    pub method: Method,
    /// The dimension of [0, 1]^dim.
    pub dim: usize,
    /// Values per point the callback writes (default 1; `nis_integrate_vector` overrides it).
    #[serde(default = "one")]
    pub components: usize,
    /// Whether the callback may be called from several threads at once (default false).
    #[serde(default)]
    pub concurrent_callback: bool,
    /// The rest: a patch of the library's default settings (`"seed"` seeds every method,
    /// `"train_on"` is `{"component": j}` or `"sum_abs"`, `"nis"`, `"vegas"`, `"uniform"`).
    #[serde(flatten)]
    pub settings: Map<String, Value>,
}

fn one() -> usize {
    1
}

impl Config {
    /// The library's settings this config stands for.
    pub(crate) fn settings(&self) -> nis::Result<Settings> {
        Settings::default().patched(Value::Object(self.settings.clone()))
    }
}
