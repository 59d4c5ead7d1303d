//! The NIS integrator's settings, [`NisConfig`], and their builder.

use serde::{Deserialize, Serialize};

use crate::error::{Error, Result};
use crate::flow::FlowConfig;
use crate::integrate::integrand::TrainOn;
use crate::loss::Loss;
use crate::nn::AdamConfig;
use crate::transform::TransformKind;

/// Settings of the NIS integrator. The defaults work across the built-in suite untuned.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct NisConfig {
    /// The flow (its `dim` is set from the integrator's; its `seed` initialises the weights).
    /// By default 2×32 conditioners on a one-blob encoding of 8 bins per input and
    /// piecewise-quadratic couplings of 16 bins: 8 encoding bins rather than 16 gave lower
    /// variance per evaluation on most of the suite, in less time (docs/results/integration.md,
    /// "One-blob bins"). A partial section in JSON changes the fields
    /// it names and keeps these defaults for the rest.
    #[serde(deserialize_with = "flow_patch")]
    pub flow: FlowConfig,
    /// The training loss; `auto` (the default) is KL for a whole integrand and χ² for the parts
    /// of a multi-channel integral ([`Loss::resolve`]).
    pub loss: Loss,
    /// Samples per adaptive iteration (one Adam step each). 256 by default: for the same training
    /// evaluations, four times the steps of 1024-point batches gave lower variance per
    /// evaluation on the suite's 4- and 8-d integrands (docs/results/integration.md, "Training
    /// batch").
    /// Many MPI ranks want larger batches (docs/results/scaling.md).
    pub batch: usize,
    /// Adam steps per batch: the first on-policy, the others reuse the batch off-policy (its
    /// points keep the density they were drawn from), trading compute for evaluations.
    pub steps_per_batch: usize,
    /// Earlier batches (the flow's share of each, its points, target values and the density that
    /// drew them) kept for replay, the newest replacing the oldest (0: none).
    pub replay_batches: usize,
    /// Extra Adam steps per batch, each on one kept batch (newest first, in turn), off-policy:
    /// loss weights from f/q_sampling, gradient of ln q_current (MadNIS's buffered training).
    pub replay_steps: usize,
    /// Share of the evaluation budget spent in the adaptive phase.
    pub train_fraction: f64,
    /// The optimiser.
    #[serde(deserialize_with = "adam_patch")]
    pub adam: AdamConfig,
    /// The learning rate decays exponentially over the adaptive phase to this fraction of its
    /// initial value (1: constant; Adam's own `decay` is then set from the number of steps).
    pub learning_rate_end: f32,
    /// Span of the exponential moving average of the flow's weights over the training batches,
    /// which the final phase samples from, as a share of the first training's batches: the
    /// average's decay is β = 1 − 1/(span·batches) (bias-corrected; 0: the last step's
    /// weights). Training samples from, and goes on from, the last step's weights. 0.1 by
    /// default: lower variance per evaluation on the suite integrands measured at large budgets,
    /// level at small ones (docs/results/integration.md, "Weight average").
    pub average_span: f64,
    /// Share λ of uniform points in every batch (the defensive mixture).
    pub uniform_fraction: f64,
    /// Initial exponent β of the tempered target |f|^β; rises linearly to 1 over the first half
    /// of training (1: no annealing).
    pub anneal_from: f64,
    /// Iterations of the final phase (for χ²/dof).
    pub final_iterations: usize,
    /// Share of the adaptive phase's batches, the last ones, whose evaluations also enter the
    /// estimate of `integrate`, with shares fixed before each batch is drawn so that it stays
    /// unbiased (`integrate/nis/reuse.rs`, docs/ESTIMATE.md; 0: the final phase's evaluations
    /// alone). Each batch's share weighs it against the final phase as predicted from earlier
    /// batches, post-stratified on the stratified final phase's latent grid, so training takes
    /// little where stratification gains much (2-d) and more where it gains little (d ≥ 4;
    /// docs/results/integration.md, "Training in the estimate").
    pub reuse_training: f64,
    /// Seed of the random streams (training, estimating, unweighting).
    pub seed: u64,
    /// The component of a vector-valued integrand the flow learns.
    pub train_on: TrainOn,
    /// Stratified sampling of the flow's latent in the final phase, with VEGAS+'s adaptive
    /// allocation of points to hypercubes (`None` or JSON `null`: i.i.d. latents).
    pub stratify: Option<Stratify>,
    /// Integrating an untrained flow of binary masks to a precision target, NIS switches to the
    /// codes' fewer coupling layers (`flow.masks`) when the tempered weights of its first batches
    /// show a smooth integrand, on which the codes learn as well in less time; their batches
    /// are spent, and training starts afresh (`integrate/strategies.rs`). Peaked and
    /// multi-modal integrands keep the binary masks, which miss modes less often. The probe's
    /// batches count against `max_evals` and `max_seconds`. No effect on budgets, on a trained
    /// flow, with `couplings` set or without annealing; the keyword `masks` turns it off
    /// unless `auto_masks` is given too.
    pub auto_masks: bool,
    /// Integrating an untrained flow to a precision target, NIS races VEGAS+: after a few
    /// training batches VEGAS+ runs to the target while it is predicted to get there before
    /// NIS's training would end, and its result is the answer when it meets the target with no
    /// warning (`IntegrationResult::answered_by`; the flow then stays barely trained). Cheap,
    /// nearly separable integrands then take VEGAS+'s time instead of a flow's training
    /// (`integrate/race.rs`). No effect on budgets, on a trained flow, or on an integrator
    /// built without a rival ([`super::NisIntegrator::new`]; [`crate::integrate::integrator`],
    /// which every front end builds with, hands NIS VEGAS+).
    pub race_vegas: bool,
}

