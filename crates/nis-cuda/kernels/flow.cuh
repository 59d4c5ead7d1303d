// The coupling flow's elementwise kernels, written once for two compilers: NVRTC builds the
// `__global__` kernels at the end for the GPU; the C harness (harness.c, built by the crate's
// build script with `cc`) runs the same per-thread bodies on the CPU in the tests, against the
// Rust transforms of `nis::transform`. The arithmetic follows those transforms step by step:
// piecewise-quadratic in f32 with ln C' in f64, rational-quadratic in f64 from f32 parameters.
// NVRTC fuses multiply-adds (its default) where the harness and Rust do not: the GPU's numbers
// differ from theirs by rounding.
#ifndef NIS_FLOW_CUH
#define NIS_FLOW_CUH

#if defined(__CUDACC_RTC__) || defined(__CUDACC__)
#define NIS_HD __device__ __forceinline__
#define NIS_GPU 1
typedef unsigned long long nis_u64;
#else
#include <math.h>
#include <stdint.h>
#include <string.h>
#define NIS_HD static inline
typedef uint64_t nis_u64;
#endif

// The largest bin count (nis::transform::MAX_BINS): knots live in per-thread arrays.
#define NIS_MAX_BINS 256
// Floors, as nis::transform::quadratic and ::rational_quadratic define them.
#define NIS_PQ_MIN_W 1e-3f
#define NIS_PQ_MIN_V 1e-3f
#define NIS_RQ_MIN_W 1e-3
#define NIS_RQ_MIN_SLOPE 1e-3
#define NIS_RQ_MIN_D 1e-3

NIS_HD float nis_clamp01f(float v) { return fminf(fmaxf(v, 0.0f), 1.0f); }

NIS_HD float nis_bits_to_float(unsigned int b) {
#ifdef NIS_GPU
    return __uint_as_float(b);
#else
    float f;
    memcpy(&f, &b, sizeof f);
    return f;
#endif
}

NIS_HD unsigned int nis_float_to_bits(float f) {
#ifdef NIS_GPU
    return __float_as_uint(f);
#else
    unsigned int b;
    memcpy(&b, &f, sizeof b);
    return b;
#endif
}

// e^x in f32 as nis::kernels::elementwise::exp computes it (Cody–Waite reduction, degree-6
// Taylor polynomial, the exponent put back through the bits): the same operations as the Rust
// side, not libm's or the GPU's own exponential.
NIS_HD float nis_exp(float x) {
    x = fminf(fmaxf(x, -87.0f), 88.0f);
    const float shifter = 12582912.0f;
    float t = x * 1.44269504088896341f + shifter;
    float n = t - shifter;
    int ni = (int)(nis_float_to_bits(t) - nis_float_to_bits(shifter));
    float r = x - n * 0.69314575f - n * 1.4286068e-6f;
    float p = 1.0f + r * (1.0f + r * (0.5f + r * (1.0f / 6.0f + r * (1.0f / 24.0f + r * (1.0f / 120.0f + r * (1.0f / 720.0f))))));
    return p * nis_bits_to_float((unsigned int)(ni + 127) << 23);
}

// ln(1 + t) for t in [0, 1] as nis's ln_1p_unit: 2·atanh(t/(2 + t)) by its odd series.
NIS_HD float nis_ln_1p_unit(float t) {
    float s = t / (2.0f + t);
    float s2 = s * s;
    return 2.0f * s * (1.0f + s2 * (1.0f / 3.0f + s2 * (1.0f / 5.0f + s2 * (1.0f / 7.0f + s2 * (1.0f / 9.0f + s2 * (1.0f / 11.0f + s2 / 13.0f))))));
}
NIS_HD double nis_clamp01(double v) { return fmin(fmax(v, 0.0), 1.0); }

// ---- Random numbers: SplitMix64 of (seed, counter), a counter-based stream -------------------

// The 64-bit finaliser of SplitMix64 (Steele, Lea, Flood 2014).
NIS_HD nis_u64 nis_mix64(nis_u64 z) {
    z = (z ^ (z >> 30)) * 0xbf58476d1ce4e5b9ULL;
    z = (z ^ (z >> 27)) * 0x94d049bb133111ebULL;
    return z ^ (z >> 31);
}

