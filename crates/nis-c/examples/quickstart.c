/*
 * quickstart.c: the smallest whole program on the C ABI (the README's and docs/guide's C
 * example): integrates f(x) = 2 x0 over [0,1]^2 (exactly 1) with neural importance sampling.
 *
 *   cargo build --release -p nis-c
 *   cc -I crates/nis-c/include crates/nis-c/examples/quickstart.c \
 *      target/release/libnis_c.a -lm -lpthread -ldl -o quickstart && ./quickstart
 */
#include <math.h>
#include <stdio.h>

#include "nis.h"

/* The integrand gets a whole batch: n points of dim coordinates, row-major. Return 0, or
 * non-zero to stop the integration. */
static int f(const double *x, size_t n, size_t dim, double *out, void *user) {
    (void)user;
    for (size_t i = 0; i < n; i++) out[i] = 2.0 * x[i * dim];
    return 0;
}

int main(void) {
    nis_integrator *integ = NULL;
    nis_result r;
    if (nis_create("{\"method\": \"nis\", \"dim\": 2, \"seed\": 1}", &integ) != NIS_OK ||
        nis_integrate(integ, f, NULL, 100000, &r) != NIS_OK) {
        fprintf(stderr, "nis: %s\n", nis_last_error_message());
        nis_free(integ);
        return 1;
    }
    printf("%.6f +- %.6f (exact 1), chi2/dof %.2f, k-hat %.2f\n", r.value, r.std_err,
           r.chi2_per_dof, r.pareto_k);
    nis_free(integ);
    int ok = fabs(r.value - 1.0) < 5.0 * r.std_err;
    printf(ok ? "quickstart: ok\n" : "quickstart: FAILED\n");
    return ok ? 0 : 1;
}