/// Overlays the fields of the JSON object `given` on those of `base`; anything but two objects:
/// `given` replaces `base` (and the type read from it says what is wrong).
fn overlay(base: &mut serde_json::Value, given: serde_json::Value) {
    match (base.as_object_mut(), given) {
        (Some(fields), serde_json::Value::Object(given)) => fields.extend(given),
        (_, other) => *base = other,
    }
}

/// A section read as a patch of `default`: the fields it names replace `default`'s and the others
/// keep them (serde would fill them from the section type's own `Default`, which for the flow and
/// the optimiser is not the integrator's).
fn patch<'de, D, T>(d: D, default: T) -> std::result::Result<T, D::Error>
where
    D: serde::Deserializer<'de>,
    T: Serialize + serde::de::DeserializeOwned,
{
    use serde::de::Error as _;
    let given = serde_json::Value::deserialize(d)?;
    let mut merged = serde_json::to_value(default).map_err(D::Error::custom)?;
    overlay(&mut merged, given);
    T::deserialize(merged).map_err(D::Error::custom)
}

fn flow_patch<'de, D: serde::Deserializer<'de>>(d: D) -> std::result::Result<FlowConfig, D::Error> {
    patch(d, NisConfig::default().flow)
}

fn adam_patch<'de, D: serde::Deserializer<'de>>(d: D) -> std::result::Result<AdamConfig, D::Error> {
    patch(d, NisConfig::default().adam)
}

/// How the final phase stratifies the flow's latent space (see `integrate::nis::strata`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Stratify {
    /// Damping of the allocation's adaptation, as VEGAS+'s β (0: equal counts per hypercube).
    pub beta: f64,
    /// Fewest points per hypercube (at least 2, for its variance).
    pub min_per_cube: usize,
    /// Most hypercubes (they are planned from the points per iteration, as VEGAS+ plans them;
    /// this bounds the memory of a large budget; 1: no stratification of the latent).
    pub max_cubes: usize,
}

impl Default for Stratify {
    fn default() -> Self {
        Stratify {
            beta: 0.75,
            min_per_cube: 2,
            max_cubes: 1 << 16,
        }
    }
}

