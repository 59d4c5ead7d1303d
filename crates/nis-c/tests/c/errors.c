/*
 * errors.c: the C ABI's error paths and its vector results, from C. Compiled, linked against
 * libnis_c.a and run by tests/c_programs.rs; prints one line per failed check and exits non-zero
 * if any failed.
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "nis.h"

static int failures = 0, checks = 0;

#define CHECK(cond)                                                                   \
    do {                                                                              \
        checks++;                                                                     \
        if (!(cond)) {                                                                \
            failures++;                                                               \
            printf("FAILED line %d: %s (last error: %s)\n", __LINE__, #cond,          \
                   nis_last_error_message());                                         \
        }                                                                             \
    } while (0)

static int has(const char *s) { return strstr(nis_last_error_message(), s) != NULL; }

static int product(const double *x, size_t n, size_t dim, double *out, void *user) {
    (void)user;
    for (size_t i = 0; i < n; i++) {
        out[i] = 1.0;
        for (size_t j = 0; j < dim; j++) out[i] *= 2.0 * x[i * dim + j];
    }
    return 0;
}

static int refuses(const double *x, size_t n, size_t dim, double *out, void *user) {
    (void)x, (void)n, (void)dim, (void)out;
    ++*(int *)user;
    return 7;
}

static int nan_at_half(const double *x, size_t n, size_t dim, double *out, void *user) {
    (void)user;
    for (size_t i = 0; i < n; i++) out[i] = x[i * dim] > 0.5 ? NAN : 1.0;
    return 0;
}

/* Two components: f = 1 + x1 and x0·f; ∫ = 1.5 and 0.75. */
static int pair(const double *x, size_t n, size_t dim, double *out, void *user) {
    (void)user;
    for (size_t i = 0; i < n; i++) {
        double f = 1.0 + x[i * dim + 1];
        out[2 * i] = f;
        out[2 * i + 1] = x[i * dim] * f;
    }
    return 0;
}

