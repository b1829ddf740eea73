// Tile-based CPU compositing of projected Gaussians with an analytic backward (3DGS semantics).
//
// Inputs are the screen-space quantities the torch projection produces; this file only bins,
// composites and back-propagates. Every pixel is owned by one tile and every tile by one task,
// and per-Gaussian gradients are summed over per-(tile, Gaussian) partials in a fixed order, so
// the bytes of every output depend neither on thread scheduling nor on the thread count.
//
// A second stream, optional: the Gaussians outside a subset (flag = last feature, 0) composited on
// their own, with their own transmittance and early stop, in the same walk over each tile's list.
// It gives the surface's depth and alpha as a separate render of the surface would, while the
// first stream composites surface and smoke together; binning, the record reads and each lane
// group's alpha (one exponent per pixel) are shared. A pixel stops walking when both its streams
// have stopped.
//
// Pixels are visited in lane groups of 8 along a tile row (see `Lanes`). Each lane rounds exactly
// as the scalar formula it vectorises, so the images are the bytes a pixel-by-pixel walk gives;
// per-Gaussian gradient sums are taken lane-wise, then over the lanes in a fixed order.

#include <torch/extension.h>

#include "projection.h"
#include "sh_colors.h"

#include <ATen/Parallel.h>
#include <omp.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <type_traits>
#include <utility>
#include <vector>

// Lane vectors are passed between inline functions of this file only, so the ABI note GCC gives for
// wide vector arguments does not apply.
#pragma GCC diagnostic ignored "-Wpsabi"

namespace {

constexpr int kTile = 16;
constexpr int kTilePixels = kTile * kTile;
constexpr double kAlphaMax = 0.99;
constexpr double kAlphaMin = 1.0 / 255.0;
constexpr double kTransmittanceMin = 1e-4;

// Inclusive pixel rectangle of one (camera, Gaussian); empty when x1 < x0 or y1 < y0.
struct Rect {
  int32_t x0, x1, y0, y1;
};

// Tile lists of all cameras plus the inverse map the backward reduction walks. The Gaussians that
// touch a pixel are packed front to back, one record each, so a tile walking its list in depth
// order reads memory in increasing address order.
struct Bins {
  torch::Tensor records;        // [S, 6 + F] mx, my, conic a, b, c, opacity, features (packed order)
  torch::Tensor rects;          // [S, 4] int32 pixel rectangles (packed order)
  torch::Tensor source;         // [S] int64 camera * N + Gaussian of each packed record
  torch::Tensor tile_offsets;   // [C*T + 1] int64 start of each tile's list in `entries`
  torch::Tensor entries;        // [E] int32 packed record index, front to back within a tile
  torch::Tensor record_offsets; // [S + 1] int64 start of each record's gradient slots (one per tile)
  torch::Tensor slot_of;        // [E] int64 gradient slot of each tile entry (record-major order)
};

int num_threads() { return std::max(1, at::get_num_threads()); }

// Pixels are processed in lane groups: 8 horizontally adjacent pixels of one tile row. The code is
// written with GCC vector extensions of 32 bytes, the AVX2 register width (8 floats, 4 doubles),
// so it vectorises whatever the auto-vectoriser decides; without AVX2 the compiler splits each
// vector into SSE halves. Comparisons give integer masks (-1 true, 0 false).
constexpr int kLanes = 8;
constexpr int kHalf = 4;  // doubles per register: a group's double work runs in two halves

typedef float F8 __attribute__((vector_size(32)));
typedef int32_t I8 __attribute__((vector_size(32)));
typedef double D4 __attribute__((vector_size(32)));
typedef int64_t L4 __attribute__((vector_size(32)));
typedef float F4 __attribute__((vector_size(16)));
typedef int32_t I4 __attribute__((vector_size(16)));

template <typename V>
inline V load_v(const void* p) {
  V v;
  std::memcpy(&v, p, sizeof(V));
  return v;
}

template <typename V>
inline void store_v(void* p, const V& v) {
  std::memcpy(p, &v, sizeof(V));
}

// One bit per lane of a mask.
inline unsigned lane_bits(const L4& m) {
#if defined(__AVX2__)
  return unsigned(__builtin_ia32_movmskpd256((D4)m));
#else
  unsigned bits = 0;
  for (int l = 0; l < 4; ++l) bits |= (m[l] != 0 ? 1u : 0u) << l;
  return bits;
#endif
}

inline unsigned lane_bits(const I8& m) {
#if defined(__AVX2__)
  return unsigned(__builtin_ia32_movmskps256((F8)m));
#else
  unsigned bits = 0;
  for (int l = 0; l < 8; ++l) bits |= (m[l] != 0 ? 1u : 0u) << l;
  return bits;
#endif
}

inline L4 widen(const I4& m) { return __builtin_convertvector(m, L4); }

// exp(-sigma) for sigma >= 0, lane-wise. float: a branch-free polynomial (Cephes-style range
// reduction, relative error ~2e-7, like expf); x*log2(e) is rounded to an integer by adding and
// subtracting 1.5*2^23, which is round-to-nearest-even exactly as nearbyint for |x| < 2^22.
// double: std::exp per lane. Forward and backward call the same code with the same rounding (no
// FMA contraction), so they agree on every skipped pair.
inline F8 exp_neg(const F8& sigma) {
  const F8 neg = -sigma;
  const F8 x = neg < -87.0f ? F8{} - 87.0f : neg;
  const F8 k = (x * 1.44269504088896341f + 12582912.0f) - 12582912.0f;
  const F8 r = (x - k * 0.693359375f) + k * 2.12194440e-4f;
  F8 p = F8{} + 1.9875691500e-4f;
  p = p * r + 1.3981999507e-3f;
  p = p * r + 8.3334519073e-3f;
  p = p * r + 4.1665795894e-2f;
  p = p * r + 1.6666665459e-1f;
  p = p * r + 5.0000001201e-1f;
  const F8 poly = (p * r) * r + r + 1.0f;
  const I8 bits = (I8)poly + (__builtin_convertvector(k, I8) << 23);  // vector casts reinterpret the bits
  return (F8)bits;
}

inline D4 exp_neg(const D4& sigma) {
  D4 out;
  for (int l = 0; l < kHalf; ++l) out[l] = std::exp(-sigma[l]);
  return out;
}

// The native vector of a kernel dtype: 8 float lanes (one chunk per group) or 4 double lanes (two).
template <typename scalar_t>
struct Native;
template <>
struct Native<float> {
  using V = F8;
  using M = I8;
};
template <>
struct Native<double> {
  using V = D4;
  using M = L4;
};

// Half `h` of a group's lanes as doubles, from 8 stored scalars.
inline D4 half_as_double(const float* v, int h) { return __builtin_convertvector(load_v<F4>(v + kHalf * h), D4); }
inline D4 half_as_double(const double* v, int h) { return load_v<D4>(v + kHalf * h); }

// Pixels where alpha can reach 1/255 lie inside the ellipse sigma <= log(255 * opacity). What a
// tile walk needs of one packed record, computed once per record (a log and two square roots):
// the centre, conic and opacity, and the pixel rectangle with its rows and columns narrowed,
// conservatively (a margin in sigma and one pixel on each side), to the ellipse's bounding box. The exact per-pixel
// test still decides; the narrowing only skips pixels that test would reject. A record whose opacity
// can never reach 1/255 gets an empty rectangle.
template <typename scalar_t>
struct Footprint {
  scalar_t mx, my, qa, qb, qc, opac;
  // No pixel with sigma above this reaches alpha 1/255 (the ellipse's limit with its margin, which
  // dwarfs the exponent's rounding); infinite where the conic gives no usable bound.
  scalar_t sigma_cut = std::numeric_limits<scalar_t>::infinity();
  int32_t x0, x1, y0, y1;  // inclusive; empty when x1 < x0 or y1 < y0