impl Default for NisConfig {
    fn default() -> Self {
        NisConfig {
            flow: FlowConfig {
                transform: TransformKind::Quadratic { bins: 16 },
                hidden_layers: 2,
                hidden_width: 32,
                blob_bins: 8,
                ..FlowConfig::default()
            },
            loss: Loss::Auto,
            batch: 256,
            steps_per_batch: 1,
            replay_batches: 0,
            replay_steps: 0,
            train_fraction: 0.4,
            adam: AdamConfig {
                learning_rate: 5e-3,
                clip_norm: Some(10.0),
                ..Default::default()
            },
            learning_rate_end: 0.1,
            average_span: 0.1,
            uniform_fraction: 0.002,
            anneal_from: 0.1,
            final_iterations: 10,
            reuse_training: 0.5,
            seed: 0,
            train_on: TrainOn::default(),
            stratify: Some(Stratify::default()),
            auto_masks: true,
            race_vegas: true,
        }
    }
}

impl NisConfig {
    /// A builder starting from the defaults.
    pub fn builder() -> NisConfigBuilder {
        NisConfigBuilder {
            config: NisConfig::default(),
            seed: None,
        }
    }

    pub(crate) fn validate(&self) -> Result<()> {
        if self.loss == Loss::Nll {
            return Err(Error::Config(
                "loss \"nll\" is for data (a flow fitted to points); an integrand trains with \
                 \"kl\" or \"chi2\""
                    .into(),
            ));
        }
        let ok = self.batch >= 2
            && self.steps_per_batch >= 1
            && (self.replay_steps == 0 || self.replay_batches >= 1)
            && (0.0..1.0).contains(&self.train_fraction)
            && (0.0..1.0).contains(&self.uniform_fraction)
            && self.anneal_from > 0.0
            && self.anneal_from <= 1.0
            && self.final_iterations >= 1
            && (0.0..=1.0).contains(&self.reuse_training)
            && self.learning_rate_end > 0.0
            && self.learning_rate_end <= 1.0
            && (0.0..=1.0).contains(&self.average_span)
            && self
                .stratify
                .is_none_or(|s| s.beta >= 0.0 && s.min_per_cube >= 2 && s.max_cubes >= 1);
        if ok {
            Ok(())
        } else {
            Err(Error::Config(format!("invalid NIS settings: {self:?}")))
        }
    }
}

/// Builds a [`NisConfig`] with named setters.
///
/// ```
/// use nis::integrate::nis::NisConfig;
/// use nis::{loss::Loss, TransformKind};
/// let c = NisConfig::builder()
///     .transform(TransformKind::RationalQuadratic { bins: 8 })
///     .loss(Loss::ChiSquare)
///     .batch(2048)
///     .learning_rate(1e-3)
///     .seed(4)
///     .build()
///     .unwrap();
/// assert_eq!((c.batch, c.seed, c.flow.seed), (2048, 4, 4));
/// assert!(NisConfig::builder().train_fraction(1.5).build().is_err());
/// ```
#[derive(Clone, Debug)]
pub struct NisConfigBuilder {
    config: NisConfig,
    seed: Option<u64>,
}

