// Python bindings for the native core: one function per kernel. Defaults, validation and
// conversions live in Python (clearsplat/render/_kernels.py); the checks here only guard memory.
// Every kernel runs without the GIL.
#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>
#include <omp.h>

#include <algorithm>
#include <cstdlib>
#include <new>
#include <stdexcept>
#include <string>

#include "raster.h"

namespace nb = nanobind;
using namespace nb::literals;

namespace {

template <class T>
using In = nb::ndarray<const T, nb::c_contig, nb::device::cpu>;
template <class T>
using Out = nb::ndarray<T, nb::c_contig, nb::device::cpu>;

void require(bool ok, const char* what) {
    if (!ok) throw std::invalid_argument(std::string("clearsplat._core: ") + what);
}

// Hands a malloc'ed buffer to NumPy, which frees it with the array.
template <class T>
nb::ndarray<nb::numpy, T> owned(T* data, std::initializer_list<size_t> shape) {
    nb::capsule owner(data, [](void* p) noexcept { std::free(p); });
    return nb::ndarray<nb::numpy, T>(data, shape, owner);
}

int threads(int n) { return n > 0 ? n : omp_get_max_threads(); }

cs::ViewData view_of(const In<float>& splats, const In<int64_t>& offsets,
                     const In<int32_t>& lists, int width, int height) {
    require(splats.ndim() == 2 && splats.shape(1) == 12, "splats must be (V, 12)");
    cs::ViewData v;
    v.splats = reinterpret_cast<const cs::Splat*>(splats.data());
    v.num = int64_t(splats.shape(0));
    v.width = width;
    v.height = height;
    v.grid_w = (width + cs::kTile - 1) / cs::kTile;
    v.grid_h = (height + cs::kTile - 1) / cs::kTile;
    require(width > 0 && height > 0, "bad image size");
    require(int64_t(offsets.size()) == int64_t(v.num_tiles()) + 1, "tile offsets size");
    v.tile_offsets = offsets.data();
    v.tile_lists = lists.data();
    require(v.tile_offsets[v.num_tiles()] == int64_t(lists.size()), "tile lists size");
    return v;
}

const uint8_t* keep_of(const In<uint8_t>& keep, int64_t n) {
    if (keep.size() == 0) return nullptr;
    require(int64_t(keep.size()) == n, "keep size");
    return keep.data();
}

nb::tuple project(In<float> means, In<float> scales, In<float> quats, In<float> opacities,
                  In<float> sh, In<uint8_t> keep, In<double> view, In<double> intrinsics,
                  In<double> campos, int width, int height, double near_plane, double eps2d,
                  bool antialiased, double radius_clip, int num_threads) {
    const int64_t n = means.ndim() == 2 ? int64_t(means.shape(0)) : -1;
    require(means.ndim() == 2 && means.shape(1) == 3, "means must be (N, 3)");
    require(int64_t(scales.size()) == 3 * n && int64_t(quats.size()) == 4 * n &&
                int64_t(opacities.size()) == n, "per-Gaussian array sizes");
    require(sh.ndim() == 3 && int64_t(sh.shape(0)) == n && sh.shape(2) == 3, "sh must be (N, K, 3)");
    const size_t k = sh.shape(1);
    require(k == 1 || k == 4 || k == 9 || k == 16 || k == 25, "sh must have K in 1, 4, 9, 16, 25");
    require(view.size() == 12 && intrinsics.size() == 4 && campos.size() == 3, "camera sizes");
    cs::ProjectInputs in{means.data(), scales.data(), quats.data(), opacities.data(), sh.data(),
                         int(sh.shape(1)), n, keep_of(keep, n)};
    cs::ProjectParams p;
    for (int k = 0; k < 12; ++k) p.view[k] = view.data()[k];
    p.fx = intrinsics.data()[0], p.fy = intrinsics.data()[1];
    p.cx = intrinsics.data()[2], p.cy = intrinsics.data()[3];
    for (int k = 0; k < 3; ++k) p.campos[k] = campos.data()[k];
    p.width = width, p.height = height, p.near_plane = near_plane;
    p.eps2d = eps2d, p.antialiased = antialiased, p.radius_clip = radius_clip;
    cs::ProjectResult r;
    {
        nb::gil_scoped_release release;
        r = cs::project(in, p, threads(num_threads));
    }
    const size_t v = size_t(r.num);
    return nb::make_tuple(owned(reinterpret_cast<float*>(r.splats), {v, 12}),
                          owned(reinterpret_cast<uint16_t*>(r.rects), {v, 4}),
                          owned(r.index, {v}));
}

nb::tuple bin_tiles(In<uint16_t> rects, int grid_w, int grid_h, int num_threads) {
    require(rects.ndim() == 2 && rects.shape(1) == 4, "rects must be (V, 4)");
    cs::BinResult r;
    {
        nb::gil_scoped_release release;
        r = cs::bin_tiles(reinterpret_cast<const cs::Rect*>(rects.data()), int64_t(rects.shape(0)),
                          grid_w, grid_h, threads(num_threads));
    }
    return nb::make_tuple(owned(r.offsets, {size_t(grid_w) * grid_h + 1}),
                          owned(r.lists, {size_t(r.num_pairs)}));
}

nb::tuple restrict_view(Out<float> splats, Out<uint16_t> rects, Out<int32_t> index,
                        Out<int64_t> offsets, Out<int32_t> lists, In<uint8_t> keep) {
    require(splats.ndim() == 2 && splats.shape(1) == 12, "splats must be (V, 12)");
    const int64_t num = int64_t(splats.shape(0));
    require(rects.ndim() == 2 && rects.shape(1) == 4 && int64_t(rects.shape(0)) == num &&
                int64_t(index.size()) == num, "rects / index size");
    const int64_t num_tiles = int64_t(offsets.size()) - 1;
    const int64_t* off = offsets.data();
    require(num_tiles >= 0 && off[0] == 0 && off[num_tiles] == int64_t(lists.size()),
            "tile lists size");
    for (int64_t t = 0; t < num_tiles; ++t) require(off[t] <= off[t + 1], "tile offsets order");
    for (size_t e = 0; e < lists.size(); ++e)
        require(lists.data()[e] >= 0 && int64_t(lists.data()[e]) < num, "tile list id");
    int64_t new_num = 0, new_pairs = 0;
    bool ok;
    {
        nb::gil_scoped_release release;
        ok = cs::restrict_view(reinterpret_cast<cs::Splat*>(splats.data()),
                               reinterpret_cast<cs::Rect*>(rects.data()), index.data(), num,
                               offsets.data(), lists.data(), num_tiles, keep.data(),
                               int64_t(keep.size()), new_num, new_pairs);
    }
    require(ok, "index out of range");
    return nb::make_tuple(new_num, new_pairs);
}

nb::tuple tiles_touched(In<uint16_t> rects, In<int64_t> group_offsets, In<int32_t> ids,
                        int grid_w, int grid_h, int num_threads) {
    const int64_t groups = int64_t(group_offsets.size()) - 1;
    require(groups >= 0 && group_offsets.data()[groups] == int64_t(ids.size()), "group offsets");
    cs::TileSets r;
    {
        nb::gil_scoped_release release;
        r = cs::tiles_touched(reinterpret_cast<const cs::Rect*>(rects.data()), group_offsets.data(),
                              ids.data(), groups, grid_w, grid_h, threads(num_threads));
    }
    return nb::make_tuple(owned(r.offsets, {size_t(groups) + 1}), owned(r.tiles, {size_t(r.total)}));
}

void composite(In<float> splats, In<int64_t> offsets, In<int32_t> lists, In<uint8_t> keep,
               In<int32_t> tiles, int width, int height, In<float> background, Out<float> rgb,
               Out<float> alpha, Out<float> depth, int num_threads) {
    const cs::ViewData v = view_of(splats, offsets, lists, width, height);
    const int64_t px = int64_t(width) * height;
    require(int64_t(rgb.size()) == 3 * px && int64_t(alpha.size()) == px &&
                int64_t(depth.size()) == px && background.size() == 3, "output sizes");
    nb::gil_scoped_release release;
    cs::composite_image(v, keep_of(keep, v.num), tiles.data(), int64_t(tiles.size()),
                        background.data(), rgb.data(), alpha.data(), depth.data(),
                        threads(num_threads));
}

void composite_pair(In<float> splats, In<int64_t> offsets, In<int32_t> lists,
                    In<uint8_t> keep_a, In<uint8_t> keep, In<int32_t> tiles,
                    int width, int height, In<float> background, Out<float> rgb_a,
                    Out<float> alpha_a, Out<float> depth_a, Out<float> rgb_b, Out<float> alpha_b,
                    Out<float> depth_b, int num_threads) {
    const cs::ViewData v = view_of(splats, offsets, lists, width, height);
    const int64_t px = int64_t(width) * height;
    require(int64_t(keep.size()) == v.num, "keep size");
    require(int64_t(rgb_a.size()) == 3 * px && int64_t(alpha_a.size()) == px &&
                int64_t(depth_a.size()) == px && int64_t(rgb_b.size()) == 3 * px &&
                int64_t(alpha_b.size()) == px && int64_t(depth_b.size()) == px &&
                background.size() == 3, "output sizes");
    nb::gil_scoped_release release;
    cs::composite_image_pair(v, keep_of(keep_a, v.num), keep.data(), tiles.data(),
                             int64_t(tiles.size()), background.data(), rgb_a.data(), alpha_a.data(),
                             depth_a.data(), rgb_b.data(), alpha_b.data(), depth_b.data(),
                             threads(num_threads));
}

void composite_layers(In<float> splats, In<int64_t> offsets, In<int32_t> lists,
                      In<int8_t> layer, int num_layers, In<int32_t> tiles, int width, int height,
                      In<float> background, Out<float> rgb, Out<float> alpha, Out<float> depth,
                      int num_threads) {
    const cs::ViewData v = view_of(splats, offsets, lists, width, height);
    const int64_t px = int64_t(width) * height;
    require(int64_t(layer.size()) == v.num, "layer size");
    require(num_layers >= 0 && num_layers <= 127, "layer count");
    require(int64_t(rgb.size()) == 3 * px * num_layers &&
                int64_t(alpha.size()) == px * num_layers &&
                int64_t(depth.size()) == px * num_layers && background.size() == 3,
            "output sizes");
    const int8_t* l = layer.data();
    for (int64_t i = 0; i < v.num; ++i) require(l[i] < num_layers, "layer out of range");
    const int32_t* t = tiles.data();
    for (size_t j = 0; j < tiles.size(); ++j)
        require(t[j] >= 0 && t[j] < v.num_tiles(), "tile out of range");
    nb::gil_scoped_release release;
    cs::composite_image_layers(v, l, num_layers, t, int64_t(tiles.size()), background.data(),
                               rgb.data(), alpha.data(), depth.data(), threads(num_threads));
}

void composite_patches(In<float> splats, In<int64_t> offsets, In<int32_t> lists,
                       In<uint16_t> rects, In<uint8_t> keep, In<int64_t> removal_offsets,
                       In<int32_t> removal_ids, In<int64_t> task_offsets, In<int32_t> task_tiles,
                       int width, int height, In<float> background, In<float> base_rgb,
                       In<float> base_alpha, In<float> base_depth, Out<float> rgb,
                       Out<float> alpha, Out<float> depth, int num_threads) {
    const cs::ViewData v = view_of(splats, offsets, lists, width, height);
    const int64_t pixels = int64_t(width) * height;
    const bool with_base = base_rgb.size() > 0;
    require(!with_base || (int64_t(base_rgb.size()) == 3 * pixels &&
                           int64_t(base_alpha.size()) == pixels &&
                           int64_t(base_depth.size()) == pixels), "base sizes");
    const int64_t removals = int64_t(removal_offsets.size()) - 1;
    require(removals >= 0 && int64_t(task_offsets.size()) == removals + 1, "removal offsets");
    const int64_t tasks = task_offsets.data()[removals];
    require(tasks == int64_t(task_tiles.size()), "task tiles");
    require(int64_t(rgb.size()) == 3 * cs::kTilePixels * tasks &&
                int64_t(alpha.size()) == cs::kTilePixels * tasks &&
                int64_t(depth.size()) == cs::kTilePixels * tasks, "patch sizes");
    require(int64_t(rects.size()) == 4 * v.num, "rects size");
    nb::gil_scoped_release release;
    cs::composite_patches(v, reinterpret_cast<const cs::Rect*>(rects.data()), keep_of(keep, v.num),
                          removal_offsets.data(), removal_ids.data(), removals, task_offsets.data(),
                          task_tiles.data(), background.data(),
                          with_base ? base_rgb.data() : nullptr,
                          with_base ? base_alpha.data() : nullptr,
                          with_base ? base_depth.data() : nullptr, rgb.data(), alpha.data(),
                          depth.data(), threads(num_threads));
}

void live_entries(In<float> splats, In<int64_t> offsets, In<int32_t> lists, In<uint8_t> floor,
                  int width, int height, Out<uint8_t> live, int num_threads) {
    const cs::ViewData v = view_of(splats, offsets, lists, width, height);
    require(int64_t(floor.size()) == v.num, "floor size");
    require(int64_t(live.size()) == int64_t(lists.size()), "live size");
    nb::gil_scoped_release release;
    cs::live_entries(v, floor.data(), live.data(), threads(num_threads));
}

nb::tuple contributions(In<float> splats, In<int64_t> offsets, In<int32_t> lists,
                        In<uint8_t> keep, In<uint8_t> mask, int width, int height,
                        int num_threads) {
    const cs::ViewData v = view_of(splats, offsets, lists, width, height);
    require(int64_t(mask.size()) == int64_t(width) * height, "mask size");
    cs::ContribResult r;
    {
        nb::gil_scoped_release release;
        r = cs::contributions(v, keep_of(keep, v.num), mask.data(), threads(num_threads));
    }
    const size_t m = size_t(r.num);
    return nb::make_tuple(owned(r.pixel, {m}), owned(r.id, {m}), owned(r.weight, {m}));
}

// The values of `index` (non-negative int32) in ascending order and the position of each in
// `index` (stable): a view's visible Gaussians by Gaussian index, with their visible ids.
nb::tuple sort_index(In<int32_t> index, int num_threads) {
    const int64_t v = int64_t(index.size());
    const size_t bytes = size_t(std::max<int64_t>(v, 1)) * sizeof(uint32_t);
    uint32_t* keys = static_cast<uint32_t*>(std::malloc(bytes));
    uint32_t* values = static_cast<uint32_t*>(std::malloc(bytes));
    uint32_t* tmp = static_cast<uint32_t*>(std::malloc(2 * bytes));
    if (!keys || !values || !tmp) {
        std::free(keys), std::free(values), std::free(tmp);
        throw std::bad_alloc();
    }
    const int32_t* idx = index.data();
    bool bad = false;
    {
        nb::gil_scoped_release release;
        for (int64_t i = 0; i < v; ++i) {
            bad |= idx[i] < 0;
            keys[i] = uint32_t(idx[i]);
            values[i] = uint32_t(i);
        }
        if (!bad) cs::radix_sort_pairs(keys, values, v, tmp, tmp + std::max<int64_t>(v, 1),
                                       threads(num_threads));
    }
    std::free(tmp);
    if (bad) {
        std::free(keys), std::free(values);
        require(false, "negative index");
    }
    return nb::make_tuple(owned(reinterpret_cast<int32_t*>(keys), {size_t(v)}),
                          owned(reinterpret_cast<int32_t*>(values), {size_t(v)}));
}

// out[i] = mask[index[i]]: a (N,) mask over the visible Gaussians of a view, without widening
// the int32 indices first.
nb::ndarray<nb::numpy, uint8_t> take_mask(In<uint8_t> mask, In<int32_t> index, int num_threads) {
    const int64_t n = int64_t(mask.size()), v = int64_t(index.size());
    uint8_t* out = static_cast<uint8_t*>(std::malloc(size_t(std::max<int64_t>(v, 1))));
    if (!out) throw std::bad_alloc();
    const uint8_t* m = mask.data();
    const int32_t* idx = index.data();
    int64_t bad = 0;
    {
        nb::gil_scoped_release release;
        // A gather of scattered bytes: about 0.2 ms for 300,000 on one core and 2 ms for 1.5
        // million (the mask then outgrows the cache), so threads pay from a million on (on a
        // busy machine a parallel region can wait a whole scheduler slice, 10 ms and more,
        // for a thread that is not running).
        const int threads = v < (int64_t(1) << 20) ? 1 : std::max(1, num_threads);
#pragma omp parallel for schedule(static) reduction(+ : bad) num_threads(threads)
        for (int64_t i = 0; i < v; ++i) {
            const int32_t k = idx[i];
            const bool ok = k >= 0 && int64_t(k) < n;
            out[i] = ok ? m[k] : 0;
            bad += !ok;
        }
    }
    if (bad) {
        std::free(out);
        require(false, "index out of range");
    }
    return owned(out, {size_t(v)});
}

// (n,) uint8: 1 for the Gaussians (index[i]) whose projected centre (splats[i, 0:2]) lies in
// the width x height image.
nb::ndarray<nb::numpy, uint8_t> centres_inside(In<float> splats, In<int32_t> index, int64_t n,
                                               int width, int height) {
    require(splats.ndim() == 2 && splats.shape(1) == 12 &&
                int64_t(splats.shape(0)) == int64_t(index.size()) && n >= 0, "splats / index");
    uint8_t* out = static_cast<uint8_t*>(std::calloc(size_t(std::max<int64_t>(n, 1)), 1));
    if (!out) throw std::bad_alloc();
    const float* s = splats.data();
    const int32_t* idx = index.data();
    const float w = float(width), h = float(height);
    int64_t bad = 0;
    {
        nb::gil_scoped_release release;
        for (int64_t i = 0; i < int64_t(index.size()); ++i) {
            const float u = s[12 * i], v = s[12 * i + 1];
            const int32_t k = idx[i];
            if (k < 0 || int64_t(k) >= n) {
                ++bad;
                continue;
            }
            if (u >= 0.0f && u < w && v >= 0.0f && v < h) out[k] = 1;
        }
    }
    if (bad) {
        std::free(out);
        require(false, "index out of range");
    }
    return owned(out, {size_t(n)});
}

}  // namespace

