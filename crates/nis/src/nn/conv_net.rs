//! The conditioner of the multi-scale flow ([`crate::flow::multiscale`]): a small residual network of
//! 3×3 convolutions (RealNVP, Dinh et al. 2016, Sec. 4.1, without batch normalisation) on the
//! fused im2col + gemm kernels of [`crate::kernels::conv`], with its backward pass.

use rand::Rng;

use crate::kernels::conv::{self, Shape, TAPS};
use crate::kernels::elementwise;

/// A residual network of 3×3 convolutions: in (c_in → F), `blocks` × [h + conv(relu(conv(relu
/// h)))], out (relu → c_out). Weights at `offset` in the model's parameters.
#[derive(Clone, Debug, PartialEq)]
pub struct ConvNet {
    pub c_in: usize,
    pub features: usize,
    pub blocks: usize,
    pub c_out: usize,
    pub offset: usize,
}

/// What a conditioner's forward pass keeps for its backward pass (one chunk).
#[derive(Clone, Debug, Default)]
pub struct NetTape {
    pub(crate) input: Vec<f32>,
    /// Per block: relu(h) and relu(conv_a(relu h)).
    pub(crate) r: Vec<Vec<f32>>,
    pub(crate) t: Vec<Vec<f32>>,
    /// relu(h) before the output convolution, and the output (spline parameters).
    pub(crate) f: Vec<f32>,
    pub(crate) out: Vec<f32>,
}

impl ConvNet {
    /// (c_in, c_out) of every convolution, in order.
    fn convs(&self) -> Vec<(usize, usize)> {
        let f = self.features;
        let mut v = vec![(self.c_in, f)];
        for _ in 0..self.blocks {
            v.push((f, f));
            v.push((f, f));
        }
        v.push((f, self.c_out));
        v
    }

    /// Offsets of each convolution's weights within the network's parameters.
    fn offsets(&self) -> Vec<usize> {
        let mut off = 0;
        self.convs()
            .iter()
            .map(|&(i, o)| {
                let at = off;
                off += TAPS * i * o + o;
                at
            })
            .collect()
    }

    pub fn param_count(&self) -> usize {
        self.convs().iter().map(|&(i, o)| TAPS * i * o + o).sum()
    }

    /// He-uniform weights, zero biases, and a zero output layer (the identity transform).
    pub(crate) fn init(&self, params: &mut [f32], rng: &mut impl Rng) {
        params.fill(0.0);
        let convs = self.convs();
        for (k, (&(i, o), off)) in convs.iter().zip(self.offsets()).enumerate() {
            if k + 1 == convs.len() {
                break;
            }
            let bound = (6.0 / (TAPS * i) as f32).sqrt();
            for p in &mut params[off..off + TAPS * i * o] {
                *p = bound * (2.0 * rng.random::<f32>() - 1.0);
            }
        }
    }

