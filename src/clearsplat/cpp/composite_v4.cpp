// The compositing kernels of composite.cpp once more, compiled with -march=x86-64-v4 (AVX-512):
// sixteen lanes, two rows of eight pixels, a step. composite.cpp calls them where the machine
// has AVX-512 (rows_per_step() == 2); CMakeLists.txt builds this file on x86-64 only.
#define CS_COMPOSITE_V4
#define CS_COMPOSITE_VARIANT v4
#define CS_ROWS 2
#define CS_CLONES
#include "composite.cpp"
