// The CPU side of flow.cuh: the same per-thread bodies the GPU kernels run, exported for the
// crate's tests (src/harness.rs), which check them against nis's Rust transforms.
#include "flow.cuh"

extern "C" {

float nis_cpu_uniform(uint64_t seed, uint64_t i) { return nis_uniform_at(seed, i); }

float nis_cpu_one_blob(float s, int k, int j) { return nis_one_blob(s, k, j); }

float nis_cpu_pq(const float* p, int k, float t, int inverse, double* log_det) {
    return nis_pq(p, k, t, inverse, log_det);
}

double nis_cpu_rq(const float* p, int k, double t, int inverse, double* log_det) {
    return nis_rq(p, k, t, inverse, log_det);
}

// The kernel nis_coupling's body over all rows, one after another.
void nis_cpu_coupling(int kind, int bins, int inverse, const float* out, float* u, double* log_q,
                      long long rows, int dim, const int* b, int nb) {
    for (long long r = 0; r < rows; ++r) {
        nis_coupling_row(kind, bins, inverse, out, u, log_q, r, dim, b, nb);
    }
}
}
