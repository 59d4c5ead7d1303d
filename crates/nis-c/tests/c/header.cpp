// header.cpp: nis.h from C++ (extern "C" linkage), with one call through it.
#include <cstdio>
#include <cstring>

#include "nis.h"

int main() {
    nis_integrator *integ = nullptr;
    int status = nis_create(R"({"method": "uniform", "dim": 2, "seed": 1})", &integ);
    auto f = [](const double *x, size_t n, size_t dim, double *out, void *) -> int {
        for (size_t i = 0; i < n; i++) out[i] = x[i * dim] + x[i * dim + 1];
        return 0;
    };
    nis_result r{};
    if (status == NIS_OK) status = nis_integrate(integ, f, nullptr, 10000, &r);
    nis_free(integ);
    bool ok = status == NIS_OK && std::strcmp(nis_version(), NIS_VERSION_STRING) == 0 &&
              r.value > 0.9 && r.value < 1.1;
    std::printf("%s\n", ok ? "c++: ok" : "c++: FAILED");
    return ok ? 0 : 1;
}
