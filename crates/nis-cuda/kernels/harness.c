// The CPU side of flow.cuh, in C: the same per-thread bodies the GPU kernels run, exported for
// the crate's tests (src/harness.rs), which check them against nis's Rust transforms.
#include "flow.cuh"

float nis_cpu_uniform(uint64_t seed, uint64_t i) { return nis_uniform_at(seed, i); }

float nis_cpu_one_blob(float s, int k, int j) { return nis_one_blob(s, k, j); }

float nis_cpu_pq(const float* p, int k, float t, int inverse, double* log_det) {
    return nis_pq(p, k, t, inverse, log_det);
}

double nis_cpu_rq(const float* p, int k, double t, int inverse, double* log_det) {
    return nis_rq(p, k, t, inverse, log_det);
}

float nis_cpu_pq_backward(const float* p, int k, float x, float g_y, float g_ld, float* g_p) {
    return nis_pq_backward(p, k, x, g_y, g_ld, g_p);
}

double nis_cpu_rq_backward(const float* p, int k, double x, double g_y, double g_ld, float* g_p) {
    return nis_rq_backward(p, k, x, g_y, g_ld, g_p);
}

float nis_cpu_one_blob_backward(float s, int k, const float* e, const float* g_e) {
    return nis_one_blob_backward(s, k, e, g_e);
}

void nis_cpu_adam(float* p, const float* g, float* m, float* v, long long n, float lr_t,
                  float beta1, float beta2, float eps, float grad_scale) {
    for (long long i = 0; i < n; ++i) {
        nis_adam_one(p + i, g[i], m + i, v + i, lr_t, beta1, beta2, eps, grad_scale);
    }
}

// The kernel nis_coupling_backward's body over all rows.
void nis_cpu_coupling_backward(int kind, int bins, const float* out, const float* input,
                               float* g_u, const float* g_ld, float* g_out, long long rows,
                               int dim, const int* b, int nb) {
    for (long long r = 0; r < rows; ++r) {
        nis_coupling_backward_row(kind, bins, out, input, g_u, g_ld, g_out, r, dim, b, nb);
    }
}

// The kernel nis_coupling's body over all rows, one after another.
void nis_cpu_coupling(int kind, int bins, int inverse, const float* out, float* u, double* log_q,
                      long long rows, int dim, const int* b, int nb) {
    for (long long r = 0; r < rows; ++r) {
        nis_coupling_row(kind, bins, inverse, out, u, log_q, r, dim, b, nb);
    }
}
