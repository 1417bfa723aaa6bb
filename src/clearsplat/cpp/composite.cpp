// Per-tile front-to-back alpha compositing (the 3DGS forward pass), for full images, for
// batched incremental tile patches and for the per-pixel contribution lists.
//
// The kernels below are compiled twice: here, eight lanes a step (one row of eight pixels;
// clones for AVX2 and for any x86-64), into namespace cs::generic; and by composite_v4.cpp
// with -march=x86-64-v4, sixteen lanes a step (two rows), into cs::v4. Every lane does the
// same IEEE operations in both, so they give the same bits; the public functions at the end of
// this file pick one by rows_per_step(). Whatever the second compilation could share with
// this one is kept out of it: the helpers live in an anonymous namespace and the containers
// use a local allocator, so no instruction of one compilation is linked into the other.
#include <omp.h>

#include <cmath>
#include <cstdlib>
#include <cstring>
#include <new>
#include <vector>

#include "raster.h"
#include "simd.h"

#ifndef CS_COMPOSITE_VARIANT
#define CS_COMPOSITE_VARIANT generic
#define CS_ROWS 1
#define CS_CLONES CS_TARGET_CLONES
#endif

namespace cs {
namespace CS_COMPOSITE_VARIANT {

namespace {

// This compilation's rows per step and its lane types.
constexpr int R = CS_ROWS;
typedef Rows<R>::F F;
typedef Rows<R>::I I;

CS_INLINE int imin(int a, int b) { return b < a ? b : a; }
CS_INLINE int imax(int a, int b) { return a < b ? b : a; }

// malloc-backed, 64-byte aligned (a TileState's rows): with a type of this file, every
// container instantiation stays inside this compilation.
template <class T>
struct Allocator {
    typedef T value_type;
    Allocator() = default;
    template <class U>
    Allocator(const Allocator<U>&) {}
    T* allocate(size_t n) {
        const size_t bytes = (n * sizeof(T) + 63) / 64 * 64;
        if (void* p = std::aligned_alloc(64, bytes > 0 ? bytes : 64)) return static_cast<T*>(p);
        throw std::bad_alloc();
    }
    void deallocate(T* p, size_t) { std::free(p); }
};
template <class T, class U>
bool operator==(const Allocator<T>&, const Allocator<U>&) { return true; }
template <class T, class U>
bool operator!=(const Allocator<T>&, const Allocator<U>&) { return false; }
template <class T>
using Vec = std::vector<T, Allocator<T>>;

constexpr int64_t kPrefetch = 8;

// Fetches a record ahead of use: 48-byte records straddle two cache lines at every other
// position, so both ends are fetched.
CS_INLINE void prefetch_splat(const Splat* s) {
    __builtin_prefetch(s);
    __builtin_prefetch(reinterpret_cast<const char*>(s) + sizeof(Splat) - 1);
}

struct Entry {  // one added contribution, for contributions()
    int32_t pixel_in_tile;
    int32_t id;
    float weight;
};

struct TileState {
    alignas(64) float T[kTilePixels];
    alignas(64) float r[kTilePixels];
    alignas(64) float g[kTilePixels];
    alignas(64) float b[kTilePixels];
    alignas(64) float d[kTilePixels];
    alignas(64) int32_t done[kTilePixels];  // 0 or -1 (lane masks)
    int remaining;
    int x0, y0, w, h;  // tile origin in pixels and its size inside the image