// Uniform on [0, 1) in f32 (24 random bits) for counter `i` of stream `seed`: the value does not
// depend on how the counters are split over threads.
NIS_HD float nis_uniform_at(nis_u64 seed, nis_u64 i) {
    nis_u64 z = nis_mix64(seed * 0x9e3779b97f4a7c15ULL + 0x632be59bd9b4e019ULL);
    z = nis_mix64(z + (i + 1) * 0x9e3779b97f4a7c15ULL);
    return (float)(z >> 40) * (1.0f / 16777216.0f);
}

// ---- One-blob encoding (Müller et al. 2019, Sec. 4.3) -----------------------------------------

// e_j = exp(−(k²/2)((j + ½)/k − s)²).
NIS_HD float nis_one_blob(float s, int k, int j) {
    float kf = (float)k;
    float d = ((float)j + 0.5f) / kf - s;
    return nis_exp(-0.5f * kf * kf * d * d);
}

// ---- Piecewise-quadratic (nis::transform::quadratic) ------------------------------------------

// w = floor/K + (1 − floor)·softmax(logits), in f32; returns nothing, fills w[0..k).
NIS_HD void nis_softmax_floor_f(const float* l, int k, float floor, float* w) {
    float m = l[0];
    for (int i = 1; i < k; ++i) m = fmaxf(m, l[i]);
    float sum = -0.0f;
    for (int i = 0; i < k; ++i) {
        w[i] = nis_exp(l[i] - m);
        sum += w[i];
    }
    float scale = (1.0f - floor) / sum;
    float base = floor / (float)k;
    for (int i = 0; i < k; ++i) w[i] = base + scale * w[i];
}

// Widths W, vertex heights V (the trapezoids' area one) and the totals as computed.
NIS_HD void nis_pq_knots(const float* p, int k, float* w, float* v, float* x_tot, float* y_tot) {
    nis_softmax_floor_f(p, k, NIS_PQ_MIN_W, w);
    const float* lv = p + k;
    float m = lv[0];
    for (int j = 1; j <= k; ++j) m = fmaxf(m, lv[j]);
    for (int j = 0; j <= k; ++j) v[j] = nis_exp(lv[j] - m);
    float norm = -0.0f;
    for (int i = 0; i < k; ++i) norm += 0.5f * (v[i] + v[i + 1]) * w[i];
    float scale = (1.0f - NIS_PQ_MIN_V) / norm;
    for (int j = 0; j <= k; ++j) v[j] = NIS_PQ_MIN_V + scale * v[j];
    float xt = 0.0f, yt = 0.0f;
    for (int i = 0; i < k; ++i) {
        xt += w[i];
        yt += 0.5f * (v[i] + v[i + 1]) * w[i];
    }
    *x_tot = xt;
    *y_tot = yt;
}

// The bin of t (in x, or in y when in_y): its index, left edge and CDF there.
NIS_HD int nis_pq_locate(const float* w, const float* v, int k, float t, int in_y, float* edge,
                         float* cdf) {
    int b = 0;
    float e = 0.0f, c = 0.0f, xr = 0.0f, yr = 0.0f;
    for (int j = 1; j < k; ++j) {
        yr += 0.5f * (v[j - 1] + v[j]) * w[j - 1];
        xr += w[j - 1];
        int reached = in_y ? !(t < yr) : (t >= xr);
        if (reached) {
            b = j;
            e = xr;
            c = yr;
        }
    }
    *edge = e;
    *cdf = c;
    return b;
}

