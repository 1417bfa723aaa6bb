// Per-tile front-to-back alpha compositing (the 3DGS forward pass), for full images, for
// batched incremental tile patches and for the per-pixel contribution lists.
#include <omp.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <vector>

#include "raster.h"
#include "simd.h"

namespace cs {

namespace {

constexpr int64_t kPrefetch = 8;

// Fetches a record ahead of use: 48-byte records straddle two cache lines at every other
// position, so both ends are fetched.
inline void prefetch_splat(const Splat* s) {
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
        w = std::min(kTile, v.width - x0);
        h = std::min(kTile, v.height - y0);
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

// Adds one Gaussian's contribution to the `active` lanes of pixels [p, p + 8) of `s`, the
// 3DGS rule: where T would fall below 1e-4 the pixel stops without adding; elsewhere
// C += c * alpha * T, D += z * alpha * T, T *= 1 - alpha.
__attribute__((always_inline)) inline void accumulate(TileState& s, int p, i8 done, i8 active,
                                                      f8 alpha, const Splat& gs, int32_t id,
                                                      std::vector<Entry>* record) {
    const f8 t = load(s.T + p);
    const f8 test_t = t * (1.0f - alpha);
    const i8 stop = active & (test_t < kMinTransmittance);
    const i8 add = active & ~stop;
    const f8 weight = alpha * t;
    const f8 zero = splat(0.0f);
    store(s.T + p, select(add, test_t, t));
    store(s.r + p, load(s.r + p) + select(add, gs.rgb[0] * weight, zero));
    store(s.g + p, load(s.g + p) + select(add, gs.rgb[1] * weight, zero));
    store(s.b + p, load(s.b + p) + select(add, gs.rgb[2] * weight, zero));
    store(s.d + p, load(s.d + p) + select(add, gs.depth * weight, zero));
    if (any(stop)) {
        store(s.done + p, done | stop);
        s.remaining -= count(stop);
    }
    if (record)
        for (int l = 0; l < 8; ++l)
            if (add[l]) record->push_back(Entry{p + l, id, weight[l]});
}

// The lanes of pixels [p, p + 8) (row ly of the tile, p = 16 ly + base) that `gs` reaches:
// inside its box columns [start, lx1], not `done`, power <= 0 and alpha >= 1/255, with their
// alpha (capped at 0.99) in `alpha`. The 3DGS per-pixel test, shared by every compositing loop.
__attribute__((always_inline)) inline i8 reached(const Splat& gs, const TileState& s, int start,
                                                 int lx1, int base, float dy, i8 done,
                                                 f8& alpha) {
    const i8 iota = {0, 1, 2, 3, 4, 5, 6, 7};
    const i8 col = iota + base;
    i8 active = (col >= start) & (col <= lx1) & ~done;
    if (!any(active)) return active;
    const f8 dx = gs.u - (__builtin_convertvector(col + s.x0, f8) + 0.5f);
    const f8 power = -0.5f * (gs.ca * dx * dx + gs.cc * dy * dy) - gs.cb * dx * dy;
    active &= power <= 0.0f;
    alpha = gs.opacity * exp_nonpositive(power);
    alpha = select(alpha < kMaxAlpha, alpha, splat(kMaxAlpha));
    return active & (alpha >= kMinAlpha);
}

// Adds `gs` (visible id `id`) to the pixels of its box inside the tile of `s`: the 3DGS rule per
// pixel (reached, accumulate), eight pixels of a row at a time.
__attribute__((always_inline)) inline void add_splat(TileState& s, const Splat& gs, int32_t id,
                                                     std::vector<Entry>* record) {
    const int lx0 = std::max(int(gs.bx0) - s.x0, 0), lx1 = std::min(int(gs.bx1) - s.x0, s.w - 1);
    const int ly0 = std::max(int(gs.by0) - s.y0, 0), ly1 = std::min(int(gs.by1) - s.y0, s.h - 1);
    for (int ly = ly0; ly <= ly1; ++ly) {
        const float dy = gs.v - (float(s.y0 + ly) + 0.5f);
        for (int start = lx0; start <= lx1; start += 8) {
            const int base = std::min(start, kTile - 8);  // the 8 lanes stay in the row
            const int p = ly * kTile + base;
            const i8 done = load(s.done + p);
            f8 alpha;
            const i8 active = reached(gs, s, start, lx1, base, dy, done, alpha);
            if (any(active)) accumulate(s, p, done, active, alpha, gs, id, record);
        }
    }
}

// Composites one tile's list into `s`, skipping ids with keep[id] == 0 and the ascending ids
// in `removed`; appends every added contribution to `record` when given.
//
// Per pixel this is the 3DGS loop: skip power > 0 and alpha < 1/255, stop (without adding)
// when T would fall below 1e-4, else add c * alpha * T. It runs eight pixels of a row at a
// time over each Gaussian's pixel box; lanes outside the box or already done change nothing.
CS_TARGET_CLONES
void composite_tile(const ViewData& v, int tile, const uint8_t* keep, const int32_t* removed,
                    int64_t num_removed, TileState& s, std::vector<Entry>* record) {
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
CS_TARGET_CLONES
void composite_tile_pair(const ViewData& v, int tile, const uint8_t* keep_a,
                         const uint8_t* keep_b, TileState& a, TileState& b) {
    const int32_t* list = v.tile_lists + v.tile_offsets[tile];
    const int64_t len = v.tile_offsets[tile + 1] - v.tile_offsets[tile];
    const i8 iota = {0, 1, 2, 3, 4, 5, 6, 7};
    const i8 all_done = iota == iota;
    for (int64_t k = 0; k < len && (a.remaining > 0 || b.remaining > 0); ++k) {
        if (k + kPrefetch < len) prefetch_splat(v.splats + list[k + kPrefetch]);
        const int32_t id = list[k];
        const bool in_a = a.remaining > 0 && (!keep_a || keep_a[id]);
        const bool in_b = b.remaining > 0 && keep_b[id];
        if (!in_a && !in_b) continue;
        const Splat& gs = v.splats[id];
        const int lx0 = std::max(int(gs.bx0) - a.x0, 0), lx1 = std::min(int(gs.bx1) - a.x0, a.w - 1);
        const int ly0 = std::max(int(gs.by0) - a.y0, 0), ly1 = std::min(int(gs.by1) - a.y0, a.h - 1);
        for (int ly = ly0; ly <= ly1; ++ly) {
            const float dy = gs.v - (float(a.y0 + ly) + 0.5f);
            for (int start = lx0; start <= lx1; start += 8) {
                const int base = std::min(start, kTile - 8);
                const int p = ly * kTile + base;
                const i8 done_a = in_a ? load(a.done + p) : all_done;
                const i8 done_b = in_b ? load(b.done + p) : all_done;
                // The lanes either state still composites (a and b share the tile's origin).
                f8 alpha;
                const i8 act = reached(gs, a, start, lx1, base, dy, done_a & done_b, alpha);
                if (!any(act)) continue;
                const i8 act_a = act & ~done_a, act_b = act & ~done_b;
                if (any(act_a)) accumulate(a, p, done_a, act_a, alpha, gs, id, nullptr);
                if (any(act_b)) accumulate(b, p, done_b, act_b, alpha, gs, id, nullptr);
            }
        }
    }
}

// The tile's Gaussians of each layer into that layer's state, in one pass over its list:
// layer[id] in [0, num_layers) picks the state, a negative value none. Each state is updated
// exactly as composite_tile updates it with keep = (layer == k), so each equals that render
// bit for bit; a Gaussian is evaluated once, for its own layer.
CS_TARGET_CLONES
void composite_tile_layers(const ViewData& v, int tile, const int8_t* layer, TileState* states,
                           int num_layers) {
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
CS_TARGET_CLONES
void mark_tile(const ViewData& v, int tile, const uint8_t* floor, TileState& s, uint8_t* live) {
    const int32_t* list = v.tile_lists + v.tile_offsets[tile];
    const int64_t len = v.tile_offsets[tile + 1] - v.tile_offsets[tile];
    int64_t k = 0;
    for (; k < len && s.remaining > 0; ++k) {
        if (k + kPrefetch < len) prefetch_splat(v.splats + list[k + kPrefetch]);
        const int32_t id = list[k];
        const bool in_floor = floor[id] != 0;
        const Splat& gs = v.splats[id];
        const int lx0 = std::max(int(gs.bx0) - s.x0, 0), lx1 = std::min(int(gs.bx1) - s.x0, s.w - 1);
        const int ly0 = std::max(int(gs.by0) - s.y0, 0), ly1 = std::min(int(gs.by1) - s.y0, s.h - 1);
        bool used = false;
        for (int ly = ly0; ly <= ly1; ++ly) {
            const float dy = gs.v - (float(s.y0 + ly) + 0.5f);
            for (int start = lx0; start <= lx1; start += 8) {
                const int base = std::min(start, kTile - 8);
                const int p = ly * kTile + base;
                const i8 done = load(s.done + p);
                f8 alpha;
                const i8 active = reached(gs, s, start, lx1, base, dy, done, alpha);
                if (!any(active)) continue;
                used = true;
                if (in_floor) accumulate(s, p, done, active, alpha, gs, id, nullptr);
            }
        }
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
        std::vector<TileState> states(size_t(std::max(num_layers, 1)));
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
    std::vector<std::vector<int32_t>> removed(num_tasks);
#pragma omp parallel num_threads(team_size(num_threads, num_removals))
    {
        std::vector<int32_t> local(size_t(v.num_tiles()), -1);
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
            const std::vector<int32_t>& ids = removed[j];
            if (base_rgb) {
                // Compositing visits a Gaussian only inside its pixel box, so outside the boxes
                // of the removed Gaussians the result is the base render, bit for bit: only
                // the pixels inside them are composited.
                std::fill(changed, changed + kTilePixels, uint8_t(0));
                const int tx = (tile % v.grid_w) * kTile, ty = (tile / v.grid_w) * kTile;
                for (const int32_t id : ids) {
                    const Splat& gs = v.splats[id];
                    const int lx0 = std::max(int(gs.bx0) - tx, 0), lx1 = std::min(int(gs.bx1) - tx, kTile - 1);
                    const int ly0 = std::max(int(gs.by0) - ty, 0), ly1 = std::min(int(gs.by1) - ty, kTile - 1);
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
    std::vector<std::vector<Entry>> per_tile(num_tiles);
    std::vector<int64_t> offsets(int64_t(v.width) * v.height + 1, 0);  // count per pixel first
#pragma omp parallel num_threads(num_threads)
    {
        TileState s;
#pragma omp for schedule(dynamic, 1)
        for (int tile = 0; tile < num_tiles; ++tile) {
            s.reset(v, tile, mask);
            if (s.remaining == 0) continue;
            std::vector<Entry>& out = per_tile[tile];
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
    const size_t cap = size_t(std::max<int64_t>(res.num, 1));
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

}  // namespace cs