    // `mask` (H, W) or null: pixels outside the mask (and outside the image) start done.
    // `local` (16 x 16, the tile's pixels) or null: the same, for a mask of the tile only.
    void reset(const ViewData& v, int tile, const uint8_t* mask, const uint8_t* local = nullptr) {
        x0 = (tile % v.grid_w) * kTile;
        y0 = (tile / v.grid_w) * kTile;
        w = imin(kTile, v.width - x0);
        h = imin(kTile, v.height - y0);
        remaining = 0;
        for (int p = 0; p < kTilePixels; ++p) {
            const int lx = p % kTile, ly = p / kTile;
            bool active = lx < w && ly < h;
            if (active && mask) active = mask[int64_t(y0 + ly) * v.width + x0 + lx] != 0;
            if (active && local) active = local[p] != 0;
            T[p] = 1.0f;
            r[p] = g[p] = b[p] = d[p] = 0.0f;
            done[p] = active ? 0 : -1;
            remaining += active;
        }
    }
};

// One step's rows: lanes of row ly (and ly + 1 when `two`) from column `base` on, at tile
// offset p = 16 ly + base; `dy` the vertical offsets of the Gaussian's centre from each lane's
// pixel row, `valid` the lanes of rows inside the box.
struct Step {
    int p;
    bool two;
    F dy;
    I valid;
};

CS_INLINE Step rows_at(const Splat& gs, const TileState& s, int ly, int ly1, int base) {
    Step st;
    st.p = ly * kTile + base;
    const f8 dy0 = splat(gs.v - (float(s.y0 + ly) + 0.5f));
#if CS_ROWS == 1
    (void)ly1;
    st.two = false;
    st.dy = dy0;
    st.valid = splat_i(-1);
#else
    st.two = ly + 1 <= ly1;
    st.dy = join(dy0, splat(gs.v - (float(s.y0 + ly + 1) + 0.5f)));
    st.valid = join(splat_i(-1), splat_i(st.two ? -1 : 0));
#endif
    return st;
}

// Adds one Gaussian's contribution to the `active` lanes of step `st` of `s`, the 3DGS rule:
// where T would fall below 1e-4 the pixel stops without adding; elsewhere C += c * alpha * T,
// D += z * alpha * T, T *= 1 - alpha.
CS_INLINE void accumulate(TileState& s, const Step& st, I done,
                          I active, F alpha,
                          const Splat& gs, int32_t id, Vec<Entry>* record) {
    const int p = st.p;
    const bool two = st.two;
    const F t = load_rows<F>(s.T + p, kTile, two);
    const F test_t = t * (1.0f - alpha);
    const I stop = active & (test_t < kMinTransmittance);
    const I add = active & ~stop;
    const F weight = alpha * t;
    const F zero = F{};
    store_rows(s.T + p, kTile, two, select(add, test_t, t));
    store_rows(s.r + p, kTile, two, load_rows<F>(s.r + p, kTile, two) + select(add, gs.rgb[0] * weight, zero));
    store_rows(s.g + p, kTile, two, load_rows<F>(s.g + p, kTile, two) + select(add, gs.rgb[1] * weight, zero));
    store_rows(s.b + p, kTile, two, load_rows<F>(s.b + p, kTile, two) + select(add, gs.rgb[2] * weight, zero));
    store_rows(s.d + p, kTile, two, load_rows<F>(s.d + p, kTile, two) + select(add, gs.depth * weight, zero));
    if (any(stop)) {
        store_rows(s.done + p, kTile, two, done | stop);
        s.remaining -= count(stop);
    }
    if (record)
        for (int l = 0; l < 8 * R; ++l)
            if (add[l]) record->push_back(Entry{p + (l & 7) + (l >> 3) * kTile, id, weight[l]});
}

// The lanes of step `st` (columns base.. of its rows) that `gs` reaches: inside its box
// columns [start, lx1] and rows, not `done`, power <= 0 and alpha >= 1/255, with their alpha
// (capped at 0.99) in `alpha`. The 3DGS per-pixel test, shared by every compositing loop.
CS_INLINE I reached(const Splat& gs, const TileState& s, const Step& st,
                                      int start, int lx1, int base, I done,
                                      F& alpha) {
#if CS_ROWS == 1
    const I col = I{0, 1, 2, 3, 4, 5, 6, 7} + base;
#else
    const I col = I{0, 1, 2, 3, 4, 5, 6, 7, 0, 1, 2, 3, 4, 5, 6, 7} + base;
#endif
    I active = (col >= start) & (col <= lx1) & ~done & st.valid;
    if (!any(active)) return active;
    const F dx = gs.u - (__builtin_convertvector(col + s.x0, F) + 0.5f);
    const F dy = st.dy;
    const F power = -0.5f * (gs.ca * dx * dx + gs.cc * dy * dy) - gs.cb * dx * dy;
    active &= power <= 0.0f;
    alpha = gs.opacity * exp_nonpositive(power);
    alpha = alpha < kMaxAlpha ? alpha : F{} + kMaxAlpha;
    return active & (alpha >= kMinAlpha);
}

// Calls f(step, start, base) for each step of R rows and eight columns of `gs`'s box inside the
// tile of `s`, row by row (columns [lx0, lx1]: start is the first box column of the step,
// base = min(start, 8) its first lane's, so that the eight lanes stay in the row).
template <class Fn>
CS_INLINE void for_box(const Splat& gs, const TileState& s, Fn&& f) {
    const int lx0 = imax(int(gs.bx0) - s.x0, 0), lx1 = imin(int(gs.bx1) - s.x0, s.w - 1);
    const int ly0 = imax(int(gs.by0) - s.y0, 0), ly1 = imin(int(gs.by1) - s.y0, s.h - 1);
    for (int ly = ly0; ly <= ly1; ly += R)
        for (int start = lx0; start <= lx1; start += 8) {
            const int base = imin(start, kTile - 8);
            f(rows_at(gs, s, ly, ly1, base), start, lx1, base);
        }
}

// Adds `gs` (visible id `id`) to the pixels of its box inside the tile of `s`: the 3DGS rule per
// pixel (reached, accumulate), eight pixels of R rows at a time.
CS_INLINE void add_splat(TileState& s, const Splat& gs, int32_t id, Vec<Entry>* record) {
    for_box(gs, s, [&](const Step& st, int start, int lx1, int base) CS_LAMBDA_INLINE {
        const I done = load_rows<I>(s.done + st.p, kTile, st.two);
        F alpha;
        const I active = reached(gs, s, st, start, lx1, base, done, alpha);
        if (any(active)) accumulate(s, st, done, active, alpha, gs, id, record);
    });
}

// Composites one tile's list into `s`, skipping ids with keep[id] == 0 and the ascending ids
// in `removed`; appends every added contribution to `record` when given.
//
// Per pixel this is the 3DGS loop: skip power > 0 and alpha < 1/255, stop (without adding)
// when T would fall below 1e-4, else add c * alpha * T. It runs eight pixels of a row (two rows
// on AVX-512) at a time over each Gaussian's pixel box; lanes outside the box or already done
// change nothing.
CS_CLONES
void composite_tile(const ViewData& v, int tile, const uint8_t* keep,
                                   const int32_t* removed, int64_t num_removed, TileState& s,
                                   Vec<Entry>* record) {
    const int32_t* list = v.tile_lists + v.tile_offsets[tile];
    const int64_t len = v.tile_offsets[tile + 1] - v.tile_offsets[tile];
    int64_t ri = 0;
    for (int64_t k = 0; k < len && s.remaining > 0; ++k) {
        // A tile's ids are scattered over the depth order: fetch records ahead of use.
        if (k + kPrefetch < len) prefetch_splat(v.splats + list[k + kPrefetch]);
        const int32_t id = list[k];
        if (keep && !keep[id]) continue;
        if (ri < num_removed) {
            while (ri < num_removed && removed[ri] < id) ++ri;
            if (ri < num_removed && removed[ri] == id) continue;
        }
        add_splat(s, v.splats[id], id, record);
    }
}

// The tile restricted to keep_a (all when null) into `a` and to keep_b into `b`, in one pass
// over its list: the per-lane alpha is computed once and each state is updated exactly as
// composite_tile would update it alone, so both equal their separate renders bit for bit.
CS_CLONES
void composite_tile_pair(const ViewData& v, int tile, const uint8_t* keep_a,
                                        const uint8_t* keep_b, TileState& a, TileState& b) {
    const int32_t* list = v.tile_lists + v.tile_offsets[tile];
    const int64_t len = v.tile_offsets[tile + 1] - v.tile_offsets[tile];
    const I all_done = I{} - 1;
    for (int64_t k = 0; k < len && (a.remaining > 0 || b.remaining > 0); ++k) {
        if (k + kPrefetch < len) prefetch_splat(v.splats + list[k + kPrefetch]);
        const int32_t id = list[k];
        const bool in_a = a.remaining > 0 && (!keep_a || keep_a[id]);
        const bool in_b = b.remaining > 0 && keep_b[id];
        if (!in_a && !in_b) continue;
        const Splat& gs = v.splats[id];
        for_box(gs, a, [&](const Step& st, int start, int lx1, int base) CS_LAMBDA_INLINE {
            const I done_a = in_a ? load_rows<I>(a.done + st.p, kTile, st.two) : all_done;
            const I done_b = in_b ? load_rows<I>(b.done + st.p, kTile, st.two) : all_done;
            // The lanes either state still composites (a and b share the tile's origin).
            F alpha;
            const I act = reached(gs, a, st, start, lx1, base, done_a & done_b, alpha);
            if (!any(act)) return;
            const I act_a = act & ~done_a, act_b = act & ~done_b;
            if (any(act_a)) accumulate(a, st, done_a, act_a, alpha, gs, id, nullptr);
            if (any(act_b)) accumulate(b, st, done_b, act_b, alpha, gs, id, nullptr);
        });
    }
}

// The tile's Gaussians of each layer into that layer's state, in one pass over its list:
// layer[id] in [0, num_layers) picks the state, a negative value none. Each state is updated
// exactly as composite_tile updates it with keep = (layer == k), so each equals that render
// bit for bit; a Gaussian is evaluated once, for its own layer.
CS_CLONES
void composite_tile_layers(const ViewData& v, int tile, const int8_t* layer,
                                          TileState* states, int num_layers) {
    const int32_t* list = v.tile_lists + v.tile_offsets[tile];
    const int64_t len = v.tile_offsets[tile + 1] - v.tile_offsets[tile];
    int live = 0;  // layers with a pixel still compositing
    for (int l = 0; l < num_layers; ++l) live += states[l].remaining > 0;
    for (int64_t k = 0; k < len && live > 0; ++k) {
        if (k + kPrefetch < len && layer[list[k + kPrefetch]] >= 0)
            prefetch_splat(v.splats + list[k + kPrefetch]);
        const int32_t id = list[k];
        const int l = layer[id];
        if (l < 0 || states[l].remaining <= 0) continue;
        TileState& s = states[l];
        add_splat(s, v.splats[id], id, nullptr);
        if (s.remaining <= 0) --live;
    }
}

// Marks the entries of one tile's list that a render of any subset containing `floor` can
// use: live[k] = 1 where entry k, reached in front-to-back order, has alpha >= 1/255 (and
// power <= 0) at a pixel of its box that has not stopped under `floor` alone. The state
// composites only the Gaussians in `floor`, exactly as composite_tile does. A superset of
// `floor` multiplies in more factors 1 - alpha <= 1, so its transmittance is never higher at
// any point of the list (rounding is monotone) and a pixel stopped under `floor` has stopped
// under it too, at the same entry or before: an entry not marked never changes such a render.
CS_CLONES
void mark_tile(const ViewData& v, int tile, const uint8_t* floor, TileState& s,
                              uint8_t* live) {
    const int32_t* list = v.tile_lists + v.tile_offsets[tile];
    const int64_t len = v.tile_offsets[tile + 1] - v.tile_offsets[tile];
    int64_t k = 0;
    for (; k < len && s.remaining > 0; ++k) {
        if (k + kPrefetch < len) prefetch_splat(v.splats + list[k + kPrefetch]);
        const int32_t id = list[k];
        const bool in_floor = floor[id] != 0;
        const Splat& gs = v.splats[id];
        bool used = false;
        for_box(gs, s, [&](const Step& st, int start, int lx1, int base) CS_LAMBDA_INLINE {
            const I done = load_rows<I>(s.done + st.p, kTile, st.two);
            F alpha;
            const I active = reached(gs, s, st, start, lx1, base, done, alpha);
            if (!any(active)) return;
            used = true;
            if (in_floor) accumulate(s, st, done, active, alpha, gs, id, nullptr);
        });
        live[k] = used ? 1 : 0;
    }
    for (; k < len; ++k) live[k] = 0;  // every pixel of the tile has stopped
}

// Writes pixel p of the tile state: rgb = C + T bg, alpha = 1 - T, depth = D / alpha.
inline void finish_pixel(const TileState& s, int p, const float bg[3], float* rgb, float* alpha,
                         float* depth) {
    const float t = s.T[p];
    const float a = 1.0f - t;
    rgb[0] = s.r[p] + t * bg[0];
    rgb[1] = s.g[p] + t * bg[1];
    rgb[2] = s.b[p] + t * bg[2];
    *alpha = a;
    *depth = a > 0.0f ? s.d[p] / a : 0.0f;
}

}  // namespace

void composite_image(const ViewData& v, const uint8_t* keep, const int32_t* tiles,
                     int64_t num_tiles, const float bg[3], float* rgb, float* alpha,
                     float* depth, int num_threads) {
#pragma omp parallel num_threads(team_size(num_threads, num_tiles))
    {
        TileState s;
#pragma omp for schedule(dynamic, 1)
        for (int64_t j = 0; j < num_tiles; ++j) {
            const int tile = tiles ? tiles[j] : int(j);
            s.reset(v, tile, nullptr);
            composite_tile(v, tile, keep, nullptr, 0, s, nullptr);
            for (int ly = 0; ly < s.h; ++ly)
                for (int lx = 0; lx < s.w; ++lx) {
                    const int64_t q = int64_t(s.y0 + ly) * v.width + s.x0 + lx;
                    finish_pixel(s, ly * kTile + lx, bg, rgb + 3 * q, alpha + q, depth + q);
                }
        }
    }
}

void composite_image_pair(const ViewData& v, const uint8_t* keep_a, const uint8_t* keep_b,
                          const int32_t* tiles, int64_t num_tiles, const float bg[3],
                          float* rgb_a, float* alpha_a, float* depth_a, float* rgb_b,
                          float* alpha_b, float* depth_b, int num_threads) {
#pragma omp parallel num_threads(team_size(num_threads, num_tiles))
    {
        TileState a, b;
#pragma omp for schedule(dynamic, 1)
        for (int64_t j = 0; j < num_tiles; ++j) {
            const int tile = tiles ? tiles[j] : int(j);
            a.reset(v, tile, nullptr);
            b.reset(v, tile, nullptr);
            composite_tile_pair(v, tile, keep_a, keep_b, a, b);
            for (int ly = 0; ly < a.h; ++ly)
                for (int lx = 0; lx < a.w; ++lx) {
                    const int64_t q = int64_t(a.y0 + ly) * v.width + a.x0 + lx;
                    const int p = ly * kTile + lx;
                    finish_pixel(a, p, bg, rgb_a + 3 * q, alpha_a + q, depth_a + q);
                    finish_pixel(b, p, bg, rgb_b + 3 * q, alpha_b + q, depth_b + q);
                }
        }
    }
}

void composite_image_layers(const ViewData& v, const int8_t* layer, int num_layers,
                            const int32_t* tiles, int64_t num_tiles, const float bg[3],
                            float* rgb, float* alpha, float* depth, int num_threads) {
    const int64_t px = int64_t(v.width) * v.height;
#pragma omp parallel num_threads(team_size(num_threads, num_tiles))
    {
        Vec<TileState> states(size_t(imax(num_layers, 1)));
#pragma omp for schedule(dynamic, 1)
        for (int64_t j = 0; j < num_tiles; ++j) {
            const int tile = tiles ? tiles[j] : int(j);
            for (int l = 0; l < num_layers; ++l) states[l].reset(v, tile, nullptr);
            composite_tile_layers(v, tile, layer, states.data(), num_layers);
            for (int l = 0; l < num_layers; ++l) {
                const TileState& s = states[l];
                for (int ly = 0; ly < s.h; ++ly)
                    for (int lx = 0; lx < s.w; ++lx) {
                        const int64_t q = int64_t(s.y0 + ly) * v.width + s.x0 + lx;
                        finish_pixel(s, ly * kTile + lx, bg, rgb + 3 * (l * px + q),
                                     alpha + l * px + q, depth + l * px + q);
                    }
            }
        }
    }
}

void composite_patches(const ViewData& v, const Rect* rects, const uint8_t* keep,
                       const int64_t* removal_offsets, const int32_t* removal_ids,
                       int64_t num_removals, const int64_t* task_offsets,
                       const int32_t* task_tiles, const float bg[3], const float* base_rgb,
                       const float* base_alpha, const float* base_depth, float* rgb,
                       float* alpha, float* depth, int num_threads) {
    const int64_t num_tasks = task_offsets[num_removals];
    // Bucket each removal's ids by the tasks (tiles) whose lists they are in.
    Vec<Vec<int32_t>> removed(num_tasks);
#pragma omp parallel num_threads(team_size(num_threads, num_removals))
    {
        Vec<int32_t> local(size_t(v.num_tiles()), -1);
#pragma omp for schedule(dynamic, 1)
        for (int64_t r = 0; r < num_removals; ++r) {
            for (int64_t j = task_offsets[r]; j < task_offsets[r + 1]; ++j) local[task_tiles[j]] = int32_t(j);
            for (int64_t k = removal_offsets[r]; k < removal_offsets[r + 1]; ++k) {
                const int32_t id = removal_ids[k];
                const Rect& rc = rects[id];
                for (int y = rc.y0; y <= rc.y1; ++y)
                    for (int x = rc.x0; x <= rc.x1; ++x) {
                        const int32_t j = local[y * v.grid_w + x];
                        if (j >= 0) removed[j].push_back(id);
                    }
            }
            for (int64_t j = task_offsets[r]; j < task_offsets[r + 1]; ++j) local[task_tiles[j]] = -1;
        }
    }
#pragma omp parallel num_threads(team_size(num_threads, num_tasks))
    {
        TileState s;
        alignas(64) uint8_t changed[kTilePixels];
#pragma omp for schedule(dynamic, 1)
        for (int64_t j = 0; j < num_tasks; ++j) {
            const int tile = task_tiles[j];
            const Vec<int32_t>& ids = removed[j];
            if (base_rgb) {
                // Compositing visits a Gaussian only inside its pixel box, so outside the boxes
                // of the removed Gaussians the result is the base render, bit for bit: only
                // the pixels inside them are composited.
                std::memset(changed, 0, sizeof changed);
                const int tx = (tile % v.grid_w) * kTile, ty = (tile / v.grid_w) * kTile;
                for (const int32_t id : ids) {
                    const Splat& gs = v.splats[id];
                    const int lx0 = imax(int(gs.bx0) - tx, 0), lx1 = imin(int(gs.bx1) - tx, kTile - 1);
                    const int ly0 = imax(int(gs.by0) - ty, 0), ly1 = imin(int(gs.by1) - ty, kTile - 1);
                    for (int ly = ly0; ly <= ly1; ++ly)
                        for (int lx = lx0; lx <= lx1; ++lx) changed[ly * kTile + lx] = 1;
                }
                s.reset(v, tile, nullptr, changed);
            } else {
                s.reset(v, tile, nullptr);
            }
            if (s.remaining > 0)
                composite_tile(v, tile, keep, ids.data(), int64_t(ids.size()), s, nullptr);
            float* prgb = rgb + int64_t(3) * kTilePixels * j;
            float* palpha = alpha + int64_t(kTilePixels) * j;
            float* pdepth = depth + int64_t(kTilePixels) * j;
            for (int p = 0; p < kTilePixels; ++p) {
                if (p % kTile < s.w && p / kTile < s.h) {
                    if (base_rgb && !changed[p]) {
                        const int64_t q = int64_t(s.y0 + p / kTile) * v.width + s.x0 + p % kTile;
                        for (int c = 0; c < 3; ++c) prgb[3 * p + c] = base_rgb[3 * q + c];
                        palpha[p] = base_alpha[q];
                        pdepth[p] = base_depth[q];
                    } else {
                        finish_pixel(s, p, bg, prgb + 3 * p, palpha + p, pdepth + p);
                    }
                } else {
                    prgb[3 * p] = prgb[3 * p + 1] = prgb[3 * p + 2] = 0.0f;
                    palpha[p] = pdepth[p] = 0.0f;
                }
            }
        }
    }
}

void live_entries(const ViewData& v, const uint8_t* floor, uint8_t* live, int num_threads) {
#pragma omp parallel num_threads(num_threads)
    {
        TileState s;
#pragma omp for schedule(dynamic, 1)
        for (int tile = 0; tile < v.num_tiles(); ++tile) {
            s.reset(v, tile, nullptr);
            mark_tile(v, tile, floor, s, live + v.tile_offsets[tile]);
        }
    }
}

ContribResult contributions(const ViewData& v, const uint8_t* keep, const uint8_t* mask,
                            int num_threads) {
    const int num_tiles = v.num_tiles();
    Vec<Vec<Entry>> per_tile(num_tiles);
    Vec<int64_t> offsets(int64_t(v.width) * v.height + 1, 0);  // count per pixel first
#pragma omp parallel num_threads(num_threads)
    {
        TileState s;
#pragma omp for schedule(dynamic, 1)
        for (int tile = 0; tile < num_tiles; ++tile) {
            s.reset(v, tile, mask);
            if (s.remaining == 0) continue;
            Vec<Entry>& out = per_tile[tile];
            composite_tile(v, tile, keep, nullptr, 0, s, &out);
            for (const Entry& e : out)
                ++offsets[1 + int64_t(s.y0 + e.pixel_in_tile / kTile) * v.width + s.x0 +
                          e.pixel_in_tile % kTile];
        }
    }
    const int64_t num_pixels = int64_t(v.width) * v.height;
    for (int64_t q = 0; q < num_pixels; ++q) offsets[q + 1] += offsets[q];
    ContribResult res;
    res.num = offsets[num_pixels];
    const size_t cap = size_t(res.num > 1 ? res.num : 1);
    res.pixel = static_cast<int64_t*>(std::malloc(cap * sizeof(int64_t)));
    res.id = static_cast<int32_t*>(std::malloc(cap * sizeof(int32_t)));
    res.weight = static_cast<float*>(std::malloc(cap * sizeof(float)));
    // Entries of a pixel are in compositing order within its tile; scatter keeps that order.
#pragma omp parallel for schedule(dynamic, 1) num_threads(num_threads)
    for (int tile = 0; tile < num_tiles; ++tile) {
        const int x0 = (tile % v.grid_w) * kTile, y0 = (tile / v.grid_w) * kTile;
        for (const Entry& e : per_tile[tile]) {
            const int64_t q = int64_t(y0 + e.pixel_in_tile / kTile) * v.width + x0 + e.pixel_in_tile % kTile;
            const int64_t at = offsets[q]++;
            res.pixel[at] = q;
            res.id[at] = e.id;
            res.weight[at] = e.weight;
        }
    }
    return res;
}

}  // namespace CS_COMPOSITE_VARIANT

#ifndef CS_COMPOSITE_V4
// The public functions: the two-row kernels where the machine has AVX-512, else these.

#ifdef CS_HAVE_V4
namespace v4 {
decltype(cs::composite_image) composite_image;
decltype(cs::composite_image_pair) composite_image_pair;
decltype(cs::composite_image_layers) composite_image_layers;
decltype(cs::composite_patches) composite_patches;
decltype(cs::live_entries) live_entries;
decltype(cs::contributions) contributions;
}  // namespace v4
#define CS_PICK(f) (rows_per_step() == 2 ? v4::f : generic::f)
#else
#define CS_PICK(f) generic::f
#endif

namespace {
int detect_rows() {
#ifdef CS_HAVE_V4
    __builtin_cpu_init();
    return __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512vl") &&
                   __builtin_cpu_supports("avx512bw") && __builtin_cpu_supports("avx512dq") &&
                   __builtin_cpu_supports("avx512cd") && __builtin_cpu_supports("avx2") &&
                   __builtin_cpu_supports("fma") && __builtin_cpu_supports("bmi2")
               ? 2
               : 1;
#else
    return 1;
#endif
}
const int g_machine_rows = detect_rows();
int g_rows = g_machine_rows;
}  // namespace

int rows_per_step() { return g_rows; }

void set_rows_per_step(int rows) {
    g_rows = rows == 1 || (rows == 2 && g_machine_rows == 2) ? rows : g_machine_rows;
}

void composite_image(const ViewData& v, const uint8_t* keep, const int32_t* tiles,
                     int64_t num_tiles, const float bg[3], float* rgb, float* alpha,
                     float* depth, int num_threads) {
    CS_PICK(composite_image)(v, keep, tiles, num_tiles, bg, rgb, alpha, depth, num_threads);
}

void composite_image_pair(const ViewData& v, const uint8_t* keep_a, const uint8_t* keep_b,
                          const int32_t* tiles, int64_t num_tiles, const float bg[3],
                          float* rgb_a, float* alpha_a, float* depth_a, float* rgb_b,
                          float* alpha_b, float* depth_b, int num_threads) {
    CS_PICK(composite_image_pair)(v, keep_a, keep_b, tiles, num_tiles, bg, rgb_a, alpha_a,
                                  depth_a, rgb_b, alpha_b, depth_b, num_threads);
}

void composite_image_layers(const ViewData& v, const int8_t* layer, int num_layers,
                            const int32_t* tiles, int64_t num_tiles, const float bg[3],
                            float* rgb, float* alpha, float* depth, int num_threads) {
    CS_PICK(composite_image_layers)(v, layer, num_layers, tiles, num_tiles, bg, rgb, alpha,
                                    depth, num_threads);
}

void composite_patches(const ViewData& v, const Rect* rects, const uint8_t* keep,
                       const int64_t* removal_offsets, const int32_t* removal_ids,
                       int64_t num_removals, const int64_t* task_offsets,
                       const int32_t* task_tiles, const float bg[3], const float* base_rgb,
                       const float* base_alpha, const float* base_depth, float* rgb,
                       float* alpha, float* depth, int num_threads) {
    CS_PICK(composite_patches)(v, rects, keep, removal_offsets, removal_ids, num_removals,
                               task_offsets, task_tiles, bg, base_rgb, base_alpha, base_depth,
                               rgb, alpha, depth, num_threads);
}

void live_entries(const ViewData& v, const uint8_t* floor, uint8_t* live, int num_threads) {
    CS_PICK(live_entries)(v, floor, live, num_threads);
}

ContribResult contributions(const ViewData& v, const uint8_t* keep, const uint8_t* mask,
                            int num_threads) {
    return CS_PICK(contributions)(v, keep, mask, num_threads);
}
#endif  // CS_COMPOSITE_V4

}  // namespace cs