// y = C(x) (inverse == 0) or x = C⁻¹(y) (inverse == 1) of one scalar with parameters p (2k + 1
// of them); returns the transformed value and writes ln C' at the data-side point.
NIS_HD float nis_pq(const float* p, int k, float t, int inverse, double* log_det) {
    float w[NIS_MAX_BINS], v[NIS_MAX_BINS + 1];
    float xt, yt, edge, cdf, out, alpha;
    nis_pq_knots(p, k, w, v, &xt, &yt);
    if (!inverse) {
        float xs = t * xt;
        int b = nis_pq_locate(w, v, k, xs, 0, &edge, &cdf);
        float wb = w[b], v0 = v[b], dv = v[b + 1] - v[b];
        alpha = nis_clamp01f((xs - edge) / wb);
        out = nis_clamp01f((cdf + wb * alpha * (v0 + 0.5f * alpha * dv)) / yt);
        *log_det = log((double)((v0 + alpha * dv) * (xt / yt)));
    } else {
        float ys = t * yt;
        int b = nis_pq_locate(w, v, k, ys, 1, &edge, &cdf);
        float wb = w[b], v0 = v[b], dv = v[b + 1] - v[b];
        float a = 0.5f * dv * wb, bq = v0 * wb, c = fmaxf(ys - cdf, 0.0f);
        float disc = fmaxf(bq * bq + 4.0f * a * c, 0.0f);
        alpha = nis_clamp01f(2.0f * c / (bq + sqrtf(disc)));
        out = nis_clamp01f((edge + alpha * wb) / xt);
        *log_det = log((double)((v0 + alpha * dv) * (xt / yt)));
    }
    return out;
}

// ---- Rational-quadratic (nis::transform::rational_quadratic) ----------------------------------

NIS_HD void nis_softmax_floor_d(const float* l, int k, double floor, double* w) {
    float m = l[0];
    for (int i = 1; i < k; ++i) m = fmaxf(m, l[i]);
    double sum = -0.0;
    for (int i = 0; i < k; ++i) {
        w[i] = (double)nis_exp(l[i] - m);
        sum += w[i];
    }
    double scale = (1.0 - floor) / sum;
    double base = floor / (double)k;
    for (int i = 0; i < k; ++i) w[i] = base + scale * w[i];
}

// y = C(x) or x = C⁻¹(y) of one scalar with parameters p (3k + 1 of them); ln C' as for nis_pq.
NIS_HD double nis_rq(const float* p, int k, double t, int inverse, double* log_det) {
    double w[NIS_MAX_BINS], h[NIS_MAX_BINS];
    double d0, d1;
    nis_softmax_floor_d(p, k, NIS_RQ_MIN_W, w);
    nis_softmax_floor_d(p + k, k, 0.0, h);
    for (int i = 0; i < k; ++i) h[i] = NIS_RQ_MIN_SLOPE * w[i] + (1.0 - NIS_RQ_MIN_SLOPE) * h[i];
    // softplus⁻¹(1 − m), so that zero parameters give unit derivatives.
    const float shift = (float)log(exp(1.0 - NIS_RQ_MIN_D) - 1.0);
    int b = 0;
    double x0 = 0.0, y0 = 0.0;
    if (!inverse) {
        while (b + 1 < k && t >= x0 + w[b]) {
            x0 += w[b];
            y0 += h[b];
            ++b;
        }
    } else {
        while (b + 1 < k && t >= y0 + h[b]) {
            x0 += w[b];
            y0 += h[b];
            ++b;
        }
    }
    {
        float u0 = p[2 * k + b] + shift, u1 = p[2 * k + b + 1] + shift;
        d0 = (double)(fmaxf(u0, 0.0f) + nis_ln_1p_unit(nis_exp(-fabsf(u0)))) + NIS_RQ_MIN_D;
        d1 = (double)(fmaxf(u1, 0.0f) + nis_ln_1p_unit(nis_exp(-fabsf(u1)))) + NIS_RQ_MIN_D;
    }
    double wb = w[b], hb = h[b], s = hb / wb, sum = d1 + d0 - 2.0 * s, xi, out;
    if (!inverse) {
        xi = nis_clamp01((t - x0) / wb);
        double tt = xi * (1.0 - xi);
        out = nis_clamp01(y0 + hb * (s * xi * xi + d0 * tt) / (s + sum * tt));
    } else {
        double dy = fmin(fmax(t - y0, 0.0), hb);
        double a = hb * (s - d0) + dy * sum, bb = hb * d0 - dy * sum, c = -s * dy;
        double disc = fmax(bb * bb - 4.0 * a * c, 0.0);
        xi = c == 0.0 ? 0.0 : nis_clamp01(2.0 * c / (-bb - sqrt(disc)));
        out = nis_clamp01(x0 + xi * wb);
    }
    double tt = xi * (1.0 - xi);
    double den = s + sum * tt;
    double dnum = d1 * xi * xi + 2.0 * s * tt + d0 * (1.0 - xi) * (1.0 - xi);
    *log_det = 2.0 * log(s) + log(dnum) - 2.0 * log(den);
    return out;
}

