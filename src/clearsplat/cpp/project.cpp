// Projection (EWA splatting as in the original 3DGS forward pass), culling, colour and the
// front-to-back sort of the visible Gaussians of one camera.
#include <omp.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <vector>

#include "memory.h"
#include "raster.h"
#include "sh.h"
#include "simd.h"

namespace cs {

namespace {

constexpr int kBlock = 64;  // Gaussians per block

// Per-block projection results, one lane per Gaussian. The block loop is branch-free over
// structure-of-arrays lanes so that compilers can vectorise it (GCC 12 keeps it scalar; the
// opacity logarithm is explicitly vectorised).
struct Block {
    alignas(64) double u[kBlock], v[kBlock], ca[kBlock], cb[kBlock], cc[kBlock], tz[kBlock];
    alignas(64) double e2[kBlock];
    alignas(64) double op[kBlock];  // opacity times the antialiasing compensation (AA mode only)
    alignas(64) double ok[kBlock];  // 1 visible, 0 culled
    alignas(64) int32_t x0[kBlock], x1[kBlock], y0[kBlock], y1[kBlock];      // pixel range
    alignas(64) int32_t bx0[kBlock], bx1[kBlock], by0[kBlock], by1[kBlock];  // alpha box
};

// Four-lane double vectors for the projection (GCC/Clang vector extensions). Each lane does
// the IEEE operations a scalar loop would do, in the same order, so the bits do not depend on
// the instruction set.
typedef double d4 __attribute__((vector_size(32)));
typedef int64_t m4 __attribute__((vector_size(32)));  // lane masks: all ones or zero
typedef int32_t n4 __attribute__((vector_size(16)));

CS_INLINE d4 dsplat(double a) { return d4{a, a, a, a}; }
CS_INLINE d4 dload(const double* p) {
    d4 v;
    std::memcpy(&v, p, sizeof v);
    return v;
}
CS_INLINE void dstore(double* p, d4 v) { std::memcpy(p, &v, sizeof v); }
CS_INLINE void nstore(int32_t* p, n4 v) { std::memcpy(p, &v, sizeof v); }
CS_INLINE d4 dsel(m4 m, d4 a, d4 b) { return m ? a : b; }
// std::max(a, b) and std::min(a, b), lane by lane (same NaN behaviour).
CS_INLINE d4 dmax(d4 a, d4 b) { return dsel(a < b, b, a); }
CS_INLINE d4 dmin(d4 a, d4 b) { return dsel(b < a, b, a); }
CS_INLINE d4 dsqrt(d4 a) {
    d4 r;
    for (int l = 0; l < 4; ++l) r[l] = std::sqrt(a[l]);
    return r;
}
// Whole doubles in int32 range: truncation toward zero.
CS_INLINE n4 to_int(d4 a) { return __builtin_convertvector(a, n4); }
CS_INLINE d4 trunc_small(d4 a) { return __builtin_convertvector(to_int(a), d4); }

// Pixel index range [lo, hi] (inclusive) whose centres (i + 0.5) lie within [c - e, c + e],
// clamped to [0, last]: lo = ceil(c - e - 0.5), hi = floor(c + e - 0.5), as whole doubles.
// The mask is false where the range is empty or not finite.
CS_INLINE m4 centre_range(d4 c, d4 e, d4 last, d4& lo, d4& hi) {
    const d4 zero = dsplat(0.0);
    d4 a = c - e - 0.5, b = c + e - 0.5;
    const m4 in = (b >= 0.0) & (a <= last);  // false for NaN
    a = dsel(in, dmin(dmax(a, zero), last), zero);
    b = dsel(in, dmin(dmax(b, zero), last), zero);
    const d4 fa = trunc_small(a);  // a, b >= 0: truncation is floor
    lo = dsel(fa < a, fa + 1.0, fa);
    hi = trunc_small(b);
    return in & (lo <= hi);
}

// e2 = 2 ln(255 o), the squared Mahalanobis radius where alpha reaches 1/255, for the block's
// opacities (clamped at 0; Cephes logf polynomial, about 1e-7 relative error, covered by the
// padding of the box).
inline void box_radius2(const float* opacity, int cnt, double* e2) {
    // Every Gaussian goes through the same eight-lane polynomial (a short last group is
    // padded), so its box depends on its opacity alone, not on where it falls in a block: a
    // subset of the Gaussians projects to the same boxes.
    for (int j = 0; j < cnt; j += 8) {
        alignas(32) float lanes[8] = {1.0f, 1.0f, 1.0f, 1.0f, 1.0f, 1.0f, 1.0f, 1.0f};
        const int len = std::min(8, cnt - j);
        std::memcpy(lanes, opacity + j, size_t(len) * sizeof(float));
        f8 x = load(lanes) * 255.0f;
        x = select(x > 1.0f, x, splat(1.0f));  // o < 1/255 is culled anyway
        const i8 bits = (i8)x;
        f8 e = __builtin_convertvector(((bits >> 23) & 0xff) - 126, f8);
        f8 m = (f8)((bits & 0x007fffff) | 0x3f000000);  // mantissa in [0.5, 1)
        const i8 small = m < 0.70710678118654752f;
        e = select(small, e - 1.0f, e);
        m = select(small, m + m - 1.0f, m - 1.0f);
        const f8 z = m * m;
        f8 y = splat(7.0376836292e-2f);
        y = y * m - 1.1514610310e-1f;
        y = y * m + 1.1676998740e-1f;
        y = y * m - 1.2420140846e-1f;
        y = y * m + 1.4249322787e-1f;
        y = y * m - 1.6668057665e-1f;
        y = y * m + 2.0000714765e-1f;
        y = y * m - 2.4999993993e-1f;
        y = y * m + 3.3333331174e-1f;
        y = y * m * z;
        y = y + e * -2.12194440e-4f;
        y = y - 0.5f * z;
        const f8 ln = m + y + e * 0.693359375f;
        const f8 r = 2.0f * ln;
        for (int l = 0; l < len; ++l) e2[j + l] = r[l] > 0.0f ? double(r[l]) : 0.0;
    }
}

// Projects Gaussians [i0, i0 + cnt) into `b`; b.ok[j] is 0 where a Gaussian is culled (behind
// the near plane, degenerate, off-image, never reaching alpha 1/255, radius at most
// p.radius_clip, or not finite). In antialiased mode the opacity is scaled by the compensation
// sqrt(det(Sigma2D) / det(Sigma2D + eps2d I)) before culling and bounding (as gsplat does).
CS_TARGET_CLONES
void project_block(const ProjectInputs& in, const ProjectParams& p, int64_t i0, int cnt,
                   Block& b) {
    const bool aa = p.antialiased;
    if (!aa) box_radius2(in.opacities + i0, cnt, b.e2);  // AA: from the scaled opacity below
    const double* V = p.view;
    const double fx = p.fx, fy = p.fy, cx = p.cx, cy = p.cy;
    const d4 near_plane = dsplat(p.near_plane);
    const d4 last_x = dsplat(double(p.width - 1)), last_y = dsplat(double(p.height - 1));
    const d4 limx = dsplat(1.3 * double(p.width) / (2.0 * fx));
    const d4 limy = dsplat(1.3 * double(p.height) / (2.0 * fy));
    const d4 zero = dsplat(0.0), one = dsplat(1.0);
    const d4 eps2d = dsplat(p.eps2d), radius_clip = dsplat(p.radius_clip);
    // Transpose the inputs to contiguous lanes first (zeros past cnt: those lanes are ignored).
    alignas(64) double in_m[3][kBlock], in_q[4][kBlock], in_s[3][kBlock], in_o[kBlock];
    for (int j = 0; j < cnt; ++j) {
        const int64_t i = i0 + j;
        for (int k = 0; k < 3; ++k) in_m[k][j] = in.means[3 * i + k];
        for (int k = 0; k < 4; ++k) in_q[k][j] = in.quats[4 * i + k];
        for (int k = 0; k < 3; ++k) in_s[k][j] = in.scales[3 * i + k];
        in_o[j] = in.opacities[i];
    }
    const int padded = (cnt + 3) / 4 * 4;
    for (int j = cnt; j < padded; ++j) {
        for (int k = 0; k < 3; ++k) in_m[k][j] = in_s[k][j] = 0.0;
        for (int k = 0; k < 4; ++k) in_q[k][j] = 0.0;
        in_o[j] = b.e2[j] = b.op[j] = 0.0;
    }
    for (int j = 0; j < padded; j += 4) {
        const d4 mx = dload(in_m[0] + j), my = dload(in_m[1] + j), mz = dload(in_m[2] + j);
        const d4 tz = V[8] * mx + V[9] * my + V[10] * mz + V[11];
        const d4 tx = V[0] * mx + V[1] * my + V[2] * mz + V[3];
        const d4 ty = V[4] * mx + V[5] * my + V[6] * mz + V[7];
        const d4 opacity = dload(in_o + j);
        // alpha = min(0.99, o * exp(power)) <= o, so o < 1/255 never contributes.
        m4 ok = (tz >= near_plane) & (opacity >= double(kMinAlpha)) & (opacity < 1e30);

        // M = R S with R from the quaternion (w, x, y, z), normalised via 2 / |q|^2.
        const d4 qw = dload(in_q[0] + j), qx = dload(in_q[1] + j);
        const d4 qy = dload(in_q[2] + j), qz = dload(in_q[3] + j);
        const d4 qn2 = qw * qw + qx * qx + qy * qy + qz * qz;
        ok &= (qn2 > 0.0) & (qn2 < 1e300);
        const d4 k2 = 2.0 / qn2;  // culled lanes may hold inf; they are masked out
        const d4 R00 = 1 - k2 * (qy * qy + qz * qz), R01 = k2 * (qx * qy - qw * qz);
        const d4 R02 = k2 * (qx * qz + qw * qy), R10 = k2 * (qx * qy + qw * qz);
        const d4 R11 = 1 - k2 * (qx * qx + qz * qz), R12 = k2 * (qy * qz - qw * qx);
        const d4 R20 = k2 * (qx * qz - qw * qy), R21 = k2 * (qy * qz + qw * qx);
        const d4 R22 = 1 - k2 * (qx * qx + qy * qy);
        const d4 s0 = dload(in_s[0] + j), s1 = dload(in_s[1] + j), s2 = dload(in_s[2] + j);

        // Perspective Jacobian with x/z, y/z clamped to 1.3 times the half field of view.
        const d4 iz = 1.0 / tz;
        const d4 xz = dmin(dmax(tx * iz, -limx), limx);
        const d4 yz = dmin(dmax(ty * iz, -limy), limy);
        const d4 j00 = fx * iz, j02 = -fx * xz * iz;
        const d4 j11 = fy * iz, j12 = -fy * yz * iz;
        // Sigma2D = (J W M)(J W M)^T + eps2d I, with Sigma = M M^T; A, B: rows of J W.
        const d4 A0 = j00 * V[0] + j02 * V[8], A1 = j00 * V[1] + j02 * V[9];
        const d4 A2 = j00 * V[2] + j02 * V[10];
        const d4 B0 = j11 * V[4] + j12 * V[8], B1 = j11 * V[5] + j12 * V[9];
        const d4 B2 = j11 * V[6] + j12 * V[10];
        const d4 AM0 = (A0 * R00 + A1 * R10 + A2 * R20) * s0;
        const d4 AM1 = (A0 * R01 + A1 * R11 + A2 * R21) * s1;
        const d4 AM2 = (A0 * R02 + A1 * R12 + A2 * R22) * s2;
        const d4 BM0 = (B0 * R00 + B1 * R10 + B2 * R20) * s0;
        const d4 BM1 = (B0 * R01 + B1 * R11 + B2 * R21) * s1;
        const d4 BM2 = (B0 * R02 + B1 * R12 + B2 * R22) * s2;
        const d4 ca0 = AM0 * AM0 + AM1 * AM1 + AM2 * AM2;
        const d4 cb = AM0 * BM0 + AM1 * BM1 + AM2 * BM2;
        const d4 cc0 = BM0 * BM0 + BM1 * BM1 + BM2 * BM2;
        const d4 ca = ca0 + eps2d, cc = cc0 + eps2d;
        const d4 det = ca * cc - cb * cb;
        ok &= (det > 0.0) & (det < 1e300);
        if (aa) {
            // The blur would spread a sub-pixel Gaussian's energy; the compensation keeps it.
            const d4 ratio = dmax(zero, (ca0 * cc0 - cb * cb) / det);
            const d4 op = opacity * dsqrt(dsel(ok, ratio, zero));
            ok &= op >= double(kMinAlpha);
            dstore(b.op + j, op);
            for (int l = 0; l < 4; ++l)  // 2 ln(255 o), as box_radius2 for the classic path
                b.e2[j + l] = std::max(0.0, 2.0 * std::log(std::max(1.0, 255.0 * op[l])));
        }
        const d4 mid = 0.5 * (ca + cc);
        const d4 lambda = mid + dsqrt(dmax(dsplat(0.1), mid * mid - det));
        d4 r3 = 3.0 * dsqrt(lambda);
        ok &= r3 < 1e9;
        r3 = dsel(ok, r3, zero);
        d4 radius = trunc_small(r3);  // ceil(3 sqrt(lambda))
        radius += dsel(radius < r3, one, zero);
        ok &= radius > radius_clip;
        const d4 u = fx * tx * iz + cx, v = fy * ty * iz + cy;

        // Pixels (and so tiles) with a centre within the radius, per axis.
        d4 c0, c1, r0, r1, bx0, bx1, by0, by1;
        ok &= centre_range(u, radius, last_x, c0, c1);
        ok &= centre_range(v, radius, last_y, r0, r1);
        // Box where alpha can reach 1/255: d^T Sigma2D^-1 d >= dx^2 / Sigma2D_xx, so
        // |dx| <= sqrt(2 ln(255 o) Sigma2D_xx). Padded against float rounding in compositing.
        const d4 e2 = dload(b.e2 + j);
        const d4 ex = dsqrt(e2 * ca) * (1.0 + 1e-3) + 1e-3;
        const d4 ey = dsqrt(e2 * cc) * (1.0 + 1e-3) + 1e-3;
        ok &= centre_range(u, ex, last_x, bx0, bx1);
        ok &= centre_range(v, ey, last_y, by0, by1);
        // Tiles outside the box see alpha < 1/255 everywhere: leaving them out changes nothing.
        const d4 x0 = dmax(c0, bx0), x1 = dmin(c1, bx1);
        const d4 y0 = dmax(r0, by0), y1 = dmin(r1, by1);
        ok &= (x0 <= x1) & (y0 <= y1);
        nstore(b.x0 + j, to_int(x0));
        nstore(b.x1 + j, to_int(x1));
        nstore(b.y0 + j, to_int(y0));
        nstore(b.y1 + j, to_int(y1));
        nstore(b.bx0 + j, to_int(bx0));
        nstore(b.bx1 + j, to_int(bx1));
        nstore(b.by0 + j, to_int(by0));
        nstore(b.by1 + j, to_int(by1));
        dstore(b.ok + j, dsel(ok, one, zero));
        dstore(b.u + j, u);
        dstore(b.v + j, v);
        dstore(b.ca + j, ca);
        dstore(b.cb + j, cb);
        dstore(b.cc + j, cc);
        dstore(b.tz + j, tz);
    }
}

// Whether any of keep[0, cnt) is set.
inline bool any_kept(const uint8_t* keep, int cnt) {
    uint8_t any = 0;
    for (int j = 0; j < cnt; ++j) any |= keep[j];
    return any != 0;
}

// Fills the record of a Gaussian that passed project_block; false if it is not finite.
inline bool finish_one(int64_t i, int j, const Block& b, const ProjectInputs& in,
                       const ProjectParams& p, Splat& s, Rect& r) {
    const double idet = 1.0 / (b.ca[j] * b.cc[j] - b.cb[j] * b.cb[j]);
    s.u = float(b.u[j]);
    s.v = float(b.v[j]);
    s.ca = float(b.cc[j] * idet);
    s.cb = float(-b.cb[j] * idet);
    s.cc = float(b.ca[j] * idet);
    s.opacity = p.antialiased ? float(b.op[j]) : in.opacities[i];
    s.depth = float(b.tz[j]);
    s.bx0 = int16_t(b.bx0[j]);
    s.bx1 = int16_t(b.bx1[j]);
    s.by0 = int16_t(b.by0[j]);
    s.by1 = int16_t(b.by1[j]);
    r = Rect{uint16_t(b.x0[j] / kTile), uint16_t(b.y0[j] / kTile), uint16_t(b.x1[j] / kTile),
             uint16_t(b.y1[j] / kTile)};
    const float* m = in.means + 3 * i;
    double d[3] = {m[0] - p.campos[0], m[1] - p.campos[1], m[2] - p.campos[2]};
    if (in.sh_k > 1) {
        const double dn2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
        if (dn2 > 0.0) {
            const double idn = 1.0 / std::sqrt(dn2);
            d[0] *= idn, d[1] *= idn, d[2] *= idn;
        }
    }
    sh_to_rgb(in.sh + int64_t(3) * in.sh_k * i, in.sh_k, d, s.rgb);
    return std::isfinite(s.rgb[0] + s.rgb[1] + s.rgb[2]) && std::isfinite(s.ca + s.cb + s.cc);
}

}  // namespace

ProjectResult project(const ProjectInputs& in, const ProjectParams& p, int num_threads) {
    const int64_t n = in.n;
    // Contiguous chunks keep the compacted order equal to the Gaussian order, which the stable
    // sort below turns into the tie-break by index.
    const int64_t num_chunks = std::max<int64_t>(1, std::min<int64_t>(n / 4096 + 1, 64 * num_threads));
    const int64_t chunk = (n + num_chunks - 1) / num_chunks;
    std::vector<int64_t> counts(num_chunks + 1, 0);
    // Chunk c writes its records from start[c] on. With a keep mask the chunks' kept
    // Gaussians are counted first, so that the temporaries hold those alone (a neighbourhood of
    // a dense capture keeps a small part of the scene), not one slot per Gaussian.
    std::vector<int64_t> start(num_chunks + 1, 0);
    if (in.keep) {
#pragma omp parallel for schedule(static) num_threads(num_threads)
        for (int64_t c = 0; c < num_chunks; ++c) {
            const int64_t begin = c * chunk, end = std::min(n, begin + chunk);
            int64_t kept = 0;
            for (int64_t i = begin; i < end; ++i) kept += in.keep[i] != 0;
            start[c + 1] = kept;
        }
        for (int64_t c = 0; c < num_chunks; ++c) start[c + 1] += start[c];
    } else {
        for (int64_t c = 0; c <= num_chunks; ++c) start[c] = std::min(n, c * chunk);
    }
    // Temporaries (reused across calls): records in Gaussian order, then sort keys and values.
    auto carve = [](char*& at, size_t bytes) {
        char* p = at;
        at += (bytes + 63) / 64 * 64;
        return p;
    };
    const size_t n1 = size_t(std::max<int64_t>(start[num_chunks], 1));
    char* at = scratch(n1 * (sizeof(Splat) + sizeof(Rect) + 5 * sizeof(uint32_t)) + 6 * 64);
    Splat* tmp_splats = reinterpret_cast<Splat*>(carve(at, n1 * sizeof(Splat)));
    Rect* tmp_rects = reinterpret_cast<Rect*>(carve(at, n1 * sizeof(Rect)));
    uint32_t* tmp_index = reinterpret_cast<uint32_t*>(carve(at, n1 * sizeof(uint32_t)));
    uint32_t* keys = reinterpret_cast<uint32_t*>(carve(at, 2 * n1 * sizeof(uint32_t)));
    uint32_t* pos = reinterpret_cast<uint32_t*>(carve(at, 2 * n1 * sizeof(uint32_t)));

#pragma omp parallel for schedule(dynamic, 1) num_threads(num_threads)
    for (int64_t c = 0; c < num_chunks; ++c) {
        const int64_t begin = c * chunk, end = std::min(n, begin + chunk);
        int64_t k = start[c];
        Block block;
        for (int64_t i0 = begin; i0 < end; i0 += kBlock) {
            const int cnt = int(std::min<int64_t>(kBlock, end - i0));
            // A block without a kept Gaussian adds nothing: skip its projection. Each lane is
            // computed on its own (project_block), so the others' records do not change.
            if (in.keep && !any_kept(in.keep + i0, cnt)) continue;
            project_block(in, p, i0, cnt, block);
            for (int j = 0; j < cnt; ++j) {
                const int64_t i = i0 + j;
                if (block.ok[j] == 0.0 || (in.keep && !in.keep[i])) continue;
                if (finish_one(i, j, block, in, p, tmp_splats[k], tmp_rects[k])) tmp_index[k++] = uint32_t(i);
            }
        }
        counts[c + 1] = k - start[c];
    }
    for (int64_t c = 0; c < num_chunks; ++c) counts[c + 1] += counts[c];
    const int64_t num = counts[num_chunks];

    // Sort keys: camera z as float bits (positive floats order like their bit patterns);
    // values: position in the compacted, index-ordered sequence.
#pragma omp parallel for schedule(static) num_threads(num_threads)
    for (int64_t c = 0; c < num_chunks; ++c) {
        const int64_t src = start[c], dst = counts[c], len = counts[c + 1] - counts[c];
        for (int64_t j = 0; j < len; ++j) {
            std::memcpy(&keys[dst + j], &tmp_splats[src + j].depth, 4);
            pos[dst + j] = uint32_t(src + j);
        }
    }
    radix_sort_pairs(keys, pos, num, keys + num, pos + num, num_threads);

    ProjectResult out;
    out.num = num;
    out.splats = big_alloc_n<Splat>(num);
    out.rects = big_alloc_n<Rect>(num);
    out.index = big_alloc_n<int32_t>(num);
    constexpr int64_t kAhead = 16;
#pragma omp parallel for schedule(static) num_threads(num_threads)
    for (int64_t j = 0; j < num; ++j) {
        if (j + kAhead < num) {  // random reads: fetch ahead
            __builtin_prefetch(tmp_splats + pos[j + kAhead]);
            __builtin_prefetch(tmp_rects + pos[j + kAhead]);
            __builtin_prefetch(tmp_index + pos[j + kAhead]);
        }
        const uint32_t src = pos[j];
        out.splats[j] = tmp_splats[src];
        out.rects[j] = tmp_rects[src];
        out.index[j] = int32_t(tmp_index[src]);
    }
    return out;
}

}  // namespace cs
