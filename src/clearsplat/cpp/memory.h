// Large buffers. Fresh pages cost a page fault and a kernel clear each (4 KiB at a time), which
// for a million Gaussians is a good part of a render, so big outputs ask for transparent huge
// pages and the temporaries of one call are reused by the next call on the same thread.
#pragma once

#include <cstddef>
#include <cstdlib>
#include <memory>

#if defined(__linux__)
#include <sys/mman.h>
#endif

namespace cs {

// malloc-compatible (release with free()); huge-page backed when large.
inline void* big_alloc(size_t bytes) {
    constexpr size_t kHuge = size_t(2) << 20;
    if (bytes < kHuge) return std::malloc(bytes > 0 ? bytes : 1);
    const size_t rounded = (bytes + kHuge - 1) / kHuge * kHuge;
    void* p = std::aligned_alloc(kHuge, rounded);
#if defined(__linux__) && defined(MADV_HUGEPAGE)
    if (p) madvise(p, rounded, MADV_HUGEPAGE);
#endif
    return p;
}

template <class T>
T* big_alloc_n(int64_t n) {
    return static_cast<T*>(big_alloc(size_t(n > 0 ? n : 1) * sizeof(T)));
}

// Per-thread scratch memory, kept between calls (grows to the largest request seen).
inline char* scratch(size_t bytes) {
    struct Free {
        void operator()(char* p) const { std::free(p); }
    };
    thread_local std::unique_ptr<char, Free> buffer;
    thread_local size_t capacity = 0;
    if (bytes > capacity) {
        buffer.reset(static_cast<char*>(big_alloc(bytes)));
        capacity = buffer ? bytes : 0;
        if (!buffer) throw std::bad_alloc();
    }
    return buffer.get();
}

}  // namespace cs
