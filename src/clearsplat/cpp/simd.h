// Eight-lane float/int vectors (GCC/Clang vector extensions) and the helpers the compositing
// kernel needs. Every operation is plain IEEE arithmetic (the build turns off FMA
// contraction), so all code paths and all instruction sets give the same bits.
#pragma once

#include <cstdint>
#include <cstring>

#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__)) && defined(__linux__)
// One copy of the hot kernels for AVX2 machines, one for any x86-64, picked at load time.
#define CS_TARGET_CLONES __attribute__((target_clones("avx2", "default")))
#else
#define CS_TARGET_CLONES
#endif
#define CS_INLINE inline __attribute__((always_inline))

namespace cs {

typedef float f8 __attribute__((vector_size(32)));
typedef int32_t i8 __attribute__((vector_size(32)));

CS_INLINE f8 splat(float a) { return f8{a, a, a, a, a, a, a, a}; }
CS_INLINE i8 splat_i(int32_t a) { return i8{a, a, a, a, a, a, a, a}; }

CS_INLINE f8 load(const float* p) {
    f8 v;
    std::memcpy(&v, p, sizeof v);
    return v;
}
CS_INLINE i8 load(const int32_t* p) {
    i8 v;
    std::memcpy(&v, p, sizeof v);
    return v;
}
CS_INLINE void store(float* p, f8 v) { std::memcpy(p, &v, sizeof v); }
CS_INLINE void store(int32_t* p, i8 v) { std::memcpy(p, &v, sizeof v); }

// Lane-wise select: mask lanes are all ones (true) or zero.
CS_INLINE f8 select(i8 mask, f8 a, f8 b) { return mask ? a : b; }

typedef int64_t i64x4 __attribute__((vector_size(32)));

CS_INLINE bool any(i8 mask) {  // log-step OR: cheaper than eight lane extracts
    i64x4 v = (i64x4)mask;
    v |= __builtin_shufflevector(v, v, 2, 3, 0, 1);
    v |= __builtin_shufflevector(v, v, 1, 0, 3, 2);
    return v[0] != 0;
}

CS_INLINE int count(i8 mask) {
    int32_t c = 0;
    for (int l = 0; l < 8; ++l) c -= mask[l];
    return c;
}

// exp(x) for x <= 0, within 2 ulp (the Cephes single-precision polynomial); x below -87 is
// treated as -87 (exp = 1.6e-38, far below any alpha that counts).
CS_INLINE f8 exp_nonpositive(f8 x) {
    x = select(x < -87.0f, splat(-87.0f), x);
    const f8 fx = x * 1.44269504088896341f + 0.5f;
    f8 n = __builtin_convertvector(__builtin_convertvector(fx, i8), f8);  // trunc
    n = select(n > fx, n - 1.0f, n);                                      // floor
    x = x - n * 0.693359375f;
    x = x - n * -2.12194440e-4f;
    const f8 z = x * x;
    f8 y = splat(1.9875691500e-4f);
    y = y * x + 1.3981999507e-3f;
    y = y * x + 8.3334519073e-3f;
    y = y * x + 4.1665795894e-2f;
    y = y * x + 1.6666665459e-1f;
    y = y * x + 5.0000001201e-1f;
    y = y * z + x + 1.0f;
    const i8 bits = (__builtin_convertvector(n, i8) + 127) << 23;
    return y * (f8)bits;
}

}  // namespace cs
