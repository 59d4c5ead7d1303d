// The coupling flow's elementwise kernels, written once for two compilers: NVRTC builds the
// `__global__` kernels at the end for the GPU; the C++ harness (harness.cpp, built by the crate's
// build script with `cc`) runs the same per-thread bodies on the CPU in the tests, against the
// Rust transforms of `nis::transform`. The arithmetic follows those transforms step by step:
// piecewise-quadratic in f32 with ln C' in f64, rational-quadratic in f64 from f32 parameters.
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
// Taylor polynomial, the exponent put back through the bits), so both sides give one number.
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

#ifdef NIS_GPU
// ---- The kernels -------------------------------------------------------------------------------

extern "C" __global__ void nis_uniform(float* u, nis_u64 n, nis_u64 seed) {
    nis_u64 i = (nis_u64)blockIdx.x * blockDim.x + threadIdx.x;
    if (i < n) u[i] = nis_uniform_at(seed, i);
}

// The conditioner's input of `rows` rows: the one-blob code of each A dimension (k bins each).
extern "C" __global__ void nis_encode(const float* u, int dim, const int* a, int na, int k,
                                      float* enc, long long rows) {
    long long i = (long long)blockIdx.x * blockDim.x + threadIdx.x;
    long long width = (long long)na * k;
    if (i >= rows * width) return;
    long long r = i / width;
    int c = (int)(i - r * width), ai = c / k, j = c - ai * k;
    enc[i] = nis_one_blob(u[r * dim + a[ai]], k, j);
}

// y += bias (broadcast over rows), then ReLU when relu != 0; y row-major [rows, o].
extern "C" __global__ void nis_bias_act(float* y, const float* bias, long long rows, int o,
                                        int relu) {
    long long i = (long long)blockIdx.x * blockDim.x + threadIdx.x;
    if (i >= rows * o) return;
    float v = y[i] + bias[i % o];
    y[i] = relu ? fmaxf(v, 0.0f) : v;
}

extern "C" __global__ void nis_coupling(int kind, int bins, int inverse, const float* out,
                                        float* u, double* log_q, long long rows, int dim,
                                        const int* b, int nb) {
    long long r = (long long)blockIdx.x * blockDim.x + threadIdx.x;
    if (r < rows) nis_coupling_row(kind, bins, inverse, out, u, log_q, r, dim, b, nb);
}

extern "C" __global__ void nis_fill_f64(double* v, long long n, double value) {
    long long i = (long long)blockIdx.x * blockDim.x + threadIdx.x;
    if (i < n) v[i] = value;
}
#endif
#endif