impl NisConfigBuilder {
    /// Sets [`NisConfig::flow`] (its `seed` too, unless [`NisConfigBuilder::seed`] is given).
    pub fn flow(mut self, flow: FlowConfig) -> Self {
        self.config.flow = flow;
        self
    }
    /// Sets the flow's coupling transform.
    pub fn transform(mut self, transform: TransformKind) -> Self {
        self.config.flow.transform = transform;
        self
    }
    /// Sets [`NisConfig::loss`].
    pub fn loss(mut self, loss: Loss) -> Self {
        self.config.loss = loss;
        self
    }
    /// Sets [`NisConfig::batch`].
    pub fn batch(mut self, batch: usize) -> Self {
        self.config.batch = batch;
        self
    }
    /// Sets [`NisConfig::steps_per_batch`].
    pub fn steps_per_batch(mut self, steps: usize) -> Self {
        self.config.steps_per_batch = steps;
        self
    }
    /// Sets [`NisConfig::replay_batches`] and [`NisConfig::replay_steps`].
    pub fn replay(mut self, batches: usize, steps: usize) -> Self {
        self.config.replay_batches = batches;
        self.config.replay_steps = steps;
        self
    }
    /// Sets [`NisConfig::train_fraction`].
    pub fn train_fraction(mut self, fraction: f64) -> Self {
        self.config.train_fraction = fraction;
        self
    }
    /// Sets [`NisConfig::adam`].
    pub fn adam(mut self, adam: AdamConfig) -> Self {
        self.config.adam = adam;
        self
    }
    /// Sets Adam's initial learning rate.
    pub fn learning_rate(mut self, rate: f32) -> Self {
        self.config.adam.learning_rate = rate;
        self
    }
    /// Sets [`NisConfig::learning_rate_end`].
    pub fn learning_rate_end(mut self, fraction: f32) -> Self {
        self.config.learning_rate_end = fraction;
        self
    }
    /// Sets [`NisConfig::average_span`].
    pub fn average_span(mut self, share: f64) -> Self {
        self.config.average_span = share;
        self
    }
    /// Sets [`NisConfig::uniform_fraction`].
    pub fn uniform_fraction(mut self, fraction: f64) -> Self {
        self.config.uniform_fraction = fraction;
        self
    }
    /// Sets [`NisConfig::anneal_from`].
    pub fn anneal_from(mut self, beta: f64) -> Self {
        self.config.anneal_from = beta;
        self
    }
    /// Sets [`NisConfig::final_iterations`].
    pub fn final_iterations(mut self, iterations: usize) -> Self {
        self.config.final_iterations = iterations;
        self
    }
    /// Sets [`NisConfig::reuse_training`].
    pub fn reuse_training(mut self, share: f64) -> Self {
        self.config.reuse_training = share;
        self
    }
    /// Sets [`NisConfig::train_on`].
    pub fn train_on(mut self, train_on: TrainOn) -> Self {
        self.config.train_on = train_on;
        self
    }
    /// Sets [`NisConfig::auto_masks`].
    pub fn auto_masks(mut self, on: bool) -> Self {
        self.config.auto_masks = on;
        self
    }
    /// Sets [`NisConfig::stratify`].
    pub fn stratify(mut self, stratify: Option<Stratify>) -> Self {
        self.config.stratify = stratify;
        self
    }
    /// Sets [`NisConfig::race_vegas`].
    pub fn race_vegas(mut self, on: bool) -> Self {
        self.config.race_vegas = on;
        self
    }
    /// Seeds the run: the random streams ([`NisConfig::seed`]) and the flow's initialisation
    /// (its `seed`), whatever order the setters came in.
    pub fn seed(mut self, seed: u64) -> Self {
        self.seed = Some(seed);
        self
    }
    /// The checked settings.
    pub fn build(mut self) -> Result<NisConfig> {
        if let Some(seed) = self.seed {
            self.config.seed = seed;
            self.config.flow.seed = seed;
        }
        self.config.validate()?;
        Ok(self.config)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_patch_changes_what_it_names_on_top_of_any_settings() {
        let mut base = NisConfig::default();
        base.flow.transform = TransformKind::RationalQuadratic { bins: 8 };
        base.batch = 1024;
        let json = serde_json::json!({"flow": {"hidden_width": 16}, "train_fraction": 0.3});
        let c = base.patched(json).unwrap();
        let mut expected = base.clone();
        expected.flow.hidden_width = 16;
        expected.train_fraction = 0.3;
        assert_eq!(c, expected);
        for bad in [
            serde_json::json!(3),
            serde_json::json!({"flow": {"width": 1}}),
            serde_json::json!({"nope": 1}),
        ] {
            assert!(base.patched(bad.clone()).is_err(), "{bad}");
        }
    }

    #[test]
    fn a_partial_nested_section_keeps_the_integrators_own_defaults() {
        // The integrator's flow and optimiser differ from `FlowConfig`'s and `AdamConfig`'s own
        // defaults (16 spline bins, 2×32 conditioners, 8 one-blob bins; learning rate 5·10⁻³,
        // clipping at 10): a section that names one field changes that field only.
        let d = NisConfig::default();
        let c: NisConfig = serde_json::from_str(
            r#"{"flow": {"hidden_width": 64}, "adam": {"learning_rate": 0.001}}"#,
        )
        .unwrap();
        assert_eq!(
            c.flow,
            FlowConfig {
                hidden_width: 64,
                ..d.flow.clone()
            }
        );
        assert_eq!(
            c.adam,
            AdamConfig {
                learning_rate: 0.001,
                ..d.adam
            }
        );
        assert_eq!(c.batch, d.batch);
        // The sections still refuse what they do not know, and what is not a section.
        for bad in [
            r#"{"flow": {"width": 64}}"#,
            r#"{"adam": {"rate": 1}}"#,
            r#"{"flow": 3}"#,
        ] {
            assert!(serde_json::from_str::<NisConfig>(bad).is_err(), "{bad}");
        }
        // A whole config (a model file's) reads back as itself.
        let json = serde_json::to_string(&c).unwrap();
        assert_eq!(serde_json::from_str::<NisConfig>(&json).unwrap(), c);
    }

    #[test]
    fn every_builder_setter_sets_its_field_and_the_seed_reaches_the_flow() {
        let flow = FlowConfig {
            hidden_width: 8,
            seed: 99,
            ..FlowConfig::default()
        };
        let adam = AdamConfig {
            clip_norm: None,
            ..AdamConfig::default()
        };
        let c = NisConfig::builder()
            .seed(6)
            .flow(flow.clone())
            .transform(TransformKind::Linear { bins: 4 })
            .loss(Loss::ChiSquare)
            .batch(100)
            .steps_per_batch(3)
            .replay(8, 2)
            .train_fraction(0.25)
            .adam(adam)
            .learning_rate(2e-3)
            .learning_rate_end(0.5)
            .average_span(0.5)
            .uniform_fraction(0.01)
            .anneal_from(0.5)
            .final_iterations(4)
            .reuse_training(0.75)
            .train_on(TrainOn::SumAbs)
            .stratify(Some(Stratify {
                beta: 0.5,
                min_per_cube: 3,
                max_cubes: 10,
            }))
            .auto_masks(false)
            .race_vegas(false)
            .build()
            .unwrap();
        let expected = NisConfig {
            flow: FlowConfig {
                hidden_width: 8,
                transform: TransformKind::Linear { bins: 4 },
                seed: 6,
                ..FlowConfig::default()
            },
            loss: Loss::ChiSquare,
            batch: 100,
            steps_per_batch: 3,
            replay_batches: 8,
            replay_steps: 2,
            train_fraction: 0.25,
            adam: AdamConfig {
                learning_rate: 2e-3,
                ..adam
            },
            learning_rate_end: 0.5,
            average_span: 0.5,
            uniform_fraction: 0.01,
            anneal_from: 0.5,
            final_iterations: 4,
            reuse_training: 0.75,
            seed: 6,
            train_on: TrainOn::SumAbs,
            stratify: Some(Stratify {
                beta: 0.5,
                min_per_cube: 3,
                max_cubes: 10,
            }),
            auto_masks: false,
            race_vegas: false,
        };
        assert_eq!(c, expected);
        // Without `seed`, the flow keeps its own.
        let c = NisConfig::builder().flow(flow).build().unwrap();
        assert_eq!((c.seed, c.flow.seed), (0, 99));
        for bad in [
            NisConfig::builder().batch(1),
            NisConfig::builder().steps_per_batch(0),
            NisConfig::builder().replay(0, 1),
            NisConfig::builder().train_fraction(1.0),
            NisConfig::builder().uniform_fraction(-0.1),
            NisConfig::builder().anneal_from(0.0),
            NisConfig::builder().final_iterations(0),
            NisConfig::builder().reuse_training(1.5),
            NisConfig::builder().reuse_training(f64::NAN),
            NisConfig::builder().learning_rate_end(0.0),
            NisConfig::builder().stratify(Some(Stratify {
                min_per_cube: 1,
                ..Stratify::default()
            })),
            NisConfig::builder().stratify(Some(Stratify {
                max_cubes: 0,
                ..Stratify::default()
            })),
            NisConfig::builder().stratify(Some(Stratify {
                beta: -1.0,
                ..Stratify::default()
            })),
        ] {
            assert!(matches!(bad.build(), Err(Error::Config(_))));
        }
    }
}