int main(void) {
    nis_integrator *integ = (nis_integrator *)1;
    nis_result r;

    /* Version. */
    CHECK(strcmp(nis_version(), NIS_VERSION_STRING) == 0);

    /* Bad configs: syntax, unknown fields (top level and in a section), bad values. */
    CHECK(nis_create("{\"method\": \"nis\", \"dim\": ", &integ) == NIS_ERR_CONFIG);
    CHECK(integ == NULL);
    CHECK(has("JSON"));
    CHECK(nis_create("{\"method\": \"nis\", \"dim\": 2, \"colour\": 1}", &integ) == NIS_ERR_CONFIG);
    CHECK(has("unknown field") && has("colour"));
    CHECK(nis_create("{\"method\": \"nis\", \"dim\": 2, \"nis\": {\"bach\": 9}}", &integ)
          == NIS_ERR_CONFIG);
    CHECK(has("bach"));
    CHECK(nis_create("{\"method\": \"simpson\", \"dim\": 2}", &integ) == NIS_ERR_CONFIG);
    CHECK(nis_create("{\"method\": \"nis\", \"dim\": 2, \"nis\": {\"batch\": 1}}", &integ)
          == NIS_ERR_CONFIG);
    CHECK(nis_create("{\"method\": \"vegas\", \"dim\": 0}", &integ) == NIS_ERR_CONFIG);
    CHECK(nis_create("{\"method\": \"uniform\", \"dim\": 2, \"components\": 0}", &integ)
          == NIS_ERR_CONFIG);

    /* NULL pointers. */
    CHECK(nis_create(NULL, &integ) == NIS_ERR_NULL_POINTER);
    CHECK(nis_create("{\"method\": \"uniform\", \"dim\": 2}", NULL) == NIS_ERR_NULL_POINTER);
    CHECK(nis_integrate(NULL, product, NULL, 1000, &r) == NIS_ERR_NULL_POINTER);
    CHECK(nis_result_estimates(NULL, NULL, NULL, NULL, 1) == NIS_ERR_NULL_POINTER);
    CHECK(nis_save(NULL, "x") == NIS_ERR_NULL_POINTER);
    CHECK(nis_load(NULL, &integ) == NIS_ERR_NULL_POINTER);
    CHECK(nis_dim(NULL) == 0);
    nis_free(NULL);

    /* A plain MC integrator: the happy path, then the integrand's failures. */
    CHECK(nis_create("{\"method\": \"uniform\", \"dim\": 3, \"seed\": 2}", &integ) == NIS_OK);
    CHECK(nis_dim(integ) == 3);
    CHECK(nis_result_estimates(integ, NULL, NULL, NULL, 1) == NIS_ERR_NO_RESULT);
    CHECK(nis_integrate(integ, NULL, NULL, 1000, &r) == NIS_ERR_NULL_POINTER);
    CHECK(nis_integrate(integ, product, NULL, 0, &r) == NIS_ERR_INVALID_ARGUMENT);
    CHECK(nis_integrate(integ, product, NULL, 100000, &r) == NIS_OK);
    CHECK(fabs(r.value - 1.0) < 5.0 * r.std_err && r.components == 1 && r.n_eval == 100000);
    double mean, err, cov;
    CHECK(nis_result_estimates(integ, &mean, &err, &cov, 1) == NIS_OK);
    CHECK(mean == r.value && err == r.std_err && cov == r.std_err * r.std_err);
    CHECK(nis_result_estimates(integ, &mean, NULL, NULL, 2) == NIS_ERR_INVALID_ARGUMENT);

    int calls = 0;
    CHECK(nis_integrate(integ, refuses, &calls, 1000, &r) == NIS_ERR_CALLBACK);
    CHECK(nis_last_callback_status() == 7 && calls == 1);
    CHECK(has("returned 7"));
    CHECK(nis_integrate(integ, nan_at_half, NULL, 1000, &r) == NIS_ERR_NON_FINITE);
    CHECK(has("NaN"));
    /* The last good result survives failed calls. */
    CHECK(nis_result_estimates(integ, &mean, NULL, NULL, 1) == NIS_OK && mean != 0.0);

    /* What only NIS does. */
    double x[6], w[2];
    CHECK(nis_sample(integ, 2, x, w) == NIS_ERR_UNSUPPORTED);
    CHECK(nis_save(integ, "never.safetensors") == NIS_ERR_UNSUPPORTED);
    CHECK(nis_set_seed(integ, 3) == NIS_ERR_UNSUPPORTED);

    /* The last error message, copied for Fortran-style callers, truncated to fit. */
    char buffer[8];
    size_t len = nis_last_error_copy(buffer, sizeof buffer);
    CHECK(len == strlen(nis_last_error_message()) && len > 7);
    CHECK(strlen(buffer) == 7 && strncmp(buffer, nis_last_error_message(), 7) == 0);
    CHECK(nis_last_error_copy(NULL, 0) == len);
    nis_free(integ);

    /* A vector integrand through VEGAS+: both components with their covariance. */
    CHECK(nis_create("{\"method\": \"vegas\", \"dim\": 2, \"seed\": 4, \"components\": 2}", &integ)
          == NIS_OK);
    CHECK(nis_integrate(integ, pair, NULL, 50000, &r) == NIS_OK);
    CHECK(r.components == 2);
    double m2[2], e2[2], c2[4];
    CHECK(nis_result_estimates(integ, m2, e2, c2, 2) == NIS_OK);
    CHECK(fabs(m2[0] - 1.5) < 5.0 * e2[0] && fabs(m2[1] - 0.75) < 5.0 * e2[1]);
    CHECK(m2[0] == r.value && e2[0] == r.std_err);
    CHECK(fabs(c2[0] - e2[0] * e2[0]) <= 1e-12 * c2[0] && c2[1] == c2[2]);
    /* Two positively correlated components: the covariance is positive. */
    CHECK(c2[1] > 0.0);
    nis_free(integ);

    /* NIS: sampling before and after training, bad sizes, files. */
    CHECK(nis_create("{\"method\": \"nis\", \"dim\": 3, \"seed\": 5, \"nis\": {\"batch\": 256}}",
                     &integ) == NIS_OK);
    CHECK(nis_sample(integ, 0, x, w) == NIS_ERR_INVALID_ARGUMENT);
    CHECK(nis_sample(integ, 2, NULL, w) == NIS_ERR_NULL_POINTER);
    CHECK(nis_sample(integ, 2, x, NULL) == NIS_ERR_NULL_POINTER);
    CHECK(nis_sample(integ, 2, x, w) == NIS_OK);
    CHECK(x[0] >= 0.0 && x[0] <= 1.0 && w[0] > 0.0);
    CHECK(nis_sample(integ, (size_t)-1, x, w) == NIS_ERR_INVALID_ARGUMENT);
    CHECK(nis_unweighted(integ, product, NULL, 2, 0.7, x, w) == NIS_ERR_INVALID_ARGUMENT);
    CHECK(nis_unweighted(integ, product, NULL, 2, 1e-3, NULL, w) == NIS_ERR_NULL_POINTER);
    CHECK(nis_sample_weighted(integ, NULL, NULL, 2, x, w) == NIS_ERR_NULL_POINTER);
    CHECK(nis_sample_weighted(integ, refuses, &calls, 2, x, w) == NIS_ERR_CALLBACK);
    CHECK(nis_sample_weighted(integ, product, NULL, 2, x, w) == NIS_OK);
    nis_free(integ);
    CHECK(nis_load("/nonexistent/model.safetensors", &integ) == NIS_ERR_FILE);
    CHECK(integ == NULL && has("/nonexistent/model.safetensors"));

    printf("errors.c: %d checks, %d failed\n", checks, failures);
    return failures == 0 ? 0 : 1;
}
