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
    alignas(64) double ok[kBlock];  // 1 visible, 0 culled
    alignas(64) int32_t x0[kBlock], x1[kBlock], y0[kBlock], y1[kBlock];      // pixel range
    alignas(64) int32_t bx0[kBlock], bx1[kBlock], by0[kBlock], by1[kBlock];  // alpha box
};

// Pixel index range [lo, hi] (inclusive) whose centres (i + 0.5) lie within [c - e, c + e],
// clamped to [0, last]: lo = ceil(c - e - 0.5), hi = floor(c + e - 0.5), as whole doubles.
// Returns false when the range is empty or not finite. Branch-free (doubles and masks only).
inline bool centre_range(double c, double e, double last, double& lo, double& hi) {
    double a = c - e - 0.5, b = c + e - 0.5;
    const bool in = (b >= 0.0) & (a <= last);  // false for NaN
    a = in ? std::min(std::max(a, 0.0), last) : 0.0;
    b = in ? std::min(std::max(b, 0.0), last) : 0.0;
    const double fa = double(int32_t(a));  // a, b >= 0: truncation is floor
    lo = fa < a ? fa + 1.0 : fa;
    hi = double(int32_t(b));
    return in & (lo <= hi);
}

// e2 = 2 ln(255 o), the squared Mahalanobis radius where alpha reaches 1/255, for the block's
// opacities (clamped at 0; Cephes logf polynomial, about 1e-7 relative error, covered by the
// padding of the box).
inline void box_radius2(const float* opacity, int cnt, double* e2) {
    int j = 0;
    for (; j + 8 <= cnt; j += 8) {
        f8 x = load(opacity + j) * 255.0f;
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
        for (int l = 0; l < 8; ++l) e2[j + l] = r[l] > 0.0f ? double(r[l]) : 0.0;
    }
    for (; j < cnt; ++j) e2[j] = std::max(0.0, 2.0 * std::log(std::max(1.0, 255.0 * double(opacity[j]))));
}