    /// (weights, bias) of convolution `k`.
    fn conv<'a>(&self, params: &'a [f32], k: usize) -> (&'a [f32], &'a [f32]) {
        let (i, o) = self.convs()[k];
        let off = self.offsets()[k];
        params[off..off + TAPS * i * o + o].split_at(TAPS * i * o)
    }

    fn conv_mut<'a>(&self, grads: &'a mut [f32], k: usize) -> (&'a mut [f32], &'a mut [f32]) {
        let (i, o) = self.convs()[k];
        let off = self.offsets()[k];
        grads[off..off + TAPS * i * o + o].split_at_mut(TAPS * i * o)
    }

    /// Forward pass of `n` images of h×w (`input`: `[n, h, w, c_in]`).
    pub(crate) fn forward(
        &self,
        params: &[f32],
        input: Vec<f32>,
        n: usize,
        h: usize,
        w: usize,
    ) -> NetTape {
        let (f, pix) = (self.features, n * h * w);
        let shape = |c_in, c_out| Shape {
            n,
            h,
            w,
            c_in,
            c_out,
        };
        let mut col = vec![0.0; pix * TAPS * self.c_in.max(f)];
        let mut hid = vec![0.0; pix * f];
        let (wt, b) = self.conv(params, 0);
        conv::forward(&input, wt, b, &mut hid, shape(self.c_in, f), &mut col);
        let mut tape = NetTape {
            input,
            ..Default::default()
        };
        let mut d = vec![0.0; pix * f];
        for blk in 0..self.blocks {
            let mut r = hid.clone();
            elementwise::relu(&mut r);
            let mut t = vec![0.0; pix * f];
            let (wt, b) = self.conv(params, 1 + 2 * blk);
            conv::forward(&r, wt, b, &mut t, shape(f, f), &mut col);
            elementwise::relu(&mut t);
            let (wt, b) = self.conv(params, 2 + 2 * blk);
            conv::forward(&t, wt, b, &mut d, shape(f, f), &mut col);
            for (h, d) in hid.iter_mut().zip(&d) {
                *h += d;
            }
            tape.r.push(r);
            tape.t.push(t);
        }
        elementwise::relu(&mut hid);
        let mut out = vec![0.0; pix * self.c_out];
        let (wt, b) = self.conv(params, 1 + 2 * self.blocks);
        conv::forward(&hid, wt, b, &mut out, shape(f, self.c_out), &mut col);
        tape.f = hid;
        tape.out = out;
        tape
    }

    /// Backward pass from ∂L/∂out: writes ∂L/∂parameters into `grads` (this network's slice,
    /// overwritten) and returns ∂L/∂input when asked.
    pub(crate) fn backward(
        &self,
        params: &[f32],
        tape: &NetTape,
        g_out: &[f32],
        grads: &mut [f32],
        (n, h, w): (usize, usize, usize),
        want_input: bool,
    ) -> Option<Vec<f32>> {
        let (f, pix) = (self.features, n * h * w);
        let shape = |c_in, c_out| Shape {
            n,
            h,
            w,
            c_in,
            c_out,
        };
        let mut col = vec![0.0; pix * TAPS * self.c_in.max(f)];
        let k_out = 1 + 2 * self.blocks;
        let mut g_h = vec![0.0; pix * f];
        let (wt, _) = self.conv(params, k_out);
        conv::backward_input(g_out, wt, &mut g_h, shape(f, self.c_out), &mut col);
        let (gw, gb) = self.conv_mut(grads, k_out);
        conv::backward_weights(
            &tape.f,
            g_out,
            gw,
            gb,
            shape(f, self.c_out),
            &mut col,
            false,
        );
        elementwise::relu_backward(&tape.f, &mut g_h);
        let mut g_t = vec![0.0; pix * f];
        let mut g_r = vec![0.0; pix * f];
        for blk in (0..self.blocks).rev() {
            let (r, t) = (&tape.r[blk], &tape.t[blk]);
            let (wt, _) = self.conv(params, 2 + 2 * blk);
            conv::backward_input(&g_h, wt, &mut g_t, shape(f, f), &mut col);
            let (gw, gb) = self.conv_mut(grads, 2 + 2 * blk);
            conv::backward_weights(t, &g_h, gw, gb, shape(f, f), &mut col, false);
            elementwise::relu_backward(t, &mut g_t);
            let (wt, _) = self.conv(params, 1 + 2 * blk);
            conv::backward_input(&g_t, wt, &mut g_r, shape(f, f), &mut col);
            let (gw, gb) = self.conv_mut(grads, 1 + 2 * blk);
            conv::backward_weights(r, &g_t, gw, gb, shape(f, f), &mut col, false);
            elementwise::relu_backward(r, &mut g_r);
            for (g, r) in g_h.iter_mut().zip(&g_r) {
                *g += r;
            }
        }
        let (gw, gb) = self.conv_mut(grads, 0);
        conv::backward_weights(
            &tape.input,
            &g_h,
            gw,
            gb,
            shape(self.c_in, f),
            &mut col,
            false,
        );
        want_input.then(|| {
            let mut g_in = vec![0.0; pix * self.c_in];
            let (wt, _) = self.conv(params, 0);
            conv::backward_input(&g_h, wt, &mut g_in, shape(self.c_in, f), &mut col);
            g_in
        })
    }
}
