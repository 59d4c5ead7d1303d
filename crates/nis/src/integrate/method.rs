//! The integration methods by name ([`Method`]), for the front ends and for a result to say
//! which method made it. Imports nothing of `integrate`.

use std::str::FromStr;

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};

/// The integration methods, by name for the front ends (`"nis"`, `"vegas"`, `"uniform"`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Method {
    /// Neural importance sampling: [`NisIntegrator`](super::nis::NisIntegrator).
    Nis,
    /// VEGAS+: [`Vegas`](super::vegas::Vegas).
    Vegas,
    /// Plain Monte Carlo with uniform points: [`PlainMc`](super::uniform::PlainMc).
    Uniform,
}

impl Method {
    /// Every method, in the order front ends list them.
    pub const ALL: [Method; 3] = [Method::Nis, Method::Vegas, Method::Uniform];

    /// The name `FromStr` reads.
    pub fn name(self) -> &'static str {
        match self {
            Method::Nis => "nis",
            Method::Vegas => "vegas",
            Method::Uniform => "uniform",
        }
    }

    /// A short label for tables ("vegas+" for VEGAS+).
    pub fn label(self) -> &'static str {
        match self {
            Method::Vegas => "vegas+",
            m => m.name(),
        }
    }
}

impl std::fmt::Display for Method {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Method {
    type Err = Error;
    fn from_str(s: &str) -> Result<Method> {
        Method::ALL
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or_else(|| {
                Error::Config(format!(
                    "unknown integration method {s:?}: expected nis, vegas or uniform"
                ))
            })
    }
}