// Projects Gaussians [i0, i0 + cnt) into `b`; b.ok[j] is 0 where a Gaussian is culled (behind
// the near plane, degenerate, off-image, never reaching alpha 1/255, or not finite).
CS_TARGET_CLONES
void project_block(const ProjectInputs& in, const ProjectParams& p, int64_t i0, int cnt,
                   Block& b) {
    box_radius2(in.opacities + i0, cnt, b.e2);
    // Locals (not struct fields) so that the compiler sees no aliasing with the stores to b.
    double V[12];
    for (int k = 0; k < 12; ++k) V[k] = p.view[k];
    const double fx = p.fx, fy = p.fy, cx = p.cx, cy = p.cy, near_plane = p.near_plane;
    const double last_x = double(p.width - 1), last_y = double(p.height - 1);
    const double limx = 1.3 * double(p.width) / (2.0 * fx);
    const double limy = 1.3 * double(p.height) / (2.0 * fy);
    // Transpose the inputs to contiguous lanes first: strided loads stop the vectoriser.
    alignas(64) double in_m[3][kBlock], in_q[4][kBlock], in_s[3][kBlock], in_o[kBlock];
    for (int j = 0; j < cnt; ++j) {
        const int64_t i = i0 + j;
        for (int k = 0; k < 3; ++k) in_m[k][j] = in.means[3 * i + k];
        for (int k = 0; k < 4; ++k) in_q[k][j] = in.quats[4 * i + k];
        for (int k = 0; k < 3; ++k) in_s[k][j] = in.scales[3 * i + k];
        in_o[j] = in.opacities[i];
    }
#pragma omp simd
    for (int j = 0; j < cnt; ++j) {
        const double mx = in_m[0][j], my = in_m[1][j], mz = in_m[2][j];
        const double tz = V[8] * mx + V[9] * my + V[10] * mz + V[11];
        const double tx = V[0] * mx + V[1] * my + V[2] * mz + V[3];
        const double ty = V[4] * mx + V[5] * my + V[6] * mz + V[7];
        const double opacity = in_o[j];
        // alpha = min(0.99, o * exp(power)) <= o, so o < 1/255 never contributes.
        bool ok = (tz >= near_plane) & (opacity >= double(kMinAlpha)) & (opacity < 1e30);

        // M = R S with R from the quaternion (w, x, y, z), normalised via 2 / |q|^2.
        const double qw = in_q[0][j], qx = in_q[1][j], qy = in_q[2][j], qz = in_q[3][j];
        const double qn2 = qw * qw + qx * qx + qy * qy + qz * qz;
        ok &= (qn2 > 0.0) & (qn2 < 1e300);
        const double k2 = 2.0 / qn2;  // culled lanes may hold inf; they are masked out
        const double R00 = 1 - k2 * (qy * qy + qz * qz), R01 = k2 * (qx * qy - qw * qz);
        const double R02 = k2 * (qx * qz + qw * qy), R10 = k2 * (qx * qy + qw * qz);
        const double R11 = 1 - k2 * (qx * qx + qz * qz), R12 = k2 * (qy * qz - qw * qx);
        const double R20 = k2 * (qx * qz - qw * qy), R21 = k2 * (qy * qz + qw * qx);
        const double R22 = 1 - k2 * (qx * qx + qy * qy);
        const double s0 = in_s[0][j], s1 = in_s[1][j], s2 = in_s[2][j];

        // Perspective Jacobian with x/z, y/z clamped to 1.3 times the half field of view.
        const double iz = 1.0 / tz;
        const double xz = std::min(std::max(tx * iz, -limx), limx);
        const double yz = std::min(std::max(ty * iz, -limy), limy);
        const double j00 = fx * iz, j02 = -fx * xz * iz;
        const double j11 = fy * iz, j12 = -fy * yz * iz;
        // Sigma2D = (J W M)(J W M)^T + 0.3 I, with Sigma = M M^T; A, B: rows of J W.
        const double A0 = j00 * V[0] + j02 * V[8], A1 = j00 * V[1] + j02 * V[9];
        const double A2 = j00 * V[2] + j02 * V[10];
        const double B0 = j11 * V[4] + j12 * V[8], B1 = j11 * V[5] + j12 * V[9];
        const double B2 = j11 * V[6] + j12 * V[10];
        const double AM0 = (A0 * R00 + A1 * R10 + A2 * R20) * s0;
        const double AM1 = (A0 * R01 + A1 * R11 + A2 * R21) * s1;
        const double AM2 = (A0 * R02 + A1 * R12 + A2 * R22) * s2;
        const double BM0 = (B0 * R00 + B1 * R10 + B2 * R20) * s0;
        const double BM1 = (B0 * R01 + B1 * R11 + B2 * R21) * s1;
        const double BM2 = (B0 * R02 + B1 * R12 + B2 * R22) * s2;
        const double ca = AM0 * AM0 + AM1 * AM1 + AM2 * AM2 + 0.3;
        const double cb = AM0 * BM0 + AM1 * BM1 + AM2 * BM2;
        const double cc = BM0 * BM0 + BM1 * BM1 + BM2 * BM2 + 0.3;
        const double det = ca * cc - cb * cb;
        ok &= (det > 0.0) & (det < 1e300);
        const double mid = 0.5 * (ca + cc);
        const double lambda = mid + std::sqrt(std::max(0.1, mid * mid - det));
        double r3 = 3.0 * std::sqrt(lambda);
        ok &= r3 < 1e9;
        r3 = ok ? r3 : 0.0;
        double radius = double(int32_t(r3));  // ceil(3 sqrt(lambda))
        radius += radius < r3 ? 1.0 : 0.0;
        const double u = fx * tx * iz + cx, v = fy * ty * iz + cy;

        // Pixels (and so tiles) with a centre within the radius, per axis.
        double c0, c1, r0, r1, bx0, bx1, by0, by1;
        ok &= centre_range(u, radius, last_x, c0, c1);
        ok &= centre_range(v, radius, last_y, r0, r1);
        // Box where alpha can reach 1/255: d^T Sigma2D^-1 d >= dx^2 / Sigma2D_xx, so
        // |dx| <= sqrt(2 ln(255 o) Sigma2D_xx). Padded against float rounding in compositing.
        const double e2 = b.e2[j];
        const double ex = std::sqrt(e2 * ca) * (1.0 + 1e-3) + 1e-3;
        const double ey = std::sqrt(e2 * cc) * (1.0 + 1e-3) + 1e-3;
        ok &= centre_range(u, ex, last_x, bx0, bx1);
        ok &= centre_range(v, ey, last_y, by0, by1);
        // Tiles outside the box see alpha < 1/255 everywhere: leaving them out changes nothing.
        const double x0 = std::max(c0, bx0), x1 = std::min(c1, bx1);
        const double y0 = std::max(r0, by0), y1 = std::min(r1, by1);
        ok &= (x0 <= x1) & (y0 <= y1);
        b.x0[j] = int32_t(x0);
        b.x1[j] = int32_t(x1);
        b.y0[j] = int32_t(y0);
        b.y1[j] = int32_t(y1);
        b.bx0[j] = int32_t(bx0);
        b.bx1[j] = int32_t(bx1);
        b.by0[j] = int32_t(by0);
        b.by1[j] = int32_t(by1);
        b.ok[j] = ok ? 1.0 : 0.0;
        b.u[j] = u;
        b.v[j] = v;
        b.ca[j] = ca;
        b.cb[j] = cb;
        b.cc[j] = cc;
        b.tz[j] = tz;
    }
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
    s.opacity = in.opacities[i];
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
    // Temporaries (reused across calls): records in Gaussian order, then sort keys and values.
    auto carve = [](char*& at, size_t bytes) {
        char* p = at;
        at += (bytes + 63) / 64 * 64;
        return p;
    };
    const size_t n1 = size_t(std::max<int64_t>(n, 1));
    char* at = scratch(n1 * (sizeof(Splat) + sizeof(Rect) + 5 * sizeof(uint32_t)) + 6 * 64);
    Splat* tmp_splats = reinterpret_cast<Splat*>(carve(at, n1 * sizeof(Splat)));
    Rect* tmp_rects = reinterpret_cast<Rect*>(carve(at, n1 * sizeof(Rect)));
    uint32_t* tmp_index = reinterpret_cast<uint32_t*>(carve(at, n1 * sizeof(uint32_t)));
    uint32_t* keys = reinterpret_cast<uint32_t*>(carve(at, 2 * n1 * sizeof(uint32_t)));
    uint32_t* pos = reinterpret_cast<uint32_t*>(carve(at, 2 * n1 * sizeof(uint32_t)));

#pragma omp parallel for schedule(dynamic, 1) num_threads(num_threads)
    for (int64_t c = 0; c < num_chunks; ++c) {
        const int64_t begin = c * chunk, end = std::min(n, begin + chunk);
        int64_t k = begin;
        Block block;
        for (int64_t i0 = begin; i0 < end; i0 += kBlock) {
            const int cnt = int(std::min<int64_t>(kBlock, end - i0));
            project_block(in, p, i0, cnt, block);
            for (int j = 0; j < cnt; ++j) {
                const int64_t i = i0 + j;
                if (block.ok[j] == 0.0 || (in.keep && !in.keep[i])) continue;
                if (finish_one(i, j, block, in, p, tmp_splats[k], tmp_rects[k])) tmp_index[k++] = uint32_t(i);
            }
        }
        counts[c + 1] = k - begin;
    }
    for (int64_t c = 0; c < num_chunks; ++c) counts[c + 1] += counts[c];
    const int64_t num = counts[num_chunks];

    // Sort keys: camera z as float bits (positive floats order like their bit patterns);
    // values: position in the compacted, index-ordered sequence.
#pragma omp parallel for schedule(static) num_threads(num_threads)
    for (int64_t c = 0; c < num_chunks; ++c) {
        const int64_t src = c * chunk, dst = counts[c], len = counts[c + 1] - counts[c];
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