// ---- Reverse mode of the transforms (nis::transform, `backward`) -----------------------------

// From ∂L/∂out of the floored softmax and its output, ∂L/∂logits (f32 gradients).
NIS_HD void nis_softmax_floor_backward_f(const float* out, const float* g_out, int k, float floor,
                                         float* g_logits) {
    float base = floor / (float)k;
    float inv = 1.0f / (1.0f - floor);
    float dot = -0.0f;
    for (int i = 0; i < k; ++i) dot += (out[i] - base) * inv * g_out[i];
    for (int j = 0; j < k; ++j) g_logits[j] = (out[j] - base) * (g_out[j] - dot);
}

NIS_HD void nis_softmax_floor_backward_d(const double* out, const double* g_out, int k,
                                         double floor, float* g_logits) {
    double base = floor / (double)k;
    double inv = 1.0 / (1.0 - floor);
    double dot = -0.0;
    for (int i = 0; i < k; ++i) dot += (out[i] - base) * inv * g_out[i];
    for (int j = 0; j < k; ++j) g_logits[j] = (float)((out[j] - base) * (g_out[j] - dot));
}

// Piecewise-quadratic at the data-side point x: writes ∂L/∂p (2k + 1 values) for L with
// ∂L/∂y = g_y and ∂L/∂ln C' = g_ld; returns ∂L/∂x. In f32, as the Rust transform.
NIS_HD float nis_pq_backward(const float* p, int k, float x, float g_y, float g_ld, float* g_p) {
    float w[NIS_MAX_BINS], v[NIS_MAX_BINS + 1], e[NIS_MAX_BINS + 1];
    float g_w[NIS_MAX_BINS], g_v[NIS_MAX_BINS + 1];
    nis_softmax_floor_f(p, k, NIS_PQ_MIN_W, w);
    const float* lv = p + k;
    float m = lv[0];
    for (int j = 1; j <= k; ++j) m = fmaxf(m, lv[j]);
    for (int j = 0; j <= k; ++j) e[j] = nis_exp(lv[j] - m);
    float norm = -0.0f;
    for (int i = 0; i < k; ++i) norm += 0.5f * (e[i] + e[i + 1]) * w[i];
    float scale = (1.0f - NIS_PQ_MIN_V) / norm;
    for (int j = 0; j <= k; ++j) v[j] = NIS_PQ_MIN_V + scale * e[j];
    float xt = 0.0f;
    for (int i = 0; i < k; ++i) xt += w[i];
    for (int i = 0; i < k; ++i) g_w[i] = 0.0f;
    for (int j = 0; j <= k; ++j) g_v[j] = 0.0f;
    float edge, cdf;
    float xs = x * xt;
    int b = nis_pq_locate(w, v, k, xs, 0, &edge, &cdf);
    float wb = w[b];
    float alpha = nis_clamp01f((xs - edge) / wb);
    float v0 = v[b], v1 = v[b + 1], dv = v1 - v0;
    float q = v0 + alpha * dv;
    float g_q = g_ld / q;
    float g_alpha = g_y * wb * q + g_q * dv;
    g_v[b] += g_y * wb * (alpha - 0.5f * alpha * alpha) + g_q * (1.0f - alpha);
    g_v[b + 1] += g_y * wb * 0.5f * alpha * alpha + g_q * alpha;
    g_w[b] += g_y * alpha * (v0 + 0.5f * alpha * dv);
    float g_x = g_alpha / wb;
    float g_edge = -g_alpha / wb;
    g_w[b] -= g_alpha * alpha / wb;
    for (int i = 0; i < b; ++i) {
        float t = 0.5f * g_y * w[i];
        g_v[i] += t;
        g_v[i + 1] += t;
        g_w[i] += g_y * 0.5f * (v[i] + v[i + 1]) + g_edge;
    }
    float sv = -0.0f;
    for (int j = 0; j <= k; ++j) sv += g_v[j] * e[j];
    sv = sv * scale / norm;
    for (int i = 0; i < k; ++i) g_w[i] -= sv * 0.5f * (e[i] + e[i + 1]);
    for (int j = 0; j <= k; ++j) {
        float left = j > 0 ? w[j - 1] : 0.0f;
        float right = j < k ? w[j] : 0.0f;
        float dn = 0.5f * (left + right);
        g_p[k + j] = (g_v[j] * scale - sv * dn) * e[j];
    }
    nis_softmax_floor_backward_f(w, g_w, k, NIS_PQ_MIN_W, g_p);
    return g_x;
}

