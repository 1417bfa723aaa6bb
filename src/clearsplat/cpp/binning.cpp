// Depth sort and tile binning. Visible Gaussians are sorted once by camera z (stable, so ties
// keep the Gaussian order); binning then walks them in that order, which leaves every tile's
// list front to back without a per-tile sort.
#include <omp.h>

#include <algorithm>
#include <cstdlib>
#include <cstring>
#include <vector>

#include "memory.h"
#include "raster.h"

namespace cs {

void radix_sort_pairs(uint32_t* keys, uint32_t* values, int64_t n, uint32_t* tmp_keys,
                      uint32_t* tmp_values, int num_threads) {
    // LSD radix sort, 11-bit digits. Each pass splits the input into contiguous parts, one per
    // thread, and scatters part by part: stable, so the result never depends on the threads.
    constexpr int kBits = 11, kBuckets = 1 << kBits;
    const int parts = int(std::max<int64_t>(1, std::min<int64_t>(num_threads, n / 65536 + 1)));
    uint32_t *src_k = keys, *src_v = values, *dst_k = tmp_keys, *dst_v = tmp_values;
    std::vector<int64_t> hist(size_t(parts) * kBuckets);
    auto begin = [&](int t) { return n * t / parts; };
    for (int shift = 0; shift < 32; shift += kBits) {
#pragma omp parallel for schedule(static, 1) num_threads(parts)
        for (int t = 0; t < parts; ++t) {
            int64_t* h = hist.data() + size_t(t) * kBuckets;
            std::fill(h, h + kBuckets, 0);
            // Bounds in locals: a call in the loop's condition would divide on every pass.
            const int64_t lo = begin(t), hi = begin(t + 1);
            for (int64_t i = lo; i < hi; ++i) ++h[(src_k[i] >> shift) & (kBuckets - 1)];
        }
        // A digit shared by every key leaves the order unchanged: skip the pass.
        int64_t first = 0;
        for (int t = 0; t < parts; ++t) first += hist[size_t(t) * kBuckets + ((src_k[0] >> shift) & (kBuckets - 1))];
        if (n == 0 || first == n) continue;
        int64_t run = 0;
        for (int b = 0; b < kBuckets; ++b)
            for (int t = 0; t < parts; ++t) {
                int64_t& h = hist[size_t(t) * kBuckets + b];
                const int64_t c = h;
                h = run;
                run += c;
            }
#pragma omp parallel for schedule(static, 1) num_threads(parts)
        for (int t = 0; t < parts; ++t) {
            int64_t* h = hist.data() + size_t(t) * kBuckets;
            const int64_t lo = begin(t), hi = begin(t + 1);
            for (int64_t i = lo; i < hi; ++i) {
                const int64_t at = h[(src_k[i] >> shift) & (kBuckets - 1)]++;
                dst_k[at] = src_k[i];
                dst_v[at] = src_v[i];
            }
        }
        std::swap(src_k, dst_k);
        std::swap(src_v, dst_v);
    }
    if (src_k != keys) {
        std::memcpy(keys, src_k, n * sizeof(uint32_t));
        std::memcpy(values, src_v, n * sizeof(uint32_t));
    }
}

BinResult bin_tiles(const Rect* rects, int64_t num, int grid_w, int grid_h, int num_threads) {
    const int64_t num_tiles = int64_t(grid_w) * grid_h;
    const int parts = std::max(1, num_threads);
    // counts[part][tile]; parts are contiguous id ranges, filled in part order, so each tile's
    // list comes out ascending whatever the thread count.
    std::vector<int64_t> counts(size_t(parts) * num_tiles, 0);
    auto part_begin = [&](int k) { return num * k / parts; };
#pragma omp parallel for schedule(static, 1) num_threads(num_threads)
    for (int k = 0; k < parts; ++k) {
        int64_t* c = counts.data() + size_t(k) * num_tiles;
        const int64_t lo = part_begin(k), hi = part_begin(k + 1);  // not divided per pass
        for (int64_t i = lo; i < hi; ++i) {
            const Rect& r = rects[i];
            for (int y = r.y0; y <= r.y1; ++y)
                for (int x = r.x0; x <= r.x1; ++x) ++c[int64_t(y) * grid_w + x];
        }
    }
    BinResult out;
    out.offsets = static_cast<int64_t*>(std::malloc((num_tiles + 1) * sizeof(int64_t)));
    int64_t run = 0;
    for (int64_t t = 0; t < num_tiles; ++t) {
        out.offsets[t] = run;
        for (int k = 0; k < parts; ++k) {
            const int64_t c = counts[size_t(k) * num_tiles + t];
            counts[size_t(k) * num_tiles + t] = run;
            run += c;
        }
    }
    out.offsets[num_tiles] = run;
    out.num_pairs = run;
    out.lists = big_alloc_n<int32_t>(run);
#pragma omp parallel for schedule(static, 1) num_threads(num_threads)
    for (int k = 0; k < parts; ++k) {
        int64_t* at = counts.data() + size_t(k) * num_tiles;
        const int64_t lo = part_begin(k), hi = part_begin(k + 1);
        for (int64_t i = lo; i < hi; ++i) {
            const Rect& r = rects[i];
            for (int y = r.y0; y <= r.y1; ++y)
                for (int x = r.x0; x <= r.x1; ++x) out.lists[at[int64_t(y) * grid_w + x]++] = int32_t(i);
        }
    }
    return out;
}

TileSets tiles_touched(const Rect* rects, const int64_t* group_offsets, const int32_t* ids,
                       int64_t num_groups, int grid_w, int grid_h, int num_threads) {
    std::vector<std::vector<int32_t>> sets(num_groups);
#pragma omp parallel num_threads(team_size(num_threads, num_groups))
    {
        std::vector<uint8_t> seen(size_t(grid_w) * grid_h, 0);
#pragma omp for schedule(dynamic, 1)
        for (int64_t g = 0; g < num_groups; ++g) {
            std::vector<int32_t>& s = sets[g];
            for (int64_t j = group_offsets[g]; j < group_offsets[g + 1]; ++j) {
                const Rect& r = rects[ids[j]];
                for (int y = r.y0; y <= r.y1; ++y)
                    for (int x = r.x0; x <= r.x1; ++x) {
                        const int32_t t = y * grid_w + x;
                        if (!seen[t]) seen[t] = 1, s.push_back(t);
                    }
            }
            for (int32_t t : s) seen[t] = 0;
            std::sort(s.begin(), s.end());
        }
    }
    TileSets out;
    out.offsets = static_cast<int64_t*>(std::malloc((num_groups + 1) * sizeof(int64_t)));
    out.offsets[0] = 0;
    for (int64_t g = 0; g < num_groups; ++g) out.offsets[g + 1] = out.offsets[g] + int64_t(sets[g].size());
    out.total = out.offsets[num_groups];
    out.tiles = static_cast<int32_t*>(std::malloc(std::max<int64_t>(out.total, 1) * sizeof(int32_t)));
    for (int64_t g = 0; g < num_groups; ++g)
        std::copy(sets[g].begin(), sets[g].end(), out.tiles + out.offsets[g]);
    return out;
}

bool restrict_view(Splat* splats, Rect* rects, int32_t* index, int64_t num, int64_t* offsets,
                   int32_t* lists, int64_t num_tiles, const uint8_t* keep, int64_t n,
                   int64_t& new_num, int64_t& new_pairs) {
    for (int64_t v = 0; v < num; ++v)
        if (index[v] < 0 || int64_t(index[v]) >= n) return false;
    // One pass each, front to back: every kept item moves to a position at or before its own,
    // so nothing is overwritten before it is read. No new memory but the reused scratch (the
    // first write to fresh pages costs more than these passes).
    int32_t* rank = reinterpret_cast<int32_t*>(scratch(size_t(n + num + 1) * sizeof(int32_t)));
    int32_t* new_id = rank + n;
    int32_t run = 0;
    for (int64_t i = 0; i < n; ++i) {
        rank[i] = run;
        run += keep[i] != 0;
    }
    int64_t at = 0;
    for (int64_t v = 0; v < num; ++v) {
        if (!keep[index[v]]) {
            new_id[v] = -1;
            continue;
        }
        new_id[v] = int32_t(at);
        splats[at] = splats[v];
        rects[at] = rects[v];
        index[at] = rank[index[v]];
        ++at;
    }
    new_num = at;
    at = 0;
    int64_t from = offsets[0];
    for (int64_t t = 0; t < num_tiles; ++t) {
        const int64_t to = offsets[t + 1];
        offsets[t] = at;
        for (int64_t e = from; e < to; ++e) {
            const int32_t id = new_id[lists[e]];
            if (id >= 0) lists[at++] = id;
        }
        from = to;
    }
    offsets[num_tiles] = at;
    new_pairs = at;
    return true;
}

}  // namespace cs