  Footprint() = default;

  Footprint(const scalar_t* rec, const Rect& r)
      : mx(rec[0]), my(rec[1]), qa(rec[2]), qb(rec[3]), qc(rec[4]), opac(rec[5]), x0(r.x0), x1(r.x1), y0(r.y0),
        y1(r.y1) {
    const double half_a = 0.5 * double(qa), b = double(qb), half_c = 0.5 * double(qc);
    const double s_max = std::log(255.0 * double(opac));
    const double limit = s_max + 1e-3 + 1e-4 * std::abs(s_max);
    const bool shaped = half_a > 0.0 && std::isfinite(half_a) && std::isfinite(b) && std::isfinite(half_c) &&
                        std::isfinite(limit);
    if (shaped && limit < 0.0) {
      y1 = y0 - 1;
      return;
    }
    if (shaped) sigma_cut = scalar_t(limit);
    const double det = 4.0 * half_a * half_c - b * b;
    if (!shaped || !(det > 0.0)) return;  // no usable bound: every row of the rectangle is tested
    const double reach_y = std::sqrt(4.0 * limit * half_a / det), reach_x = std::sqrt(4.0 * limit * half_c / det);
    y0 = std::max(y0, int32_t(std::ceil(std::max(-1e9, double(my) - reach_y - 0.5)) - 1.0));
    y1 = std::min(y1, int32_t(std::floor(std::min(1e9, double(my) + reach_y - 0.5)) + 1.0));
    x0 = std::max(x0, int32_t(std::ceil(std::max(-1e9, double(mx) - reach_x - 0.5)) - 1.0));
    x1 = std::min(x1, int32_t(std::floor(std::min(1e9, double(mx) + reach_x - 0.5)) + 1.0));
  }
};

// The Gaussians of one camera with a non-empty rectangle, front to back: ascending float64 view z,
// ties by index, as a stable argsort of the keys gives. Why not torch.argsort: its stable merge sort
// of all N keys took ~1 ms per call, several % of a demo run. This is an LSD radix sort (8 passes
// of 8 bits, stable, input in index order) of each key's order-preserving 64-bit image; -0.0 is
// first folded into +0.0, which compares equal to it.
std::vector<int32_t> depth_order(const double* key, const Rect* rect, int64_t n) {
  std::vector<uint64_t> bits, bits_tmp;
  std::vector<int32_t> idx, idx_tmp;
  for (int64_t i = 0; i < n; ++i) {
    if (rect[i].x1 < rect[i].x0 || rect[i].y1 < rect[i].y0) continue;
    const double k = key[i] + 0.0;
    uint64_t u;
    std::memcpy(&u, &k, sizeof(u));
    bits.push_back(u >> 63 ? ~u : u | (uint64_t(1) << 63));
    idx.push_back(int32_t(i));
  }
  const size_t m = idx.size();
  if (m == 0) return idx;
  bits_tmp.resize(m);
  idx_tmp.resize(m);
  for (int shift = 0; shift < 64; shift += 8) {
    size_t count[257] = {0};
    for (size_t i = 0; i < m; ++i) ++count[((bits[i] >> shift) & 0xff) + 1];
    if (count[((bits[0] >> shift) & 0xff) + 1] == m) continue;  // every key has this digit: identity pass
    for (int d = 0; d < 256; ++d) count[d + 1] += count[d];
    for (size_t i = 0; i < m; ++i) {
      const size_t pos = count[(bits[i] >> shift) & 0xff]++;
      bits_tmp[pos] = bits[i];
      idx_tmp[pos] = idx[i];
    }
    bits.swap(bits_tmp);
    idx.swap(idx_tmp);
  }
  return idx;
}

// A tile walks its list in depth order, which jumps through the records; fetching the record a few
// entries ahead hides the memory latency that otherwise dominates small Gaussians.
constexpr int64_t kPrefetch = 4;

template <typename scalar_t>
inline void prefetch_record(const Footprint<scalar_t>* footprints, const scalar_t* rec, int64_t stride, int64_t s) {
  __builtin_prefetch(footprints + s);
  __builtin_prefetch(rec + s * stride + 6);
}

template <typename scalar_t>
std::vector<Footprint<scalar_t>> record_footprints(const scalar_t* rec, const Rect* rects, int64_t packed,
                                                   int64_t stride) {
  std::vector<Footprint<scalar_t>> out(packed);
  at::parallel_for(0, packed, 2048, [&](int64_t lo, int64_t hi) {
    for (int64_t s = lo; s < hi; ++s) out[s] = Footprint<scalar_t>(rec + s * stride, rects[s]);
  });
  return out;
}

template <typename scalar_t>
Bins bin_gaussians(const torch::Tensor& means2d, const torch::Tensor& conics, const torch::Tensor& opacities,
                   const torch::Tensor& feats, const torch::Tensor& radii, const torch::Tensor& sort_keys,
                   const torch::Tensor& visible, int64_t width, int64_t height) {
  const int64_t cams = means2d.size(0), n = means2d.size(1), nf = feats.size(2);
  const int64_t tiles_x = (width + kTile - 1) / kTile, tiles_y = (height + kTile - 1) / kTile;
  const int64_t tiles = tiles_x * tiles_y;
  auto i32 = torch::TensorOptions().dtype(torch::kInt32);
  auto i64 = torch::TensorOptions().dtype(torch::kInt64);
  const scalar_t* m2 = means2d.data_ptr<scalar_t>();
  const scalar_t* rad = radii.data_ptr<scalar_t>();
  const bool* vis = visible.data_ptr<bool>();
  std::vector<Rect> rect_of(cams * n);
  // Same rounding as the torch backend: ceil/floor of (centre -+ radius - 0.5) in the input dtype.
  at::parallel_for(0, cams * n, 4096, [&](int64_t lo, int64_t hi) {
    for (int64_t i = lo; i < hi; ++i) {
      Rect r{0, -1, 0, -1};
      if (vis[i]) {
        const scalar_t mx = m2[2 * i], my = m2[2 * i + 1], rr = rad[i];
        const scalar_t half = scalar_t(0.5);
        const scalar_t fx0 = std::clamp(std::ceil(mx - rr - half), scalar_t(0), scalar_t(width));
        const scalar_t fx1 = std::clamp(std::floor(mx + rr - half), scalar_t(-1), scalar_t(width - 1));
        const scalar_t fy0 = std::clamp(std::ceil(my - rr - half), scalar_t(0), scalar_t(height));
        const scalar_t fy1 = std::clamp(std::floor(my + rr - half), scalar_t(-1), scalar_t(height - 1));
        r = Rect{int32_t(fx0), int32_t(fx1), int32_t(fy0), int32_t(fy1)};
      }
      rect_of[i] = r;
    }
  });

  // Pack the Gaussians that touch a pixel, per camera front to back, and count tile entries.
  const double* keys = sort_keys.data_ptr<double>();
  std::vector<int64_t> packed_src;
  std::vector<int64_t> cam_start(cams + 1, 0), tile_count(cams * tiles, 0);
  std::vector<int64_t> rec_off(1, 0);
  for (int64_t c = 0; c < cams; ++c) {
    for (const int32_t g : depth_order(keys + c * n, rect_of.data() + c * n, n)) {
      const int64_t cg = c * n + g;
      const Rect& r = rect_of[cg];
      packed_src.push_back(cg);
      const int tx0 = r.x0 / kTile, tx1 = r.x1 / kTile, ty0 = r.y0 / kTile, ty1 = r.y1 / kTile;
      rec_off.push_back(rec_off.back() + int64_t(tx1 - tx0 + 1) * (ty1 - ty0 + 1));
      for (int ty = ty0; ty <= ty1; ++ty)
        for (int tx = tx0; tx <= tx1; ++tx) ++tile_count[c * tiles + ty * tiles_x + tx];
    }
    cam_start[c + 1] = int64_t(packed_src.size());
  }
  const int64_t packed = int64_t(packed_src.size()), total = rec_off.back();
  TORCH_CHECK(packed < (int64_t(1) << 31), "tile rasterizer: too many Gaussians for int32 tile lists");
  Bins b;
  b.records = torch::empty({packed, 6 + nf}, means2d.options());
  b.rects = torch::empty({packed, 4}, i32);
  b.source = torch::from_blob(packed_src.data(), {packed}, i64).clone();
  b.record_offsets = torch::from_blob(rec_off.data(), {packed + 1}, i64).clone();
  const scalar_t* cn = conics.data_ptr<scalar_t>();
  const scalar_t* op = opacities.data_ptr<scalar_t>();
  const scalar_t* ft = feats.data_ptr<scalar_t>();
  scalar_t* rec = b.records.data_ptr<scalar_t>();
  Rect* rects = reinterpret_cast<Rect*>(b.rects.data_ptr<int32_t>());
  at::parallel_for(0, packed, 2048, [&](int64_t lo, int64_t hi) {
    for (int64_t s = lo; s < hi; ++s) {
      const int64_t cg = packed_src[s];
      scalar_t* r = rec + s * (6 + nf);
      r[0] = m2[2 * cg];
      r[1] = m2[2 * cg + 1];
      for (int k = 0; k < 3; ++k) r[2 + k] = cn[3 * cg + k];
      r[5] = op[cg % n];
      for (int64_t k = 0; k < nf; ++k) r[6 + k] = ft[cg * nf + k];
      rects[s] = rect_of[cg];
    }
  });

  b.tile_offsets = torch::empty({cams * tiles + 1}, i64);
  int64_t* toff = b.tile_offsets.data_ptr<int64_t>();
  toff[0] = 0;
  for (int64_t t = 0; t < cams * tiles; ++t) toff[t + 1] = toff[t] + tile_count[t];
  b.entries = torch::empty({total}, i32);
  b.slot_of = torch::empty({total}, i64);
  int32_t* ent = b.entries.data_ptr<int32_t>();
  int64_t* sof = b.slot_of.data_ptr<int64_t>();
  // Each task owns one tile row of one camera and appends in depth order: deterministic.
#pragma omp parallel for schedule(dynamic, 1) num_threads(num_threads())
  for (int64_t row = 0; row < cams * tiles_y; ++row) {
    const int64_t c = row / tiles_y;
    const int ty = int(row % tiles_y);
    std::vector<int64_t> cursor(tiles_x);
    for (int64_t tx = 0; tx < tiles_x; ++tx) cursor[tx] = toff[c * tiles + ty * tiles_x + tx];
    for (int64_t s = cam_start[c]; s < cam_start[c + 1]; ++s) {
      const Rect& r = rects[s];
      const int ty0 = r.y0 / kTile;
      if (ty < ty0 || ty > r.y1 / kTile) continue;
      const int tx0 = r.x0 / kTile, tx1 = r.x1 / kTile;
      const int64_t slot = rec_off[s] + int64_t(ty - ty0) * (tx1 - tx0 + 1);
      for (int tx = tx0; tx <= tx1; ++tx) {
        const int64_t pos = cursor[tx]++;
        ent[pos] = int32_t(s);
        sof[pos] = slot + (tx - tx0);
      }
    }
  }
  return b;
}

// Pixel range of tile `t`.
struct TileBox {
  int x0, x1, y0, y1;  // inclusive
};

inline TileBox tile_box(int64_t t, int64_t tiles_x, int64_t width, int64_t height) {
  const int tx = int(t % tiles_x), ty = int(t / tiles_x);
  return TileBox{tx * kTile, int(std::min<int64_t>(width, (tx + 1) * kTile)) - 1, ty * kTile,
                 int(std::min<int64_t>(height, (ty + 1) * kTile)) - 1};
}

// Features per record: a compile-time count (so per-pixel loops vectorise) or, for NF == 0, any.
template <int NF>
inline int64_t feature_count(int64_t nf) {
  return NF > 0 ? NF : nf;
}

// One tile entry clipped to the tile, in tile-relative pixels, with the rows it can touch.
template <typename scalar_t>
struct EntryBox {
  int lx0, lx1, y0, y1;  // lx: columns relative to the tile's first column; y: absolute rows
  bool empty() const { return lx1 < lx0 || y1 < y0; }

