/*
 * camel.c: integrates the 4-d camel (two narrow Gaussians on the diagonal of [0,1]^4, the
 * standard NIS and VEGAS test) with neural importance sampling through the C ABI, checks the
 * estimate against the exact value, and draws unweighted points from the trained integrator.
 *
 *   cargo build --release -p nis-c
 *   cc -O2 -I crates/nis-c/include crates/nis-c/examples/camel.c \
 *      target/release/libnis_c.a -lm -lpthread -ldl -o camel && ./camel
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>

#include "nis.h"

#define DIM 4
static const double A = 0.1; /* width of each bump */

/* f(x) = ½ (a√π)^-d [exp(-|x - ⅓|²/a²) + exp(-|x - ⅔|²/a²)], a whole batch per call. */
static int camel(const double *x, size_t n, size_t dim, double *out, void *user) {
    (void)user;
    const double norm = pow(1.0 / (A * sqrt(M_PI)), (double)dim);
    for (size_t i = 0; i < n; i++) {
        double r1 = 0.0, r2 = 0.0;
        for (size_t j = 0; j < dim; j++) {
            double v = x[i * dim + j];
            r1 += (v - 1.0 / 3.0) * (v - 1.0 / 3.0);
            r2 += (v - 2.0 / 3.0) * (v - 2.0 / 3.0);
        }
        out[i] = 0.5 * norm * (exp(-r1 / (A * A)) + exp(-r2 / (A * A)));
    }
    return 0;
}

static int fail(const char *what) {
    fprintf(stderr, "camel: %s: %s\n", what, nis_last_error_message());
    return 1;
}

int main(void) {
    /* Each bump's mass inside the cube: (½[erf((1-μ)/a) + erf(μ/a)])^d, the same for both. */
    const double exact = pow(0.5 * (erf((2.0 / 3.0) / A) + erf((1.0 / 3.0) / A)), DIM);
    const char *config = "{\"method\": \"nis\", \"dim\": 4, \"seed\": 1,"
                         " \"nis\": {\"batch\": 2048}}";
    nis_integrator *integ = NULL;
    nis_result r;
    printf("nis %s (header %s)\n", nis_version(), NIS_VERSION_STRING);
    if (nis_create(config, &integ) != NIS_OK) return fail("create");
    if (nis_integrate(integ, camel, NULL, 400000, &r) != NIS_OK) return fail("integrate");
    printf("camel %dd: %.6f +- %.6f (exact %.6f), chi2/dof %.2f, n_eval %llu, "
           "rel.var/eval %.3g, unw.eff %.3f, %.2f s\n",
           DIM, r.value, r.std_err, exact, r.chi2_per_dof, (unsigned long long)r.n_eval,
           r.rel_var_per_eval, r.unweighting_efficiency, r.seconds);
    int ok = fabs(r.value - exact) < 5.0 * r.std_err && r.std_err < 0.01 * exact;

    /* Unweighted points: each bump holds half of them, so the mean of x0 is ½. */
    enum { N = 2000 };
    double *x = malloc(sizeof(double) * N * DIM), *w = malloc(sizeof(double) * N);
    if (nis_unweighted(integ, camel, NULL, N, 1e-3, x, w) != NIS_OK) return fail("unweighted");
    double mean = 0.0;
    for (int i = 0; i < N; i++) mean += x[i * DIM] / N;
    /* x0 is ⅓ or ⅔ ± 0.07: its standard deviation is about 0.18, the mean's 0.004. */
    printf("unweighted: %d points, mean x0 %.4f\n", N, mean);
    ok = ok && fabs(mean - 0.5) < 0.03;
    free(x);
    free(w);

    /* To a precision instead of a budget, as Cuba's epsrel: 0.1%, at most 10^7 evaluations. */
    if (nis_integrate_to(integ, camel, NULL, 1e-3, 0.0, 10000000, 0.0, &r) != NIS_OK)
        return fail("integrate_to");
    printf("to 1e-3: %.6f +- %.6f, n_eval %llu, stopped by %s\n", r.value, r.std_err,
           (unsigned long long)r.n_eval,
           nis_result_stop(integ) == NIS_STOP_TARGET ? "the target" : "a limit");
    ok = ok && nis_result_stop(integ) == NIS_STOP_TARGET && r.std_err <= 1e-3 * fabs(r.value) &&
         fabs(r.value - exact) < 5.0 * r.std_err;
    nis_free(integ);
    printf(ok ? "camel: ok\n" : "camel: FAILED\n");
    return ok ? 0 : 1;
}
