// Shared types of the CPU rasterizer: the packed per-Gaussian record, tile rectangles and the
// read-only view of a prepared camera. Conventions: docs/conventions.md ("Rasterization").
#pragma once

#include <cstddef>
#include <cstdint>

namespace cs {

constexpr int kTile = 16;                  // tiles are kTile x kTile pixels
constexpr int kTilePixels = kTile * kTile;
constexpr float kMinAlpha = 1.0f / 255.0f;  // contributions below this are skipped
constexpr float kMaxAlpha = 0.99f;
constexpr float kMinTransmittance = 1e-4f;  // a pixel stops before T would drop below this

// One visible Gaussian as the compositing reads it (48 bytes; Python sees (V, 12) float32).
// The pixel box [bx0, bx1] x [by0, by1] (inclusive, clamped to the image) holds every pixel
// where alpha can reach 1/255: outside it the contribution is skipped anyway, so compositing
// only visits the box. It is a slightly padded bound, so results equal a full tile sweep.
struct Splat {
    float u, v;         // projected centre in image coordinates (pixel centres at +0.5)
    float ca, cb, cc;   // conic: inverse 2D covariance [[ca, cb], [cb, cc]]
    float opacity;
    float rgb[3];       // colour from the SH for this camera, clamped at 0
    float depth;        // camera z
    int16_t bx0, bx1, by0, by1;
};
static_assert(sizeof(Splat) == 48, "Splat must stay 12 floats");

// Inclusive range of tiles a Gaussian is binned into (Python sees (V, 4) uint16).
struct Rect {
    uint16_t x0, y0, x1, y1;
};

// A prepared view: visible Gaussians in front-to-back order (sorted by camera z, ties by
// Gaussian index), so a tile's list of ids is ascending.
struct ViewData {
    const Splat* splats;
    int64_t num;
    const int64_t* tile_offsets;  // (num_tiles + 1,)
    const int32_t* tile_lists;    // ids into splats, ascending within a tile
    int width, height, grid_w, grid_h;
    int num_tiles() const { return grid_w * grid_h; }
};

struct ProjectParams {
    double view[12];  // world-to-camera, rows of the 3x4 [R | t]
    double fx, fy, cx, cy;
    double campos[3];
    int width, height;
    double near_plane;
    double eps2d = 0.3;        // added to the 2D covariance's diagonal (pixels^2)
    bool antialiased = false;  // scale opacity by sqrt(det(Sigma2D) / det(Sigma2D + eps2d I))
    double radius_clip = 0.0;  // cull Gaussians whose pixel radius ceil(3 sqrt(lambda)) <= this
};

struct ProjectInputs {
    const float* means;      // (N, 3)
    const float* scales;     // (N, 3)
    const float* quats;      // (N, 4) w x y z
    const float* opacities;  // (N,)
    const float* sh;         // (N, K, 3)
    int sh_k;
    int64_t n;
    const uint8_t* keep;     // (N,) or null
};

// Project, cull and sort. Outputs are malloc'ed arrays owned by the caller (free()).
struct ProjectResult {
    Splat* splats = nullptr;
    Rect* rects = nullptr;
    int32_t* index = nullptr;  // original Gaussian index of each visible Gaussian
    int64_t num = 0;
};
ProjectResult project(const ProjectInputs& in, const ProjectParams& p, int num_threads);

// Stable LSD radix sort of (key, value) pairs by key. tmp arrays hold n entries each.
void radix_sort_pairs(uint32_t* keys, uint32_t* values, int64_t n, uint32_t* tmp_keys,
                      uint32_t* tmp_values, int num_threads);

// Tile binning: offsets (num_tiles + 1) and ascending ids per tile; malloc'ed.
struct BinResult {
    int64_t* offsets = nullptr;
    int32_t* lists = nullptr;
    int64_t num_pairs = 0;
};
BinResult bin_tiles(const Rect* rects, int64_t num, int grid_w, int grid_h, int num_threads);

// For each group of ids (CSR), the sorted unique tiles of their rectangles (CSR, malloc'ed).
struct TileSets {
    int64_t* offsets = nullptr;
    int32_t* tiles = nullptr;
    int64_t total = 0;
};
TileSets tiles_touched(const Rect* rects, const int64_t* group_offsets, const int32_t* ids,
                       int64_t num_groups, int grid_w, int grid_h, int num_threads);

// Restricts a prepared view, in place, to the subset `keep` (n,) of its scene's Gaussians,
// renumbered as the subset scene numbers them: the records, ids and tile lists of the kept
// Gaussians move to the front of their arrays, in their order; `offsets` is rewritten. Sets
// the new record and pair counts; false (nothing changed) if an id is out of range.
bool restrict_view(Splat* splats, Rect* rects, int32_t* index, int64_t num, int64_t* offsets,
                   int32_t* lists, int64_t num_tiles, const uint8_t* keep, int64_t n,
                   int64_t& new_num, int64_t& new_pairs);

// Composite `tiles` (all when tiles == null) into full images (H, W, 3), (H, W), (H, W).
void composite_image(const ViewData& v, const uint8_t* keep, const int32_t* tiles,
                     int64_t num_tiles, const float bg[3], float* rgb, float* alpha,
                     float* depth, int num_threads);

// `tiles` (all when null) twice in one pass: the Gaussians with keep_a[id] (all when null)
// into (rgb_a, alpha_a, depth_a) and those with keep_b[id] into (rgb_b, ...); each equals its
// separate composite_image bit for bit.
void composite_image_pair(const ViewData& v, const uint8_t* keep_a, const uint8_t* keep_b,
                          const int32_t* tiles, int64_t num_tiles, const float bg[3],
                          float* rgb_a, float* alpha_a, float* depth_a, float* rgb_b,
                          float* alpha_b, float* depth_b, int num_threads);

// Every layer of a view in one pass over its tile lists: the Gaussians with layer[id] == k
// (k < num_layers <= 127; negative: in none) into rgb[k] (K, H, W, 3), alpha[k] and depth[k]
// (K, H, W) each, in the num_tiles tiles of `tiles` (only those pixels are written); each equals
// its separate composite_image bit for bit there.
void composite_image_layers(const ViewData& v, const int8_t* layer, int num_layers,
                            const int32_t* tiles, int64_t num_tiles, const float bg[3],
                            float* rgb, float* alpha, float* depth, int num_threads);

// Batched incremental compositing: task j re-composites tile task_tiles[j] for the removal
// task_removal[j], skipping that removal's ids (CSR, sorted ascending per removal). With a base
// (the full (H, W) render of `keep`; null for none), only the pixels inside the removed
// Gaussians' boxes are composited and the others are copied from it (the same bits).
void composite_patches(const ViewData& v, const Rect* rects, const uint8_t* keep,
                       const int64_t* removal_offsets, const int32_t* removal_ids,
                       int64_t num_removals, const int64_t* task_offsets,
                       const int32_t* task_tiles, const float bg[3], const float* base_rgb,
                       const float* base_alpha, const float* base_depth, float* rgb,
                       float* alpha, float* depth, int num_threads);

// live (P,): 1 for the tile-list entries that some render of a subset containing floor
// (V,) can use, 0 for those it never reaches (every pixel of their box stopped before them, or
// alpha below 1/255 there); a view without the 0 entries renders such subsets identically.
void live_entries(const ViewData& v, const uint8_t* floor, uint8_t* live, int num_threads);

// Every (pixel, id, weight) the compositing adds at the masked pixels (malloc'ed, ordered by
// pixel then front to back).
struct ContribResult {
    int64_t* pixel = nullptr;
    int32_t* id = nullptr;
    float* weight = nullptr;
    int64_t num = 0;
};
ContribResult contributions(const ViewData& v, const uint8_t* keep, const uint8_t* mask,
                            int num_threads);

// Rows of pixels the compositing loops take per step: 2 on machines with AVX-512 (sixteen
// lanes in one instruction), else 1. Every lane does the same IEEE operations either way, so
// the results are the same bits; set_rows_per_step(1 or 2) chooses by hand, 0 by the machine.
int rows_per_step();
void set_rows_per_step(int rows);

// Threads for a parallel loop over `items` independent pieces of work: never more than the
// pieces, so that a loop over one or two tiles or removals runs on the calling thread (on a
// busy machine a parallel region can wait a scheduler slice for a thread that is not running).
inline int team_size(int num_threads, int64_t items) {
    return items < num_threads ? int(items > 1 ? items : 1) : num_threads;
}

}  // namespace cs
