//! What the GPU runs for a [`Flow`], read off the CPU flow: per coupling, its partition, encoding,
//! dense layers (where their weights lie in the flat parameters) and transform. Pure Rust, so
//! that the CPU harness's tests run the very plan the GPU runs.

use nis::flow::Flow;
use nis::{Density, Transform, TransformKind};

use crate::error::GpuError;

/// The largest bin count the kernels hold (kernels/flow.cuh, `NIS_MAX_BINS`).
const MAX_BINS: usize = 256;
// The kernels' knot arrays must hold every spline nis builds.
const _: () = assert!(nis::transform::MAX_BINS <= MAX_BINS);

/// The transform kinds the kernels know (kernels/flow.cuh's `kind`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Kind {
    Quadratic = 0,
    RationalQuadratic = 1,
}

/// One dense layer: `inputs × outputs` weights (row-major `[in, out]`) at `weights` in the flat
/// parameters, then `outputs` biases at `biases`.
#[derive(Clone, Debug)]
pub(crate) struct Dense {
    pub inputs: usize,
    pub outputs: usize,
    pub weights: usize,
    pub biases: usize,
}

/// One coupling layer.
#[derive(Clone, Debug)]
pub(crate) struct Step {
    pub a: Vec<i32>,
    pub b: Vec<i32>,
    pub blob_bins: usize,
    pub dense: Vec<Dense>,
    pub kind: Kind,
    pub bins: usize,
}

impl Step {
    /// The conditioner's input width: the one-blob code of x_A.
    pub fn encoded(&self) -> usize {
        self.a.len() * self.blob_bins
    }
}

/// A flow as the GPU runs it; `steps` in data-to-latent order.
#[derive(Clone, Debug)]
pub(crate) struct Plan {
    pub dim: usize,
    pub steps: Vec<Step>,
    pub params: Vec<f32>,
}

impl Plan {
    /// The plan of `flow`, or why the GPU cannot run it yet.
    pub fn of(flow: &Flow) -> Result<Plan, GpuError> {
        if flow.context_dim() > 0 {
            return Err(GpuError::Unsupported(
                "conditioned flows (context features) do not run on the GPU yet".into(),
            ));
        }
        let params = flow.params().to_vec();
        let mut steps = Vec::new();
        for c in flow.layers() {
            let (kind, bins) = match c.transform() {
                TransformKind::Quadratic { bins } => (Kind::Quadratic, bins),
                TransformKind::RationalQuadratic { bins } => (Kind::RationalQuadratic, bins),
                other => {
                    return Err(GpuError::Unsupported(format!(
                        "the {other:?} transform does not run on the GPU; piecewise-quadratic \
                         and rational-quadratic couplings do"
                    )))
                }
            };
            let dims = &c.mlp().dims;
            // The kernels read these shapes blindly: check them here, where a bad one is an error.
            let np = c.transform().param_count();
            let encoded = c.a().len() * c.encoding().bins;
            if dims.len() < 2
                || dims[0] != encoded
                || dims[dims.len() - 1] != c.b().len() * np
                || bins > MAX_BINS
            {
                return Err(GpuError::Unsupported(format!(
                    "a coupling whose conditioner ({dims:?}) does not match its {} encoded inputs \
                     and {} transformed dimensions of {bins} bins (at most {MAX_BINS})",
                    encoded,
                    c.b().len()
                )));
            }
            let mut at = c.param_range().start;
            let mut dense = Vec::new();
            for w in dims.windows(2) {
                let (inputs, outputs) = (w[0], w[1]);
                dense.push(Dense {
                    inputs,
                    outputs,
                    weights: at,
                    biases: at + inputs * outputs,
                });
                at += (inputs + 1) * outputs;
            }
            debug_assert_eq!(at, c.param_range().end);
            let index = |v: &[usize]| v.iter().map(|&i| i as i32).collect();
            steps.push(Step {
                a: index(c.a()),
                b: index(c.b()),
                blob_bins: c.encoding().bins,
                dense,
                kind,
                bins,
            });
        }
        Ok(Plan {
            dim: flow.dim(),
            steps,
            params,
        })
    }

    /// The widest activation of a row: every conditioner's encoded input and layer outputs.
    pub fn widest(&self) -> usize {
        self.steps
            .iter()
            .flat_map(|s| s.dense.iter().map(|d| d.outputs).chain([s.encoded()]))
            .max()
            .unwrap_or(1)
            .max(1)
    }

    /// The steps in the order a pass runs them: data to latent (density) or back (sampling).
    pub fn order(&self, inverse: bool) -> Vec<usize> {
        let mut order: Vec<usize> = (0..self.steps.len()).collect();
        if inverse {
            order.reverse();
        }
        order
    }
}
