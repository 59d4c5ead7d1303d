//! `nis integrate --channels` and `--signs`: a built-in example through its channels, or any
//! integrand split by sign, with `nis::integrate::multichannel`.

use std::path::Path;

use nis::channels::{examples, ChannelSet};
use nis::integrands::Builtin;
use nis::integrate::multichannel::{MultiChannel, MultiChannelConfig, Signs};
use nis::integrate::unweight::{SampleFormat, SampleWriter};
use nis::integrate::{IntegrationResult, Integrator, Method, Settings};

type Error = Box<dyn std::error::Error>;

/// `--signs`.
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub enum SignsArg {
    Auto,
    Split,
    Whole,
}

impl SignsArg {
    fn signs(self) -> Signs {
        match self {
            SignsArg::Auto => Signs::Auto,
            SignsArg::Split => Signs::Split,
            SignsArg::Whole => Signs::Whole,
        }
    }
}

/// The options of `nis integrate` that route a run through channels or a sign split.
#[derive(Clone, Debug, clap::Args)]
pub struct ChannelArgs {
    /// Integrate through the example's channels (the multi-channel examples of `nis list`): a
    /// sampler of the method per channel, weights adapted, points allocated by σ.
    #[arg(long, conflicts_with_all = ["load", "save"])]
    pub channels: bool,
    /// Split the integrand by sign (auto: when a pilot sees both signs; split; whole), with a
    /// sampler per channel and sign; without --channels, through one identity channel. Without
    /// --signs and --channels, NIS splits a scalar integrand when its first points show both
    /// signs; VEGAS+ and plain MC keep the whole.
    #[arg(long, value_enum, conflicts_with_all = ["load", "save"])]
    pub signs: Option<SignsArg>,
    /// With --channels or --signs, NIS: a flow for every channel and sign instead of the default
    /// one flow shared by all, conditioned on the part (docs/results/integration.md, "One flow
    /// shared by the channels").
    #[arg(long)]
    pub flow_per_channel: bool,
    /// With --channels, NIS: no network refining the channel weights (by default one is fitted
    /// after the parts adapt, MadNIS's, and kept only when it lowers the variance on held-out
    /// points).
    #[arg(long)]
    pub no_weight_network: bool,
    /// With --channels: weight the channels by their densities alone, α_k ∝ a_k g_k (the classic
    /// weights), instead of by the propagators the examples' channels carry as enhancements
    /// (single-diagram enhancement; docs/guide/02-integrate.md, "Several peaks")
    #[arg(long)]
    pub no_enhancement: bool,
}

impl ChannelArgs {
    /// Whether the run goes through [`MultiChannel`] (`--channels` or `--signs`).
    pub(crate) fn multichannel(&self) -> bool {
        self.channels || self.signs.is_some()
    }

    /// An error for an option that needs `--channels` or `--signs` without them.
    pub(crate) fn check(&self) -> Result<(), Error> {
        if self.flow_per_channel && !self.multichannel() {
            return Err("--flow-per-channel needs --channels or --signs".into());
        }
        if self.no_weight_network && !self.channels {
            return Err("--no-weight-network needs --channels".into());
        }
        if self.no_enhancement && !self.channels {
            return Err("--no-enhancement needs --channels".into());
        }
        Ok(())
    }

    /// The integrator of `method` through the channels of the example `f` (`--channels`), or
    /// through one identity channel (`--signs` alone): an [`Integrator`] like any other.
    pub(crate) fn integrator(
        &self,
        f: &Builtin,
        method: Method,
        settings: Settings,
    ) -> Result<Box<dyn Integrator>, Error> {
        let config = MultiChannelConfig {
            signs: self.signs.map_or(Signs::Auto, SignsArg::signs),
            shared_flow: !self.flow_per_channel,
            weight_network: !self.no_weight_network,
            ..MultiChannelConfig::default()
        };
        Ok(Box::new(if self.channels {
            let mut set = channel_set(&f.name)?;
            if self.no_enhancement {
                set = set.without_enhancements();
            }
            MultiChannel::new(set, method, settings, config)?
        } else {
            MultiChannel::single(f.dim, method, settings, config)?
        }))
    }
}

/// The channels of the example `name`, or an error that lists the examples.
fn channel_set(name: &str) -> Result<ChannelSet, Error> {
    let ex = examples::by_name(name).map_err(|_| {
        format!(
            "--channels: {name} has no channels; the multi-channel examples are {}",
            examples::names().join(", ")
        )
    })?;
    Ok(ChannelSet::new(ex.channels)?)
}

/// What `nis sample --channels` asks for: `n` events after training on `evals` evaluations.
pub(crate) struct EventsRequest<'a> {
    pub(crate) seed: u64,
    pub(crate) evals: u64,
    pub(crate) n: usize,
    pub(crate) overweight: f64,
    pub(crate) out: &'a Path,
}

/// `nis sample --channels`: a flow per channel (and sign) integrates the example `f` on
/// `--evals`, then `--n` events, each with its channel, go to `--out`.
pub(crate) fn sample_events(f: &Builtin, args: &EventsRequest) -> Result<(), Error> {
    let settings = Settings::default().seed(args.seed);
    let mut mc = MultiChannel::new(
        channel_set(&f.name)?,
        Method::Nis,
        settings,
        MultiChannelConfig::default(),
    )?;
    let r = mc.integrate(f, args.evals)?;
    let ev = mc.unweighted(f, args.n, args.overweight)?;
    let mut out = SampleWriter::create_with_channels(
        args.out,
        SampleFormat::for_path(args.out),
        f.dim,
        args.n as u64,
    )?;
    let points = ev.events.points.chunks_exact(f.dim);
    for ((p, &w), &k) in points.zip(&ev.events.weights).zip(&ev.channels) {
        out.push_event(p, w, k)?;
    }
    out.finish()?;
    println!(
        "{} events of {} through {} channels written to {} (integral {:.6e} ± {:.1e}): \
         efficiency {:.4}, {:.1}% negative",
        args.n,
        f.name,
        r.channels.as_ref().map_or(0, |c| c.means.len()),
        args.out.display(),
        r.value,
        r.std_err,
        ev.events.efficiency,
        100.0 * ev.negative_fraction
    );
    Ok(())
}

/// The lines of a multi-channel result's channels and signs, for the text table.
pub(crate) fn channel_lines(r: &IntegrationResult) -> Vec<String> {
    let Some(c) = &r.channels else {
        return Vec::new();
    };
    let mut lines: Vec<String> = (0..c.means.len())
        .map(|k| {
            format!(
                "         channel {k}: a = {:.4}, {:.6e} ± {:.2e}, {} evaluations",
                c.weights[k], c.means[k], c.std_errs[k], c.evals[k]
            )
        })
        .collect();
    if let Some(s) = &c.signs {
        lines.push(format!(
            "         f > 0: {:.6e} ± {:.2e}; f < 0: {:.6e} ± {:.2e}; negative weights {:.1}%",
            s.positive,
            s.positive_err,
            s.negative,
            s.negative_err,
            100.0 * s.negative_fraction
        ));
    }
    lines
}
