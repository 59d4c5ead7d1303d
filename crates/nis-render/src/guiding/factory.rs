//! Guides by name: what `--guide NAME --guide-config JSON` means, in one place (pbrt's
//! `Create(name, parameters)`). A [`GuideSpec`] is parsed from a name and optional settings,
//! then builds its guide for a scene ([`AnyGuide`]); rendering with it is the render module's
//! ([`crate::render::render_any`]).

use crate::guiding::gmm::{Gmm, GmmConfig};
use crate::guiding::neural::{GuideLoss, NisGuide, NisGuideConfig};
use crate::guiding::ppg::{Ppg, PpgConfig};
use crate::guiding::{Guide, NoGuide};
use crate::scene::Scene;
use crate::Error;

/// A guide of any method, as [`GuideSpec::build`] makes it.
pub enum AnyGuide {
    /// Unidirectional path tracing.
    None(NoGuide),
    /// Practical path guiding.
    Ppg(Ppg),
    /// Gaussian mixtures.
    Gmm(Gmm),
    /// Neural importance sampling of directions.
    Neural(Box<NisGuide>),
}

impl AnyGuide {
    /// Whether the guide wants to learn from the paths it helps trace (a new guide of every
    /// method but `none` does).
    pub fn learns(&self) -> bool {
        match self {
            AnyGuide::None(g) => g.wants_records(),
            AnyGuide::Ppg(g) => g.wants_records(),
            AnyGuide::Gmm(g) => g.wants_records(),
            AnyGuide::Neural(g) => g.wants_records(),
        }
    }
}

/// A guiding method and its settings.
#[derive(Clone, Debug)]
pub enum GuideSpec {
    /// Unidirectional path tracing.
    None,
    /// Practical path guiding (SD-trees).
    Ppg(PpgConfig),
    /// Gaussian mixtures (Vorba et al. 2014).
    Gmm(GmmConfig),
    /// Neural importance sampling of directions.
    Neural(NisGuideConfig),
}

impl GuideSpec {
    /// The names [`GuideSpec::parse`] knows.
    pub const NAMES: [&'static str; 5] = ["none", "ppg", "gmm", "nis-kl", "nis-chi2"];

    /// The guide called `name` with default settings, or for the neural guides with `config`
    /// (JSON, merged over the defaults; `loss` and `seed` come from the name and `seed`).
    ///
    /// ```
    /// use nis_render::guiding::factory::GuideSpec;
    /// assert!(matches!(GuideSpec::parse("ppg", None, 0), Ok(GuideSpec::Ppg(_))));
    /// assert!(GuideSpec::parse("nis-kl", Some(r#"{"couplings": 4}"#), 0).is_ok());
    /// assert!(GuideSpec::parse("vmf", None, 0).is_err());
    /// ```
    pub fn parse(name: &str, config: Option<&str>, seed: u64) -> Result<GuideSpec, Error> {
        let loss = match name {
            "none" | "ppg" | "gmm" if config.is_some() => {
                return Err(Error::Invalid(format!(
                    "the guide '{name}' takes no settings (only the neural guides do)"
                )))
            }
            "none" => return Ok(GuideSpec::None),
            "ppg" => return Ok(GuideSpec::Ppg(PpgConfig::default())),
            "gmm" => return Ok(GuideSpec::Gmm(GmmConfig::default())),
            "nis-kl" => GuideLoss::Kl,
            "nis-chi2" => GuideLoss::ChiSquare,
            _ => {
                return Err(Error::Invalid(format!(
                    "unknown guide '{name}' (choose from {})",
                    Self::NAMES.join(", ")
                )))
            }
        };
        let base: NisGuideConfig = match config {
            Some(json) => serde_json::from_str(json)
                .map_err(|e| Error::Invalid(format!("guide settings: {e}")))?,
            None => NisGuideConfig::default(),
        };
        let config = NisGuideConfig { loss, seed, ..base };
        config
            .validate()
            .map_err(|e| Error::Invalid(format!("guide settings: {e}")))?;
        Ok(GuideSpec::Neural(config))
    }

    /// The guide for `scene`, new and untrained.
    pub fn build(&self, scene: &Scene) -> Result<AnyGuide, Error> {
        let bounds = scene.bounds();
        Ok(match self {
            GuideSpec::None => AnyGuide::None(NoGuide),
            GuideSpec::Ppg(c) => {
                let film = u64::from(scene.camera.width()) * u64::from(scene.camera.height());
                AnyGuide::Ppg(Ppg::new(bounds, c.for_film(film)))
            }
            GuideSpec::Gmm(c) => AnyGuide::Gmm(Gmm::new(bounds, *c)),
            GuideSpec::Neural(c) => AnyGuide::Neural(Box::new(
                NisGuide::new(bounds, c.clone())
                    .map_err(|e| Error::Invalid(format!("neural guide: {e}")))?,
            )),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    // Regressions found by the fuzz tests: settings the guide cannot train with (min_steps >
    // max_steps made `clamp` panic mid-render) or cannot allocate are refused when parsed.
    #[test]
    fn guide_settings_that_cannot_work_are_refused_when_parsed() {
        for json in [
            r#"{"min_steps": 10, "max_steps": 2}"#,
            r#"{"batch": 0}"#,
            r#"{"buffer": 18446744073709551615}"#,
            r#"{"selection_width": 1000000000000}"#,
            r#"{"context_bins": 1000000000000}"#,
            r#"{"hidden_width": 65536, "hidden_layers": 64}"#,
            r#"{"learning_rate": -1.0}"#,
            r#"{"average_span": 1.5}"#,
            r#"{"average_span": -0.5}"#,
            r#"{"pick_by_weight": 1.5}"#,
            r#"{"pick_by_weight": -0.1}"#,
        ] {
            let e = GuideSpec::parse("nis-kl", Some(json), 0).unwrap_err();
            assert!(e.to_string().starts_with("guide settings"), "{json}: {e}");
        }
        assert!(
            GuideSpec::parse("nis-chi2", Some(r#"{"min_steps": 5, "max_steps": 5}"#), 0).is_ok()
        );
        assert!(GuideSpec::parse("nis-kl", Some(r#"{"average_span": 0.0}"#), 0).is_ok());
        assert!(GuideSpec::parse("nis-kl", Some(r#"{"pick_by_weight": 0.0}"#), 0).is_ok());
    }
}