// Rational-quadratic at the data-side point x, as nis_pq_backward (f64 inside, 3k + 1 values).
NIS_HD double nis_rq_backward(const float* p, int k, double x, double g_y, double g_ld,
                              float* g_p) {
    double w[NIS_MAX_BINS], h[NIS_MAX_BINS], hs[NIS_MAX_BINS];
    double g_w[NIS_MAX_BINS], g_hh[NIS_MAX_BINS];
    nis_softmax_floor_d(p, k, NIS_RQ_MIN_W, w);
    nis_softmax_floor_d(p + k, k, 0.0, hs);
    for (int i = 0; i < k; ++i) h[i] = NIS_RQ_MIN_SLOPE * w[i] + (1.0 - NIS_RQ_MIN_SLOPE) * hs[i];
    const float shift = (float)log(exp(1.0 - NIS_RQ_MIN_D) - 1.0);
    for (int i = 0; i < k; ++i) g_w[i] = g_hh[i] = 0.0;
    int b = 0;
    double x0 = 0.0;
    while (b + 1 < k && x >= x0 + w[b]) {
        x0 += w[b];
        ++b;
    }
    float u0 = p[2 * k + b] + shift, u1 = p[2 * k + b + 1] + shift;
    double d0 = (double)(fmaxf(u0, 0.0f) + nis_ln_1p_unit(nis_exp(-fabsf(u0)))) + NIS_RQ_MIN_D;
    double d1 = (double)(fmaxf(u1, 0.0f) + nis_ln_1p_unit(nis_exp(-fabsf(u1)))) + NIS_RQ_MIN_D;
    double wb = w[b], hb = h[b], s = hb / wb;
    double xi = nis_clamp01((x - x0) / wb);
    double t = xi * (1.0 - xi);
    double num = hb * (s * xi * xi + d0 * t);
    double den = s + (d1 + d0 - 2.0 * s) * t;
    double dnum = d1 * xi * xi + 2.0 * s * t + d0 * (1.0 - xi) * (1.0 - xi);
    double g_s = 0.0, g_h = 0.0, g_d0 = 0.0, g_d1 = 0.0, g_xi = 0.0, g_t = 0.0;
    double g_num = g_y / den;
    double g_den = -g_y * num / (den * den);
    g_s += 2.0 * g_ld / s;
    double g_dnum = g_ld / dnum;
    g_den -= 2.0 * g_ld / den;
    g_h += g_num * (s * xi * xi + d0 * t);
    g_s += g_num * hb * xi * xi;
    g_d0 += g_num * hb * t;
    g_xi += g_num * hb * 2.0 * s * xi;
    g_t += g_num * hb * d0;
    g_s += g_den * (1.0 - 2.0 * t);
    g_d0 += g_den * t;
    g_d1 += g_den * t;
    g_t += g_den * (d1 + d0 - 2.0 * s);
    g_d1 += g_dnum * xi * xi;
    g_xi += g_dnum * (2.0 * d1 * xi - 2.0 * d0 * (1.0 - xi));
    g_s += g_dnum * 2.0 * t;
    g_t += g_dnum * 2.0 * s;
    g_d0 += g_dnum * (1.0 - xi) * (1.0 - xi);
    g_xi += g_t * (1.0 - 2.0 * xi);
    g_h += g_s / wb;
    double g_w_b = -g_s * hb / (wb * wb) - g_xi * xi / wb;
    double g_x = g_xi / wb;
    double g_x0 = -g_xi / wb;
    for (int i = 0; i < b; ++i) {
        g_w[i] += g_x0;
        g_hh[i] += g_y;
    }
    g_hh[b] += g_h;
    g_w[b] += g_w_b;
    double g_soft[NIS_MAX_BINS];
    for (int i = 0; i < k; ++i) {
        g_w[i] += NIS_RQ_MIN_SLOPE * g_hh[i];
        g_soft[i] = (1.0 - NIS_RQ_MIN_SLOPE) * g_hh[i];
    }
    nis_softmax_floor_backward_d(w, g_w, k, NIS_RQ_MIN_W, g_p);
    nis_softmax_floor_backward_d(hs, g_soft, k, 0.0, g_p + k);
    for (int j = 0; j <= k; ++j) g_p[2 * k + j] = 0.0f;
    double sig0 = (double)(1.0f / (1.0f + nis_exp(-(p[2 * k + b] + shift))));
    double sig1 = (double)(1.0f / (1.0f + nis_exp(-(p[2 * k + b + 1] + shift))));
    g_p[2 * k + b] = (float)(g_d0 * sig0);
    g_p[2 * k + b + 1] = (float)(g_d1 * sig1);
    return g_x;
}