  EntryBox(const Footprint<scalar_t>& fp, const TileBox& tb)
      : lx0(std::max(fp.x0, tb.x0) - tb.x0), lx1(std::min(fp.x1, tb.x1) - tb.x0), y0(std::max(fp.y0, tb.y0)),
        y1(std::min(fp.y1, tb.y1)) {}
};

// Alpha of one record over one lane group, computed once and shared by both streams and, with the
// same rounding, by the forward and the backward pass (so both agree on every skipped pair).
// `hit`: inside the record's rectangle (lanes lo..hi), sigma >= 0 and alpha >= 1/255.
template <typename scalar_t>
struct Lanes {
  alignas(32) scalar_t alpha[kLanes];
  alignas(32) scalar_t falloff[kLanes];
  alignas(32) scalar_t dx[kLanes];
  alignas(32) int32_t hit[kLanes];

  // False when no lane is hit (the group can be skipped).
  bool evaluate(const Footprint<scalar_t>& fp, scalar_t dy, scalar_t row_term, int x_first, int lo, int hi) {
    using V = typename Native<scalar_t>::V;
    using M = typename Native<scalar_t>::M;
    constexpr int width = sizeof(V) / sizeof(scalar_t);
    unsigned any = 0;
    for (int c = 0; c < kLanes; c += width) {
      V index;
      for (int l = 0; l < width; ++l) index[l] = scalar_t(c + l);
      const V x = (index + scalar_t(x_first)) + scalar_t(0.5);
      const V d = fp.mx - x;
      const V sigma = scalar_t(0.5) * fp.qa * d * d + row_term + fp.qb * d * dy;
      if (!lane_bits(sigma <= fp.sigma_cut)) {  // no lane inside the ellipse: no exponent needed
        if constexpr (std::is_same_v<M, I8>) {
          store_v(hit + c, I8{});
        } else {
          store_v(hit + c, I4{});
        }
        continue;
      }
      const V f = exp_neg(sigma);
      const V a0 = fp.opac * f;
      const V a = scalar_t(kAlphaMax) < a0 ? V{} + scalar_t(kAlphaMax) : a0;
      const M h = (index >= scalar_t(lo)) & (index <= scalar_t(hi)) & (sigma >= scalar_t(0)) &
                  (a >= scalar_t(kAlphaMin));
      store_v(dx + c, d);
      store_v(falloff + c, f);
      store_v(alpha + c, a);
      if constexpr (std::is_same_v<M, I8>) {
        store_v(hit + c, h);
      } else {
        store_v(hit + c, __builtin_convertvector(h, I4));
      }
      any |= lane_bits(h);
    }
    return any != 0;
  }

