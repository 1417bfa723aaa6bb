// Python bindings for the native core. Validation and defaults live in Python
// (clearsplat/_render.py); this file only exposes the kernels.
#include <nanobind/nanobind.h>
#include <omp.h>

namespace nb = nanobind;

NB_MODULE(_core, m) {
    m.doc() = "clearsplat native CPU Gaussian rasterizer";
    m.def("max_threads", []() { return omp_get_max_threads(); },
          "Number of threads the native core uses by default.");
}