// One-blob's reverse mode for one scalar: ∂L/∂s = Σ_j ∂L/∂e_j · e_j · k²((j + ½)/k − s).
NIS_HD float nis_one_blob_backward(float s, int k, const float* e, const float* g_e) {
    float kf = (float)k, k2 = kf * kf, g = 0.0f;
    for (int j = 0; j < k; ++j) g += g_e[j] * e[j] * k2 * (((float)j + 0.5f) / kf - s);
    return g;
}

// Adam's update of one parameter (nis::kernels::elementwise::adam); lr_t carries the bias
// corrections and the decay, grad_scale the clipping.
NIS_HD void nis_adam_one(float* p, float g, float* m, float* v, float lr_t, float beta1,
                         float beta2, float eps, float grad_scale) {
    float gi = g * grad_scale;
    *m = beta1 * *m + (1.0f - beta1) * gi;
    *v = beta2 * *v + (1.0f - beta2) * gi * gi;
    *p -= lr_t * *m / (sqrtf(*v) + eps);
}

// ---- One coupling's transforms for one row ----------------------------------------------------

// Transforms the B dimensions `b[0..nb)` of row r of `u` (dim values a row) with the
// conditioner's output `out` (row-major, nb·np values a row, dimension k's np parameters at k·np)
// and adds the row's Σ ln C' to log_q[r]. kind 0: piecewise-quadratic, 1: rational-quadratic.
NIS_HD void nis_coupling_row(int kind, int bins, int inverse, const float* out, float* u,
                             double* log_q, long long r, int dim, const int* b, int nb) {
    int np = kind == 0 ? 2 * bins + 1 : 3 * bins + 1;
    double ld_row = 0.0;
    for (int k = 0; k < nb; ++k) {
        const float* p = out + (r * nb + k) * (long long)np;
        float* t = u + r * dim + b[k];
        double ld;
        if (kind == 0) {
            *t = nis_pq(p, bins, *t, inverse, &ld);
        } else {
            *t = (float)nis_rq(p, bins, (double)*t, inverse, &ld);
        }
        ld_row += ld;
    }
    log_q[r] += ld_row;
}

// Reverse mode of one coupling's transforms for row r: `input` is the layer's data-side input,
// g_u holds ∂L/∂(layer output) on entry and ∂L/∂(layer input) for the B dimensions on exit,
// g_ld is ∂L/∂ln C' of the row; ∂L/∂(conditioner output) goes to g_out (laid out as out).
NIS_HD void nis_coupling_backward_row(int kind, int bins, const float* out, const float* input,
                                      float* g_u, const float* g_ld, float* g_out, long long r,
                                      int dim, const int* b, int nb) {
    int np = kind == 0 ? 2 * bins + 1 : 3 * bins + 1;
    for (int k = 0; k < nb; ++k) {
        long long at = (r * nb + k) * (long long)np;
        long long i = r * dim + b[k];
        if (kind == 0) {
            g_u[i] = nis_pq_backward(out + at, bins, input[i], g_u[i], g_ld[r], g_out + at);
        } else {
            g_u[i] = (float)nis_rq_backward(out + at, bins, (double)input[i], (double)g_u[i],
                                            (double)g_ld[r], g_out + at);
        }
    }
}

#ifdef NIS_GPU
// ---- The kernels -------------------------------------------------------------------------------

extern "C" __global__ void nis_uniform(float* u, nis_u64 n, nis_u64 seed) {
    nis_u64 i = (nis_u64)blockIdx.x * blockDim.x + threadIdx.x;
    if (i < n) u[i] = nis_uniform_at(seed, i);
}