  L4 hit_half(int h) const { return widen(load_v<I4>(hit + kHalf * h)); }

  // Lanes of half `h` where opacity * falloff is below the 0.99 clamp (there alpha has a gradient).
  L4 below_clamp(int h, scalar_t opac) const {
    if constexpr (std::is_same_v<scalar_t, float>) {
      return widen(opac * load_v<F4>(falloff + kHalf * h) <= float(kAlphaMax));
    } else {
      return opac * load_v<D4>(falloff + kHalf * h) <= kAlphaMax;
    }
  }
};

// Calls visit(dy, base) for every lane group of the entry's box in which some pixel is still open
// (`open(base)`: a pixel of the group can still take this entry) and reaches 1/255, row by row;
// base is the tile-pixel index of the group's first lane. Testing `open` first skips the exponent
// where the group's pixels have all stopped, which behind dense content is most of them.
template <typename scalar_t, typename Open, typename Visit>
inline void for_each_group(const Footprint<scalar_t>& fp, const EntryBox<scalar_t>& box, const TileBox& tb,
                           Lanes<scalar_t>& lanes, Open&& open, Visit&& visit) {
  const int g0 = box.lx0 / kLanes, g1 = box.lx1 / kLanes;
  for (int y = box.y0; y <= box.y1; ++y) {
    const scalar_t dy = fp.my - (scalar_t(y) + scalar_t(0.5));
    const scalar_t row_term = scalar_t(0.5) * fp.qc * dy * dy;
    const int row_base = (y - tb.y0) * kTile;
    for (int g = g0; g <= g1; ++g) {
      const int first = g * kLanes;
      if (!open(row_base + first)) continue;
      if (!lanes.evaluate(fp, dy, row_term, tb.x0 + first, box.lx0 - first, box.lx1 - first)) continue;
      visit(dy, row_base + first);
    }
  }
}

// Whether any of the 8 transmittances from `t` is positive (a forward pixel not yet stopped).
inline bool any_positive(const double* t) {
  return lane_bits((load_v<D4>(t) > 0.0) | (load_v<D4>(t + kHalf) > 0.0)) != 0;
}

// Whether any of the 8 pixels from `stop` blended entry `e` (a backward pixel that entry reaches).
inline bool any_reached(const int32_t* stop, int32_t e) { return lane_bits(I8{} + e < load_v<I8>(stop)) != 0; }

// Per-tile pixel state of the forward pass, structure of arrays over the 16x16 pixels.
// `trans` holds the transmittance; a pixel that stopped stores its final T negated. A stream that
// is off starts stopped (T = -1), so it never blends and never keeps a pixel open.
struct ForwardTile {
  std::vector<double> trans, acc;
  std::vector<int32_t> stop;
  explicit ForwardTile(int64_t nf) : trans(kTilePixels), acc(kTilePixels * nf), stop(kTilePixels) {}
  void reset(bool on = true) {
    std::fill(trans.begin(), trans.end(), on ? 1.0 : -1.0);
    std::fill(acc.begin(), acc.end(), 0.0);
    std::fill(stop.begin(), stop.end(), 0);
  }
};

// Blend entry `e` into one lane group of a stream: returns (pairs blended, pixels stopped). A pixel
// counts as stopped when this stream ends there and the other stream (`other`, the same pixels of
// its transmittance) has already ended, so each pixel is counted once, by its last stream.
template <typename scalar_t, int NF>
inline std::pair<int, int> blend_lanes(ForwardTile& st, const Lanes<scalar_t>& la, const scalar_t* feats,
                                       int64_t nf_rt, int base, int32_t e, const double* other) {
  const int64_t nf = feature_count<NF>(nf_rt);
  int blended = 0, stopped = 0;
  for (int h = 0; h < 2; ++h) {
    const int o = base + kHalf * h;
    double* trans = st.trans.data() + o;
    const D4 t = load_v<D4>(trans);
    const L4 valid = la.hit_half(h) & (t > 0.0);
    if (!lane_bits(valid)) continue;
    const D4 a = half_as_double(la.alpha, h);
    const D4 t_next = t * (1.0 - a);
    const L4 ends = valid & (t_next < kTransmittanceMin);
    const L4 blend = valid & ~ends;
    store_v(trans, blend ? t_next : (ends ? -t : t));
    stopped += __builtin_popcount(lane_bits(ends & (load_v<D4>(other + kHalf * h) < 0.0)));
    const unsigned b = lane_bits(blend);
    if (!b) continue;
    blended += __builtin_popcount(b);
    int32_t* stop = st.stop.data() + o;
    store_v(stop, __builtin_convertvector(blend, I4) ? I4{} + (e + 1) : load_v<I4>(stop));
    const D4 weight = blend ? a * t : 0.0;
    for (int64_t k = 0; k < nf; ++k) {
      double* acc = st.acc.data() + k * kTilePixels + o;
      store_v(acc, load_v<D4>(acc) + weight * double(feats[k]));
    }
  }
  return {blended, stopped};
}

// A record of the second stream: the Gaussians outside the subset (flag, the last feature, 0),
// composited on their own with one feature, `alone`.
template <typename scalar_t>
inline bool outside_subset(const scalar_t* rec, int64_t stride) {
  return rec[stride - 1] == scalar_t(0);
}

template <typename scalar_t, int NF>
std::vector<torch::Tensor> forward_impl(const torch::Tensor& means2d, const torch::Tensor& conics,
                                        const torch::Tensor& opacities, const torch::Tensor& feats,
                                        const torch::Tensor& radii, const torch::Tensor& sort_keys,
                                        const torch::Tensor& visible, int64_t width, int64_t height,
                                        int64_t alone) {
  const int64_t cams = means2d.size(0), nf = feats.size(2);
  const int64_t tiles_x = (width + kTile - 1) / kTile, tiles_y = (height + kTile - 1) / kTile;
  const int64_t tiles = tiles_x * tiles_y;
  const bool second = alone >= 0;
  Bins b = bin_gaussians<scalar_t>(means2d, conics, opacities, feats, radii, sort_keys, visible, width, height);
  auto opts = means2d.options();
  torch::Tensor out = torch::empty({cams, height, width, nf}, opts);
  torch::Tensor alpha = torch::empty({cams, height, width}, opts);
  torch::Tensor t_final = torch::empty({cams, height, width}, opts.dtype(torch::kFloat64));
  torch::Tensor last = torch::empty({cams, height, width}, opts.dtype(torch::kInt32));
  torch::Tensor pair_count = torch::zeros({cams * tiles}, opts.dtype(torch::kInt64));
  const int64_t second_pixels = second ? cams * height * width : 0;
  torch::Tensor out2 = torch::empty({second_pixels}, opts);
  torch::Tensor alpha2 = torch::empty({second_pixels}, opts);
  torch::Tensor t_final2 = torch::empty({second_pixels}, opts.dtype(torch::kFloat64));
  torch::Tensor last2 = torch::empty({second_pixels}, opts.dtype(torch::kInt32));

  const int64_t stride = 6 + nf;
  const scalar_t* rec = b.records.data_ptr<scalar_t>();
  const Rect* rects = reinterpret_cast<const Rect*>(b.rects.data_ptr<int32_t>());
  const int64_t* toff = b.tile_offsets.data_ptr<int64_t>();
  const int32_t* ent = b.entries.data_ptr<int32_t>();
  scalar_t* out_p = out.data_ptr<scalar_t>();
  scalar_t* alpha_p = alpha.data_ptr<scalar_t>();
  double* tf_p = t_final.data_ptr<double>();
  int32_t* last_p = last.data_ptr<int32_t>();
  int64_t* pc_p = pair_count.data_ptr<int64_t>();
  scalar_t* out2_p = out2.data_ptr<scalar_t>();
  scalar_t* alpha2_p = alpha2.data_ptr<scalar_t>();
  double* tf2_p = t_final2.data_ptr<double>();
  int32_t* last2_p = last2.data_ptr<int32_t>();
  const auto footprints = record_footprints(rec, rects, b.records.size(0), stride);

#pragma omp parallel num_threads(num_threads())
  {
    ForwardTile st(nf), st2(1);
    Lanes<scalar_t> lanes;
#pragma omp for schedule(dynamic, 1)
    for (int64_t ct = 0; ct < cams * tiles; ++ct) {
      const int64_t c = ct / tiles;
      const TileBox tb = tile_box(ct % tiles, tiles_x, width, height);
      int active = (tb.x1 - tb.x0 + 1) * (tb.y1 - tb.y0 + 1);
      st.reset();
      st2.reset(second);
      int64_t pairs = 0;
      const int64_t begin = toff[ct], count = toff[ct + 1] - begin;
      for (int64_t e = 0; e < count && active > 0; ++e) {
        if (e + kPrefetch < count) prefetch_record(footprints.data(), rec, stride, ent[begin + e + kPrefetch]);
        const int64_t s = ent[begin + e];
        const Footprint<scalar_t>& fp = footprints[s];
        const EntryBox<scalar_t> box(fp, tb);
        if (box.empty()) continue;
        const scalar_t* feats_s = rec + s * stride + 6;
        const bool in_second = second && outside_subset(rec + s * stride, stride);
        const auto open = [&](int base) {
          return any_positive(st.trans.data() + base) || (in_second && any_positive(st2.trans.data() + base));
        };
        for_each_group(fp, box, tb, lanes, open, [&](scalar_t, int base) {
          const auto [blended, stopped] =
              blend_lanes<scalar_t, NF>(st, lanes, feats_s, nf, base, int32_t(e), st2.trans.data() + base);
          pairs += blended;
          active -= stopped;
          if (in_second) {
            active -= blend_lanes<scalar_t, 1>(st2, lanes, feats_s + alone, 1, base, int32_t(e),
                                               st.trans.data() + base).second;
          }
        });
      }
      pc_p[ct] = pairs;
      for (int y = tb.y0; y <= tb.y1; ++y) {
        for (int x = tb.x0; x <= tb.x1; ++x) {
          const int p = (y - tb.y0) * kTile + (x - tb.x0);
          const int64_t pix = (c * height + y) * width + x;
          const double t = std::abs(st.trans[p]);
          for (int64_t k = 0; k < nf; ++k) out_p[pix * nf + k] = scalar_t(st.acc[k * kTilePixels + p]);
          alpha_p[pix] = scalar_t(1.0 - t);
          tf_p[pix] = t;
          last_p[pix] = st.stop[p];
          if (second) {
            const double t2 = std::abs(st2.trans[p]);
            out2_p[pix] = scalar_t(st2.acc[p]);
            alpha2_p[pix] = scalar_t(1.0 - t2);
            tf2_p[pix] = t2;
            last2_p[pix] = st2.stop[p];
          }
        }
      }
    }
  }
  return {out, alpha, pair_count.sum(), out2, alpha2, t_final, last, t_final2, last2, b.records, b.rects, b.source,
          b.tile_offsets, b.entries, b.record_offsets, b.slot_of};
}

// Per-tile pixel state of the backward pass (structure of arrays over the 16x16 pixels).
struct BackwardTile {
  std::vector<double> trans, t_end, g_alpha_out, behind, g_out;
  std::vector<int32_t> stop;
  explicit BackwardTile(int64_t nf)
      : trans(kTilePixels), t_end(kTilePixels), g_alpha_out(kTilePixels), behind(kTilePixels * nf),
        g_out(kTilePixels * nf), stop(kTilePixels) {}
};

// Gradient sums of one tile entry, lane by lane: row j holds [means2d x, y, conic a, b, c,
// opacity, features...][lane]. Summed over lanes in a fixed order once per entry.
struct EntrySums {
  std::vector<double> lane;  // [(6 + F) * kLanes]
  explicit EntrySums(int64_t stride) : lane(stride * kLanes) {}
  void clear() { std::fill(lane.begin(), lane.end(), 0.0); }
  void add(int64_t row, int h, const D4& v) {
    double* p = &lane[row * kLanes + kHalf * h];
    store_v(p, load_v<D4>(p) + v);
  }
  // Each (record, tile) slot is written once, by the tile's one visit of the entry: a store, not
  // an add. The slots lie scattered through a buffer far larger than the cache, and reading one
  // back before adding stalled the walk (a quarter of the backward's time in `perf` at 200x150).
  void store_to(double* g) const {
    const int64_t rows = int64_t(lane.size()) / kLanes;
    for (int64_t j = 0; j < rows; ++j) {
      double sum = 0.0;
      for (int l = 0; l < kLanes; ++l) sum += lane[j * kLanes + l];
      g[j] = sum;
    }
  }
};

// Steps one stream back past entry `e` over one lane group: each pixel's transmittance and
// behind-features are rebuilt, and the entry's gradient terms are added lane-wise into `sums`
// (its features into rows 6 + feat_row onwards).
template <typename scalar_t, int NF>
inline void unblend_lanes(BackwardTile& st, const Lanes<scalar_t>& la, const Footprint<scalar_t>& fp,
                          const scalar_t* feats, int64_t nf_rt, int base, scalar_t dy, int32_t e, EntrySums& sums,
                          int64_t feat_row) {
  const int64_t nf = feature_count<NF>(nf_rt);
  const double qa = double(fp.qa), qb = double(fp.qb), qc = double(fp.qc), ddy = double(dy);
  for (int h = 0; h < 2; ++h) {
    const int o = base + kHalf * h;
    const L4 valid = la.hit_half(h) & widen(I4{} + e < load_v<I4>(st.stop.data() + o));
    if (!lane_bits(valid)) continue;
    double* trans = st.trans.data() + o;
    const D4 ad = valid ? half_as_double(la.alpha, h) : 0.0;
    const D4 inv_1ma = 1.0 / (1.0 - ad);
    const D4 t_i = load_v<D4>(trans) * inv_1ma;
    // alpha output = 1 - T_final
    D4 g_a = load_v<D4>(st.g_alpha_out.data() + o) * load_v<D4>(st.t_end.data() + o) * inv_1ma;
    for (int64_t k = 0; k < nf; ++k) {
      const D4 g_out = load_v<D4>(st.g_out.data() + k * kTilePixels + o);
      const D4 behind = load_v<D4>(st.behind.data() + k * kTilePixels + o);
      g_a = g_a + g_out * (t_i * double(feats[k]) - behind * inv_1ma);
    }
    const D4 w = ad * t_i;
    store_v(trans, t_i);
    const L4 open = valid & la.below_clamp(h, fp.opac);
    const D4 g_sigma = open ? -g_a * ad : 0.0;
    const D4 ddx = half_as_double(la.dx, h);
    sums.add(0, h, g_sigma * (qa * ddx + qb * ddy));
    sums.add(1, h, g_sigma * (qb * ddx + qc * ddy));
    sums.add(2, h, g_sigma * 0.5 * ddx * ddx);
    sums.add(3, h, g_sigma * ddx * ddy);
    sums.add(4, h, g_sigma * 0.5 * ddy * ddy);
    sums.add(5, h, open ? g_a * half_as_double(la.falloff, h) : 0.0);
    for (int64_t k = 0; k < nf; ++k) {
      double* behind = st.behind.data() + k * kTilePixels + o;
      sums.add(6 + feat_row + k, h, w * load_v<D4>(st.g_out.data() + k * kTilePixels + o));
      store_v(behind, load_v<D4>(behind) + w * double(feats[k]));
    }
  }
}

template <typename scalar_t, int NF>
std::vector<torch::Tensor> backward_impl(int64_t cams, int64_t n, const torch::Tensor& t_final,
                                         const torch::Tensor& last, const torch::Tensor& records,
                                         const torch::Tensor& rects_t, const torch::Tensor& source,
                                         const torch::Tensor& tile_offsets, const torch::Tensor& entries,
                                         const torch::Tensor& record_offsets, const torch::Tensor& slot_of,
                                         const torch::Tensor& grad_out, const torch::Tensor& grad_alpha,
                                         const torch::Tensor& t_final2, const torch::Tensor& last2,
                                         const torch::Tensor& grad_out2, const torch::Tensor& grad_alpha2,
                                         int64_t alone, int64_t width, int64_t height) {
  const int64_t stride = records.size(1), nf = stride - 6;
  const bool second = alone >= 0;
  const int64_t tiles_x = (width + kTile - 1) / kTile, tiles_y = (height + kTile - 1) / kTile;
  const int64_t tiles = tiles_x * tiles_y;
  const int64_t total = entries.size(0), packed = records.size(0);
  // Per-(record, tile) gradient partials in record-major slot order, zero where a tile never
  // reaches the entry (written once where it does); the final per-record sums then read memory
  // sequentially.
  std::vector<double> partial(total * stride, 0.0);
  const int64_t* sof = slot_of.data_ptr<int64_t>();

  const scalar_t* rec = records.data_ptr<scalar_t>();
  const double* tf_p = t_final.data_ptr<double>();
  const int32_t* last_p = last.data_ptr<int32_t>();
  const Rect* rects = reinterpret_cast<const Rect*>(rects_t.data_ptr<int32_t>());
  const int64_t* toff = tile_offsets.data_ptr<int64_t>();
  const int32_t* ent = entries.data_ptr<int32_t>();
  const scalar_t* go_p = grad_out.data_ptr<scalar_t>();
  const scalar_t* ga_p = grad_alpha.data_ptr<scalar_t>();
  const double* tf2_p = t_final2.data_ptr<double>();
  const int32_t* last2_p = last2.data_ptr<int32_t>();
  const scalar_t* go2_p = grad_out2.data_ptr<scalar_t>();
  const scalar_t* ga2_p = grad_alpha2.data_ptr<scalar_t>();
  const auto footprints = record_footprints(rec, rects, packed, stride);

#pragma omp parallel num_threads(num_threads())
  {
    BackwardTile st(nf), st2(1);
    Lanes<scalar_t> lanes;
    EntrySums sums(stride);
#pragma omp for schedule(dynamic, 1)
    for (int64_t ct = 0; ct < cams * tiles; ++ct) {
      const int64_t c = ct / tiles;
      const TileBox tb = tile_box(ct % tiles, tiles_x, width, height);
      const int64_t begin = toff[ct];
      int32_t max_stop = 0, max_stop2 = 0;
      std::fill(st.behind.begin(), st.behind.end(), 0.0);
      std::fill(st.stop.begin(), st.stop.end(), 0);
      std::fill(st2.behind.begin(), st2.behind.end(), 0.0);
      std::fill(st2.stop.begin(), st2.stop.end(), 0);
      for (int y = tb.y0; y <= tb.y1; ++y) {
        for (int x = tb.x0; x <= tb.x1; ++x) {
          const int p = (y - tb.y0) * kTile + (x - tb.x0);
          const int64_t pix = (c * height + y) * width + x;
          st.trans[p] = st.t_end[p] = tf_p[pix];
          st.stop[p] = last_p[pix];
          st.g_alpha_out[p] = double(ga_p[pix]);
          for (int64_t k = 0; k < nf; ++k) st.g_out[k * kTilePixels + p] = double(go_p[pix * nf + k]);
          max_stop = std::max(max_stop, st.stop[p]);
          if (second) {
            st2.trans[p] = st2.t_end[p] = tf2_p[pix];
            st2.stop[p] = last2_p[pix];
            st2.g_alpha_out[p] = double(ga2_p[pix]);
            st2.g_out[p] = double(go2_p[pix]);
            max_stop2 = std::max(max_stop2, st2.stop[p]);
          }
        }
      }
      // Back to front: rebuild each pair's transmittance from the final one, as 3DGS does; a
      // record outside the subset also steps the second stream back.
      for (int64_t e = std::max(max_stop, max_stop2) - 1; e >= 0; --e) {
        if (e >= kPrefetch) prefetch_record(footprints.data(), rec, stride, ent[begin + e - kPrefetch]);
        const int64_t s = ent[begin + e];
        const bool first_open = e < max_stop;
        const bool second_open = e < max_stop2 && outside_subset(rec + s * stride, stride);
        if (!first_open && !second_open) continue;
        const Footprint<scalar_t>& fp = footprints[s];
        const EntryBox<scalar_t> box(fp, tb);
        if (box.empty()) continue;
        const scalar_t* feats_s = rec + s * stride + 6;
        sums.clear();
        const auto open = [&](int base) {
          return (first_open && any_reached(st.stop.data() + base, int32_t(e))) ||
                 (second_open && any_reached(st2.stop.data() + base, int32_t(e)));
        };
        for_each_group(fp, box, tb, lanes, open, [&](scalar_t dy, int base) {
          if (first_open) unblend_lanes<scalar_t, NF>(st, lanes, fp, feats_s, nf, base, dy, int32_t(e), sums, 0);
          if (second_open) {
            unblend_lanes<scalar_t, 1>(st2, lanes, fp, feats_s + alone, 1, base, dy, int32_t(e), sums, alone);
          }
        });
        sums.store_to(partial.data() + sof[begin + e] * stride);
      }
    }
  }

  // Fixed-order reduction of the per-(record, tile) partials: one task per record.
  auto opts = records.options();
  torch::Tensor g_means2d = torch::zeros({cams, n, 2}, opts);
  torch::Tensor g_conics = torch::zeros({cams, n, 3}, opts);
  torch::Tensor g_opac = torch::zeros({cams, n}, opts);
  torch::Tensor g_feats = torch::zeros({cams, n, nf}, opts);
  const int64_t* roff = record_offsets.data_ptr<int64_t>();

  const int64_t* src = source.data_ptr<int64_t>();
  scalar_t* gm = g_means2d.data_ptr<scalar_t>();
  scalar_t* gc = g_conics.data_ptr<scalar_t>();
  scalar_t* gop = g_opac.data_ptr<scalar_t>();
  scalar_t* gf = g_feats.data_ptr<scalar_t>();
  at::parallel_for(0, packed, 1024, [&](int64_t lo, int64_t hi) {
    std::vector<double> sum(stride);
    for (int64_t s = lo; s < hi; ++s) {
      std::fill(sum.begin(), sum.end(), 0.0);
      for (int64_t k = roff[s]; k < roff[s + 1]; ++k) {
        const double* part = &partial[k * stride];
        for (int64_t j = 0; j < stride; ++j) sum[j] += part[j];
      }
      const int64_t cg = src[s];
      gm[2 * cg] = scalar_t(sum[0]);
      gm[2 * cg + 1] = scalar_t(sum[1]);
      for (int j = 0; j < 3; ++j) gc[3 * cg + j] = scalar_t(sum[2 + j]);
      gop[cg] = scalar_t(sum[5]);
      for (int64_t j = 0; j < nf; ++j) gf[cg * nf + j] = scalar_t(sum[6 + j]);
    }
  });
  return {g_means2d, g_conics, g_opac, g_feats};
}

// Calls fn.template operator()<NF>() with NF the feature count when it is 1..6, else NF = 0.
template <typename Fn>
auto with_feature_count(int64_t nf, Fn&& fn) {
  switch (nf) {
    case 1: return fn(std::integral_constant<int, 1>{});
    case 2: return fn(std::integral_constant<int, 2>{});
    case 3: return fn(std::integral_constant<int, 3>{});
    case 4: return fn(std::integral_constant<int, 4>{});
    case 5: return fn(std::integral_constant<int, 5>{});
    case 6: return fn(std::integral_constant<int, 6>{});
    default: return fn(std::integral_constant<int, 0>{});
  }
}

std::vector<torch::Tensor> forward(const torch::Tensor& means2d, const torch::Tensor& conics,
                                   const torch::Tensor& opacities, const torch::Tensor& feats,
                                   const torch::Tensor& radii, const torch::Tensor& sort_keys,
                                   const torch::Tensor& visible, int64_t width, int64_t height, int64_t alone) {
  TORCH_CHECK(means2d.device().is_cpu(), "tile rasterizer: tensors must be on the CPU");
  TORCH_CHECK(means2d.dim() == 3 && means2d.size(2) == 2, "tile rasterizer: means2d must be [C, N, 2]");
  const auto c = means2d.size(0), n = means2d.size(1);
  TORCH_CHECK(conics.sizes() == torch::IntArrayRef({c, n, 3}), "tile rasterizer: conics must be [C, N, 3]");
  TORCH_CHECK(opacities.dim() == 1 && opacities.size(0) == n, "tile rasterizer: opacities must be [N]");
  TORCH_CHECK(feats.dim() == 3 && feats.size(0) == c && feats.size(1) == n, "tile rasterizer: feats must be [C, N, F]");
  TORCH_CHECK(radii.sizes() == torch::IntArrayRef({c, n}) && sort_keys.sizes() == radii.sizes() &&
                  visible.sizes() == radii.sizes(),
              "tile rasterizer: radii, sort_keys and visible must be [C, N]");
  for (const auto* t : {&means2d, &conics, &opacities, &feats, &radii}) {
    TORCH_CHECK(t->is_contiguous() && t->scalar_type() == means2d.scalar_type(),
                "tile rasterizer: float inputs must be contiguous and share one dtype");
  }
  TORCH_CHECK(sort_keys.is_floating_point() && visible.scalar_type() == torch::kBool,
              "tile rasterizer: sort_keys must be floating point and visible bool");
  TORCH_CHECK(width > 0 && height > 0 && width < (1 << 30) && height < (1 << 30), "tile rasterizer: bad image size");
  TORCH_CHECK(alone < 0 || alone + 1 < feats.size(2),
              "tile rasterizer: the alone feature must precede the subset flag (the last feature)");
  std::vector<torch::Tensor> result;
  AT_DISPATCH_FLOATING_TYPES(means2d.scalar_type(), "tile_raster_forward", [&] {
    result = with_feature_count(feats.size(2), [&](auto nf) {
      return forward_impl<scalar_t, decltype(nf)::value>(means2d, conics, opacities, feats, radii,
                                                         sort_keys.to(torch::kFloat64).contiguous(),
                                                         visible.contiguous(), width, height, alone);
    });
  });
  return result;
}

std::vector<torch::Tensor> backward(int64_t cams, int64_t n, const torch::Tensor& t_final, const torch::Tensor& last,
                                    const torch::Tensor& records, const torch::Tensor& rects,
                                    const torch::Tensor& source, const torch::Tensor& tile_offsets,
                                    const torch::Tensor& entries, const torch::Tensor& record_offsets,
                                    const torch::Tensor& slot_of, const torch::Tensor& grad_out,
                                    const torch::Tensor& grad_alpha, const torch::Tensor& t_final2,
                                    const torch::Tensor& last2, const torch::Tensor& grad_out2,
                                    const torch::Tensor& grad_alpha2, int64_t alone, int64_t width, int64_t height) {
  TORCH_CHECK(records.dim() == 2 && records.size(1) >= 6, "tile rasterizer: records must be [S, 6 + F]");
  std::vector<torch::Tensor> result;
  AT_DISPATCH_FLOATING_TYPES(records.scalar_type(), "tile_raster_backward", [&] {
    result = with_feature_count(records.size(1) - 6, [&](auto nf) {
      return backward_impl<scalar_t, decltype(nf)::value>(
          cams, n, t_final, last, records, rects, source, tile_offsets, entries, record_offsets, slot_of,
          grad_out.to(records.scalar_type()).contiguous(), grad_alpha.to(records.scalar_type()).contiguous(),
          t_final2, last2, grad_out2.to(records.scalar_type()).contiguous(),
          grad_alpha2.to(records.scalar_type()).contiguous(), alone, width, height);
    });
  });
  return result;
}

}  // namespace

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  m.doc() = "Tile-based CPU Gaussian compositing with an analytic backward (3DGS semantics)";
  m.def("forward", &forward,
        "Bin and composite projected Gaussians (and, with alone >= 0, the Gaussians outside the subset on their "
        "own); returns images and saved state");
  m.def("backward", &backward, "Gradients w.r.t. means2d, conics, per-camera opacities and features");
  m.def("project_forward", &smokeseer::project_forward, "EWA projection: means2d, conics, depths, radii, visible");
  m.def("project_backward", &smokeseer::project_backward, "Gradients of the projection w.r.t. its inputs");
  m.def("sh_forward", &smokeseer::sh_forward, "View-dependent colours from SH coefficients (+0.5, clamped at 0)");
  m.def("sh_backward", &smokeseer::sh_backward, "Gradients of the SH colours w.r.t. coefficients and means");
}
