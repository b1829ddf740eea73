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
// first stream composites surface and smoke together; binning, the ellipse spans and the record
// reads are shared. A pixel stops walking when both its streams have stopped.

#include <torch/extension.h>

#include "projection.h"

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

// exp(-sigma) for sigma >= 0. float: a branch-free polynomial (Cephes-style range reduction,
// relative error ~2e-7, like expf) that vectorises; double: std::exp. Forward and backward call
// the same code with the same rounding (no FMA contraction), so they agree on every skipped pair.
inline float exp_neg(float sigma) {
  const float x = std::max(-sigma, -87.0f);
  const float k = std::nearbyint(x * 1.44269504088896341f);
  const float r = (x - k * 0.693359375f) + k * 2.12194440e-4f;
  float p = 1.9875691500e-4f;
  p = p * r + 1.3981999507e-3f;
  p = p * r + 8.3334519073e-3f;
  p = p * r + 4.1665795894e-2f;
  p = p * r + 1.6666665459e-1f;
  p = p * r + 5.0000001201e-1f;
  const float poly = (p * r) * r + r + 1.0f;
  int32_t bits;
  std::memcpy(&bits, &poly, sizeof(bits));
  bits += int32_t(k) << 23;
  float out;
  std::memcpy(&out, &bits, sizeof(out));
  return out;
}

inline double exp_neg(double sigma) { return std::exp(-sigma); }

// Pixels where alpha can reach 1/255 lie inside the ellipse sigma <= log(255 * opacity). This
// finds, conservatively (a margin in sigma and one pixel on each side), the rows of a rectangle
// that meet that ellipse and each row's column span, so the exact per-pixel test (still applied)
// runs on few pixels it rejects. Culling here only skips pixels that the exact test would skip.
struct EllipseSpans {
  double mx, my, half_a, b, half_c, limit;
  int row_lo, row_hi;  // rows that can meet the ellipse (the whole int range when not shaped)
  bool shaped;  // false: no usable bound (degenerate conic); every pixel of the rectangle is tested

  EllipseSpans() = default;

  template <typename scalar_t>
  EllipseSpans(scalar_t mx_, scalar_t my_, scalar_t qa, scalar_t qb, scalar_t qc, scalar_t opac)
      : mx(mx_), my(my_), half_a(0.5 * double(qa)), b(qb), half_c(0.5 * double(qc)) {
    const double s_max = std::log(255.0 * double(opac));
    limit = s_max + 1e-3 + 1e-4 * std::abs(s_max);
    shaped = half_a > 0.0 && std::isfinite(half_a) && std::isfinite(b) && std::isfinite(half_c) &&
             std::isfinite(limit);
    row_lo = std::numeric_limits<int>::min();
    row_hi = std::numeric_limits<int>::max();
    const double det = 4.0 * half_a * half_c - b * b;
    if (!shaped || !(det > 0.0)) return;
    const double reach = std::sqrt(4.0 * limit * half_a / det);
    row_lo = int(std::ceil(std::max(-1e9, my - reach - 0.5)) - 1.0);
    row_hi = int(std::floor(std::min(1e9, my + reach - 0.5)) + 1.0);
  }

  bool empty() const { return shaped && limit < 0.0; }

  // Narrow the inclusive row range [y0, y1].
  void rows(int& y0, int& y1) const {
    y0 = std::max(y0, row_lo);
    y1 = std::min(y1, row_hi);
  }