// The conditioner's input of `rows` rows: the one-blob code of each A dimension (k bins each).
// Launched on a 2-D grid, blocks of 8 rows × 32 columns (a warp writes 32 neighbours of a row):
// no 64-bit division per value.
extern "C" __global__ void nis_encode(const float* u, int dim, const int* a, int na, int k,
                                      float* enc, long long rows) {
    long long r = (long long)blockIdx.x * blockDim.y + threadIdx.y;
    int c = blockIdx.y * blockDim.x + threadIdx.x;
    int width = na * k;
    if (r >= rows || c >= width) return;
    int ai = c / k;
    enc[r * width + c] = nis_one_blob(u[r * dim + a[ai]], k, c - ai * k);
}

// y += bias (broadcast over rows), then ReLU when relu != 0; y row-major [rows, o]. The same
// 2-D grid as nis_encode: the column is the bias's index.
extern "C" __global__ void nis_bias_act(float* y, const float* bias, long long rows, int o,
                                        int relu) {
    long long r = (long long)blockIdx.x * blockDim.y + threadIdx.y;
    int c = blockIdx.y * blockDim.x + threadIdx.x;
    if (r >= rows || c >= o) return;
    long long i = r * o + c;
    float v = y[i] + bias[c];
    y[i] = relu ? fmaxf(v, 0.0f) : v;
}

extern "C" __global__ void nis_coupling(int kind, int bins, int inverse, const float* out,
                                        float* u, double* log_q, long long rows, int dim,
                                        const int* b, int nb) {
    long long r = (long long)blockIdx.x * blockDim.x + threadIdx.x;
    if (r < rows) nis_coupling_row(kind, bins, inverse, out, u, log_q, r, dim, b, nb);
}

extern "C" __global__ void nis_coupling_backward(int kind, int bins, const float* out,
                                                 const float* input, float* g_u,
                                                 const float* g_ld, float* g_out, long long rows,
                                                 int dim, const int* b, int nb) {
    long long r = (long long)blockIdx.x * blockDim.x + threadIdx.x;
    if (r < rows) nis_coupling_backward_row(kind, bins, out, input, g_u, g_ld, g_out, r, dim, b, nb);
}

// Adds the encoding's share to ∂L/∂u for each A dimension: one thread per (row, A dimension).
extern "C" __global__ void nis_encode_backward(const float* input, int dim, const int* a, int na,
                                               int k, const float* enc, const float* g_enc,
                                               int width, float* g_u, long long rows) {
    long long i = (long long)blockIdx.x * blockDim.x + threadIdx.x;
    if (i >= rows * na) return;
    long long r = i / na;
    int ai = (int)(i - r * na);
    long long at = r * width + (long long)ai * k;
    g_u[r * dim + a[ai]] += nis_one_blob_backward(input[r * dim + a[ai]], k, enc + at, g_enc + at);
}

// ∂L/∂(pre-activation) of a ReLU layer from ∂L/∂(activation) and the activation.
extern "C" __global__ void nis_relu_backward(float* g, const float* act, long long n) {
    long long i = (long long)blockIdx.x * blockDim.x + threadIdx.x;
    if (i < n && !(act[i] > 0.0f)) g[i] = 0.0f;
}

// Σ g² of each block of `chunk` values, in f64 and in a fixed order (a deterministic norm).
extern "C" __global__ void nis_sum_squares(const float* g, long long n, long long chunk,
                                           double* partial) {
    long long c = (long long)blockIdx.x * blockDim.x + threadIdx.x;
    long long lo = c * chunk;
    if (lo >= n) return;
    long long hi = lo + chunk < n ? lo + chunk : n;
    double s = 0.0;
    for (long long i = lo; i < hi; ++i) s += (double)g[i] * (double)g[i];
    partial[c] = s;
}

extern "C" __global__ void nis_adam(float* p, const float* g, float* m, float* v, long long n,
                                    float lr_t, float beta1, float beta2, float eps,
                                    float grad_scale) {
    long long i = (long long)blockIdx.x * blockDim.x + threadIdx.x;
    if (i < n) nis_adam_one(p + i, g[i], m + i, v + i, lr_t, beta1, beta2, eps, grad_scale);
}
#endif
#endif