NB_MODULE(_core, m) {
    m.doc() = "clearsplat native CPU Gaussian rasterizer (kernels; use clearsplat.render)";
    m.def("max_threads", []() { return omp_get_max_threads(); },
          "Number of threads the native core uses by default.");
    m.def("project", &project, "means"_a, "scales"_a, "quats"_a, "opacities"_a, "sh"_a, "keep"_a,
          "view"_a, "intrinsics"_a, "campos"_a, "width"_a, "height"_a, "near"_a, "eps2d"_a,
          "antialiased"_a, "radius_clip"_a, "num_threads"_a,
          "Project, cull and depth-sort: (splats (V, 12) f32, rects (V, 4) u16, index (V,) i32).");
    m.def("bin_tiles", &bin_tiles, "rects"_a, "grid_w"_a, "grid_h"_a, "num_threads"_a,
          "Tile lists: (offsets (T + 1,) i64, lists (P,) i32).");
    m.def("restrict_view", &restrict_view, "splats"_a, "rects"_a, "index"_a, "offsets"_a,
          "lists"_a, "keep"_a,
          "Restrict a view to the kept Gaussians, renumbered, in place: (records, pairs).");
    m.def("tiles_touched", &tiles_touched, "rects"_a, "group_offsets"_a, "ids"_a, "grid_w"_a,
          "grid_h"_a, "num_threads"_a, "Sorted unique tiles per id group: (offsets, tiles).");
    m.def("composite", &composite, "splats"_a, "offsets"_a, "lists"_a, "keep"_a, "tiles"_a,
          "width"_a, "height"_a, "background"_a, "rgb"_a, "alpha"_a, "depth"_a, "num_threads"_a,
          "Composite the given tiles into full-size outputs (in place).");
    m.def("composite_pair", &composite_pair, "splats"_a, "offsets"_a, "lists"_a, "keep_a"_a,
          "keep"_a, "tiles"_a, "width"_a, "height"_a, "background"_a, "rgb_a"_a, "alpha_a"_a, "depth_a"_a, "rgb_b"_a,
          "alpha_b"_a, "depth_b"_a, "num_threads"_a,
          "Composite the tiles twice in one pass: the Gaussians kept by keep_a (a), by keep (b).");
    m.def("composite_layers", &composite_layers, "splats"_a, "offsets"_a, "lists"_a, "layer"_a,
          "num_layers"_a, "tiles"_a, "width"_a, "height"_a, "background"_a, "rgb"_a, "alpha"_a,
          "depth"_a, "num_threads"_a,
          "Composite every layer (the Gaussians with layer == k) into outputs[k] in `tiles`, in "
          "one pass.");
    m.def("composite_patches", &composite_patches, "splats"_a, "offsets"_a, "lists"_a, "rects"_a,
          "keep"_a, "removal_offsets"_a, "removal_ids"_a, "task_offsets"_a, "task_tiles"_a,
          "width"_a, "height"_a, "background"_a, "base_rgb"_a, "base_alpha"_a, "base_depth"_a,
          "rgb"_a, "alpha"_a, "depth"_a, "num_threads"_a,
          "Re-composite (removal, tile) tasks into (tasks, 16, 16, ...) patches (in place); "
          "with a base render (empty arrays: none) only the pixels the removal can change.");
    m.def("sort_index", &sort_index, "index"_a, "num_threads"_a = 1,
          "(sorted values, their positions) of non-negative int32 indices, stable.");
    m.def("take_mask", &take_mask, "mask"_a, "index"_a, "num_threads"_a = 1,
          "mask[index] as uint8 (a keep mask over a view's visible Gaussians).");
    m.def("centres_inside", &centres_inside, "splats"_a, "index"_a, "n"_a, "width"_a, "height"_a,
          "(n,) uint8: the Gaussians whose projected centre lies inside the image.");
    m.def("live_entries", &live_entries, "splats"_a, "offsets"_a, "lists"_a, "floor"_a,
          "width"_a, "height"_a, "live"_a, "num_threads"_a,
          "Mark (in place) the tile-list entries a render of any superset of floor can use.");
    m.def("rows_per_step", &cs::rows_per_step,
          "Rows of pixels the compositing takes per step (2 with AVX-512, else 1).");
    m.def("set_rows_per_step", &cs::set_rows_per_step, "rows"_a,
          "Choose the compositing's rows per step (1 or 2; 0: by the machine). The same bits.");
    m.def("contributions", &contributions, "splats"_a, "offsets"_a, "lists"_a, "keep"_a,
          "mask"_a, "width"_a, "height"_a, "num_threads"_a,
          "Every added (pixel, id, weight) at the masked pixels.");
}