  // Narrow the inclusive column range [x0, x1] on row y; false when the row misses the ellipse.
  bool columns(int y, int& x0, int& x1) const {
    if (!shaped) return true;
    const double dy = my - (double(y) + 0.5);
    const double lin = b * dy, cst = half_c * dy * dy - limit;
    const double disc = lin * lin - 4.0 * half_a * cst;
    if (disc < 0.0) return false;
    const double root = std::sqrt(disc), inv = 0.5 / half_a;
    const double dx_lo = (-lin - root) * inv, dx_hi = (-lin + root) * inv;
    const double lo = std::ceil(std::max(-1e9, mx - dx_hi - 0.5)) - 1.0;
    const double hi = std::floor(std::min(1e9, mx - dx_lo - 0.5)) + 1.0;
    x0 = std::max(x0, int(lo));
    x1 = std::min(x1, int(hi));
    return x0 <= x1;
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

// One EllipseSpans per packed record (a log and a square root), shared by every tile entry of
// that record instead of recomputed per entry.
template <typename scalar_t>
std::vector<EllipseSpans> record_spans(const scalar_t* rec, int64_t packed, int64_t stride) {
  std::vector<EllipseSpans> spans(packed);
  at::parallel_for(0, packed, 2048, [&](int64_t lo, int64_t hi) {
    for (int64_t s = lo; s < hi; ++s) {
      const scalar_t* r = rec + s * stride;
      spans[s] = EllipseSpans(r[0], r[1], r[2], r[3], r[4], r[5]);
    }
  });
  return spans;
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

// Pixel range of tile `t` and of its intersection with a Gaussian's rectangle.
struct TileBox {
  int x0, x1, y0, y1;  // inclusive
};

inline TileBox tile_box(int64_t t, int64_t tiles_x, int64_t width, int64_t height) {
  const int tx = int(t % tiles_x), ty = int(t / tiles_x);
  return TileBox{tx * kTile, int(std::min<int64_t>(width, (tx + 1) * kTile)) - 1, ty * kTile,
                 int(std::min<int64_t>(height, (ty + 1) * kTile)) - 1};
}

// The record fields a pixel loop needs, read once per tile entry.
template <typename scalar_t>
struct Splat {
  scalar_t mx, my, qa, qb, qc, opac;
  const scalar_t* feats;
  int x0, x1, y0, y1;  // rectangle clipped to the tile

  Splat(const scalar_t* rec, const Rect& r, const TileBox& tb)
      : mx(rec[0]), my(rec[1]), qa(rec[2]), qb(rec[3]), qc(rec[4]), opac(rec[5]), feats(rec + 6),
        x0(std::max(r.x0, tb.x0)), x1(std::min(r.x1, tb.x1)), y0(std::max(r.y0, tb.y0)),
        y1(std::min(r.y1, tb.y1)) {}
};

// Features per record: a compile-time count (so per-pixel loops vectorise) or, for NF == 0, any.
template <int NF>
inline int64_t feature_count(int64_t nf) {
  return NF > 0 ? NF : nf;
}

// Per-tile pixel state of the forward pass, structure of arrays over the 16x16 pixels.
// `trans` holds the transmittance; a pixel that stopped stores its final T negated. A stream that
// is off starts stopped (T = -1), so it never blends and never keeps a pixel open.
struct ForwardTile {
  std::vector<double> trans, acc, weight;
  std::vector<int32_t> stop;
  explicit ForwardTile(int64_t nf) : trans(kTilePixels), acc(kTilePixels * nf), weight(kTile), stop(kTilePixels) {}
  void reset(bool on = true) {
    std::fill(trans.begin(), trans.end(), on ? 1.0 : -1.0);
    std::fill(acc.begin(), acc.end(), 0.0);
    std::fill(stop.begin(), stop.end(), 0);
  }
};

// Blend entry `e` (record `sp`) into one row of the tile: returns (pairs blended, pixels stopped).
// A pixel counts as stopped when this stream ends there and the other stream (`other`, the same
// row of its transmittance) has already ended, so each pixel is counted once, by its last stream.
template <typename scalar_t, int NF>
inline std::pair<int, int> blend_row(ForwardTile& st, const Splat<scalar_t>& sp, int64_t nf_rt, int row_base,
                                     int y, int cx0, int cx1, int32_t e, const double* other) {
  const int64_t nf = feature_count<NF>(nf_rt);
  const scalar_t dy = sp.my - (scalar_t(y) + scalar_t(0.5));
  const scalar_t row_term = scalar_t(0.5) * sp.qc * dy * dy;
  double* trans = st.trans.data() + row_base;
  double* weight = st.weight.data();
  int32_t* stop = st.stop.data() + row_base;
  int blended = 0, stopped = 0;
#pragma omp simd reduction(+ : blended, stopped)
  for (int x = cx0; x <= cx1; ++x) {
    const scalar_t dx = sp.mx - (scalar_t(x) + scalar_t(0.5));
    const scalar_t sigma = scalar_t(0.5) * sp.qa * dx * dx + row_term + sp.qb * dx * dy;
    const scalar_t alpha = std::min(sp.opac * exp_neg(sigma), scalar_t(kAlphaMax));
    const double t = trans[x];
    const bool valid = t > 0.0 && sigma >= scalar_t(0) && alpha >= scalar_t(kAlphaMin);
    const double t_next = t * (1.0 - double(alpha));
    const bool ends = valid && t_next < kTransmittanceMin;
    const bool blend = valid && !ends;
    weight[x - cx0] = blend ? double(alpha) * t : 0.0;
    trans[x] = blend ? t_next : (ends ? -t : t);
    stop[x] = blend ? e + 1 : stop[x];
    blended += blend ? 1 : 0;
    stopped += (ends && other[x] < 0.0) ? 1 : 0;
  }
  for (int64_t k = 0; k < nf; ++k) {
    double* acc = st.acc.data() + k * kTilePixels + row_base;
    const double f = double(sp.feats[k]);
#pragma omp simd
    for (int x = cx0; x <= cx1; ++x) acc[x] += weight[x - cx0] * f;
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
  const std::vector<EllipseSpans> spans = record_spans(rec, b.records.size(0), stride);

#pragma omp parallel num_threads(num_threads())
  {
    ForwardTile st(nf), st2(1);
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
        const int64_t s = ent[begin + e];
        const EllipseSpans& span = spans[s];
        if (span.empty()) continue;
        const Splat<scalar_t> sp(rec + s * stride, rects[s], tb);
        const bool in_second = second && outside_subset(rec + s * stride, stride);
        Splat<scalar_t> sp2 = sp;
        sp2.feats += alone;
        int ry0 = sp.y0, ry1 = sp.y1;
        span.rows(ry0, ry1);
        for (int y = ry0; y <= ry1; ++y) {
          int cx0 = sp.x0, cx1 = sp.x1;
          if (!span.columns(y, cx0, cx1)) continue;
          const int row_base = (y - tb.y0) * kTile - tb.x0;
          const auto [blended, stopped] = blend_row<scalar_t, NF>(st, sp, nf, row_base, y, cx0, cx1, int32_t(e),
                                                                  st2.trans.data() + row_base);
          pairs += blended;
          active -= stopped;
          if (in_second) {
            active -= blend_row<scalar_t, 1>(st2, sp2, 1, row_base, y, cx0, cx1, int32_t(e),
                                             st.trans.data() + row_base).second;
          }
        }
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
  std::vector<double> trans, t_end, g_alpha_out, behind, g_out, weight;
  std::vector<int32_t> stop;
  explicit BackwardTile(int64_t nf)
      : trans(kTilePixels), t_end(kTilePixels), g_alpha_out(kTilePixels), behind(kTilePixels * nf),
        g_out(kTilePixels * nf), weight(kTile), stop(kTilePixels) {}
};

// Adds one entry's gradient sums over one row to `g` (means2d 2, conic 3, opacity 1) and to
// `g_feat` (its features), stepping each pixel's transmittance and behind-colour back past this entry.
template <typename scalar_t, int NF>
inline void unblend_row(BackwardTile& st, const Splat<scalar_t>& sp, int64_t nf_rt, int row_base, int y, int cx0,
                        int cx1, int32_t e, double* g, double* g_feat) {
  const int64_t nf = feature_count<NF>(nf_rt);
  const scalar_t dy = sp.my - (scalar_t(y) + scalar_t(0.5));
  const scalar_t row_term = scalar_t(0.5) * sp.qc * dy * dy;
  const double qa = double(sp.qa), qb = double(sp.qb), qc = double(sp.qc), ddy = double(dy);
  double* trans = st.trans.data() + row_base;
  double* weight = st.weight.data();
  const double* t_end = st.t_end.data() + row_base;
  const double* g_alpha_out = st.g_alpha_out.data() + row_base;
  const double* behind = st.behind.data() + row_base;
  const double* g_out = st.g_out.data() + row_base;
  const int32_t* stop = st.stop.data() + row_base;
  const scalar_t* feats = sp.feats;
  double g0 = 0, g1 = 0, g2 = 0, g3 = 0, g4 = 0, g5 = 0;
#pragma omp simd reduction(+ : g0, g1, g2, g3, g4, g5)
  for (int x = cx0; x <= cx1; ++x) {
    const scalar_t dx = sp.mx - (scalar_t(x) + scalar_t(0.5));
    const scalar_t sigma = scalar_t(0.5) * sp.qa * dx * dx + row_term + sp.qb * dx * dy;
    const scalar_t falloff = exp_neg(sigma);
    const scalar_t alpha = std::min(sp.opac * falloff, scalar_t(kAlphaMax));
    const bool valid = e < stop[x] && sigma >= scalar_t(0) && alpha >= scalar_t(kAlphaMin);
    const double ad = valid ? double(alpha) : 0.0;
    const double inv_1ma = 1.0 / (1.0 - ad);
    const double t_i = trans[x] * inv_1ma;
    double g_a = g_alpha_out[x] * t_end[x] * inv_1ma;  // alpha output = 1 - T_final
    for (int64_t k = 0; k < nf; ++k) {
      g_a += g_out[k * kTilePixels + x] * (t_i * double(feats[k]) - behind[k * kTilePixels + x] * inv_1ma);
    }
    weight[x - cx0] = ad * t_i;
    trans[x] = t_i;
    const bool open = valid && sp.opac * falloff <= scalar_t(kAlphaMax);  // below the clamp
    const double g_sigma = open ? -g_a * ad : 0.0;
    const double ddx = double(dx);
    g5 += open ? g_a * double(falloff) : 0.0;
    g0 += g_sigma * (qa * ddx + qb * ddy);
    g1 += g_sigma * (qb * ddx + qc * ddy);
    g2 += g_sigma * 0.5 * ddx * ddx;
    g3 += g_sigma * ddx * ddy;
    g4 += g_sigma * 0.5 * ddy * ddy;
  }
  g[0] += g0;
  g[1] += g1;
  g[2] += g2;
  g[3] += g3;
  g[4] += g4;
  g[5] += g5;
  for (int64_t k = 0; k < nf; ++k) {
    double* bk = st.behind.data() + k * kTilePixels + row_base;
    const double* gk = g_out + k * kTilePixels;
    const double fk = double(feats[k]);
    double sum = 0.0;
#pragma omp simd reduction(+ : sum)
    for (int x = cx0; x <= cx1; ++x) {
      sum += weight[x - cx0] * gk[x];
      bk[x] += weight[x - cx0] * fk;
    }
    g_feat[k] += sum;
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
  // reaches the entry; the final per-record sums then read memory sequentially.
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
  const std::vector<EllipseSpans> spans = record_spans(rec, packed, stride);

#pragma omp parallel num_threads(num_threads())
  {
    BackwardTile st(nf), st2(1);
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
        const int64_t s = ent[begin + e];
        const EllipseSpans& span = spans[s];
        if (span.empty()) continue;
        const bool first_open = e < max_stop;
        const bool second_open = e < max_stop2 && outside_subset(rec + s * stride, stride);
        if (!first_open && !second_open) continue;
        const Splat<scalar_t> sp(rec + s * stride, rects[s], tb);
        Splat<scalar_t> sp2 = sp;
        sp2.feats += alone;
        double* g = partial.data() + sof[begin + e] * stride;
        int ry0 = sp.y0, ry1 = sp.y1;
        span.rows(ry0, ry1);
        for (int y = ry0; y <= ry1; ++y) {
          int cx0 = sp.x0, cx1 = sp.x1;
          if (!span.columns(y, cx0, cx1)) continue;
          const int row_base = (y - tb.y0) * kTile - tb.x0;
          if (first_open) unblend_row<scalar_t, NF>(st, sp, nf, row_base, y, cx0, cx1, int32_t(e), g, g + 6);
          if (second_open) {
            unblend_row<scalar_t, 1>(st2, sp2, 1, row_base, y, cx0, cx1, int32_t(e), g, g + 6 + alone);
          }
        }
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
}
