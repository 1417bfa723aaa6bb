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
#define CS_LAMBDA_INLINE __attribute__((always_inline))

namespace cs {

typedef float f8 __attribute__((vector_size(32)));
typedef int32_t i8 __attribute__((vector_size(32)));
// Two rows of eight lanes (the compositing's two-row step on AVX-512 machines).
typedef float f16 __attribute__((vector_size(64)));
typedef int32_t i16 __attribute__((vector_size(64)));

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

CS_INLINE i8 low(i16 v) { return __builtin_shufflevector(v, v, 0, 1, 2, 3, 4, 5, 6, 7); }
CS_INLINE i8 high(i16 v) { return __builtin_shufflevector(v, v, 8, 9, 10, 11, 12, 13, 14, 15); }
CS_INLINE f8 low(f16 v) { return __builtin_shufflevector(v, v, 0, 1, 2, 3, 4, 5, 6, 7); }
CS_INLINE f8 high(f16 v) { return __builtin_shufflevector(v, v, 8, 9, 10, 11, 12, 13, 14, 15); }
CS_INLINE f16 join(f8 a, f8 b) {
    return __builtin_shufflevector(a, b, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
}
CS_INLINE i16 join(i8 a, i8 b) {
    return __builtin_shufflevector(a, b, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
}
CS_INLINE f16 select(i16 mask, f16 a, f16 b) { return mask ? a : b; }
CS_INLINE bool any(i16 mask) { return any(low(mask) | high(mask)); }
CS_INLINE int count(i16 mask) { return count(low(mask)) + count(high(mask)); }

// Lanes of R rows of eight pixels each: R = 1 (f8, i8) or R = 2 (f16, i16). Row r's lanes are
// [8 r, 8 r + 8); every lane does the same IEEE operations whichever R runs it.
template <int R>
struct Rows;
template <>
struct Rows<1> {
    typedef f8 F;
    typedef i8 I;
};
template <>
struct Rows<2> {
    typedef f16 F;
    typedef i16 I;
};

// Eight lanes at `p` (R = 1), or at `p` and `p + stride` (R = 2; the second row is read only
// when `two`, else its lanes repeat the first's).
CS_INLINE f8 load_rows(const float* p, int, bool, f8*) { return load(p); }
CS_INLINE i8 load_rows(const int32_t* p, int, bool, i8*) { return load(p); }
CS_INLINE f16 load_rows(const float* p, int stride, bool two, f16*) {
    const f8 a = load(p);
    return join(a, two ? load(p + stride) : a);
}
CS_INLINE i16 load_rows(const int32_t* p, int stride, bool two, i16*) {
    const i8 a = load(p);
    return join(a, two ? load(p + stride) : a);
}
template <class V, class T>
CS_INLINE V load_rows(const T* p, int stride, bool two) {
    return load_rows(p, stride, two, static_cast<V*>(nullptr));
}
CS_INLINE void store_rows(float* p, int, bool, f8 v) { store(p, v); }
CS_INLINE void store_rows(int32_t* p, int, bool, i8 v) { store(p, v); }
CS_INLINE void store_rows(float* p, int stride, bool two, f16 v) {
    store(p, low(v));
    if (two) store(p + stride, high(v));
}
CS_INLINE void store_rows(int32_t* p, int stride, bool two, i16 v) {
    store(p, low(v));
    if (two) store(p + stride, high(v));
}

// exp(x) for x <= 0, within 2 ulp (the Cephes single-precision polynomial); x below -87 is
// treated as -87 (exp = 1.6e-38, far below any alpha that counts).
template <class F, class I = typename Rows<sizeof(F) / sizeof(f8)>::I>
CS_INLINE F exp_nonpositive(F x) {
    x = x < -87.0f ? F{} - 87.0f : x;
    const F fx = x * 1.44269504088896341f + 0.5f;
    F n = __builtin_convertvector(__builtin_convertvector(fx, I), F);  // trunc
    n = n > fx ? n - 1.0f : n;                                         // floor
    x = x - n * 0.693359375f;
    x = x - n * -2.12194440e-4f;
    const F z = x * x;
    F y = F{} + 1.9875691500e-4f;
    y = y * x + 1.3981999507e-3f;
    y = y * x + 8.3334519073e-3f;
    y = y * x + 4.1665795894e-2f;
    y = y * x + 1.6666665459e-1f;
    y = y * x + 5.0000001201e-1f;
    y = y * z + x + 1.0f;
    const I bits = (__builtin_convertvector(n, I) + 127) << 23;
    return y * (F)bits;
}

}  // namespace cs
