//! `nis integrate --channels` and `--signs`: a built-in example through its channels, or any
//! integrand split by sign, with `nis::integrate::multichannel`.

use nis::channels::{examples, ChannelSet};
use nis::comm::Comm;
use nis::integrands::Builtin;
use nis::integrate::multichannel::{MultiChannel, MultiChannelConfig, Signs};
use nis::integrate::{IntegrationResult, Method};

use nis::integrate::unweight::{SampleFormat, SampleWriter};
use nis::integrate::Settings;

use crate::integrate::{IntegrateArgs, SampleArgs};

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

impl IntegrateArgs {
    /// Whether the run goes through [`MultiChannel`] (`--channels` or `--signs`).
    pub(crate) fn multichannel(&self) -> bool {
        self.channels || self.signs.is_some()
    }
}

/// One method through the channels of the example `f` (`--channels`), or through one identity
/// channel (`--signs` alone).
pub(crate) fn run_multichannel(
    f: &Builtin,
    method: Method,
    args: &IntegrateArgs,
    comm: &Comm,
) -> Result<IntegrationResult, Error> {
    let config = MultiChannelConfig {
        signs: args.signs.map_or(Signs::Auto, SignsArg::signs),
        shared_flow: !args.flow_per_channel,
        weight_network: !args.no_weight_network,
        ..MultiChannelConfig::default()
    };
    let settings = args.settings()?;
    let mut mc = if args.channels {
        let mut set = channel_set(&f.name)?;
        if args.no_enhancement {
            set = set.without_enhancements();
        }
        MultiChannel::new(set, method, settings, config)?
    } else {
        MultiChannel::single(f.dim, method, settings, config)?
    };
    mc.set_comm(comm.clone());
    Ok(match args.target()? {
        Some(t) => mc.integrate_to(f, &t)?,
        None => mc.integrate(f, args.evals)?,
    })
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

/// `nis sample --channels`: a flow per channel (and sign) integrates the example on `--evals`,
/// then `--n` events, each with its channel, go to `--out`.
pub(crate) fn sample_events(args: &SampleArgs) -> Result<(), Error> {
    let f = nis::integrands::by_name(&args.name, args.dim)?;
    let settings = Settings::default().seed(args.seed);
    let mut mc = MultiChannel::new(
        channel_set(&f.name)?,
        Method::Nis,
        settings,
        MultiChannelConfig::default(),
    )?;
    let r = mc.integrate(&f, args.evals)?;
    let ev = mc.unweighted(&f, args.n, args.overweight)?;
    let mut out = SampleWriter::create_with_channels(
        &args.out,
        SampleFormat::for_path(&args.out),
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
