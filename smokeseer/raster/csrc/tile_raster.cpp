// Tile-based CPU compositing of projected Gaussians with an analytic backward (3DGS semantics).
//
// Inputs are the screen-space quantities the torch projection produces; this file only bins,
// composites and back-propagates. Every pixel is owned by one tile and every tile by one task,
// and per-Gaussian gradients are summed over per-(tile, Gaussian) partials in a fixed order, so
// the bytes of every output depend neither on thread scheduling nor on the thread count.

#include <torch/extension.h>

#include <ATen/Parallel.h>
#include <omp.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
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
  torch::Tensor record_offsets; // [S + 1] int64 start of each record's slots in `entry_of`
  torch::Tensor entry_of;       // [E] int64 position in `entries` of each (record, tile) pair
};

int num_threads() { return std::max(1, at::get_num_threads()); }

template <typename scalar_t>
inline void eval_alpha(scalar_t mx, scalar_t my, scalar_t qa, scalar_t qb, scalar_t qc, scalar_t opac,
                       scalar_t px, scalar_t py, scalar_t& dx, scalar_t& dy, scalar_t& sigma,
                       scalar_t& falloff, scalar_t& alpha) {
  dx = mx - px;
  dy = my - py;
  sigma = scalar_t(0.5) * (qa * dx * dx + qc * dy * dy) + qb * dx * dy;
  falloff = std::exp(-sigma);
  alpha = std::min(opac * falloff, scalar_t(kAlphaMax));
}

// Pixels where alpha can reach 1/255 lie inside the ellipse sigma <= log(255 * opacity). This
// finds, conservatively (a margin in sigma and one pixel on each side), the rows of a rectangle
// that meet that ellipse and each row's column span, so the exact per-pixel test (still applied)
// runs on few pixels it rejects. Culling here only skips pixels that the exact test would skip.
struct EllipseSpans {
  double mx, my, half_a, b, half_c, limit;
  bool shaped;  // false: no usable bound (degenerate conic); every pixel of the rectangle is tested

  template <typename scalar_t>
  EllipseSpans(scalar_t mx_, scalar_t my_, scalar_t qa, scalar_t qb, scalar_t qc, scalar_t opac)
      : mx(mx_), my(my_), half_a(0.5 * double(qa)), b(qb), half_c(0.5 * double(qc)) {
    const double s_max = std::log(255.0 * double(opac));
    limit = s_max + 1e-3 + 1e-4 * std::abs(s_max);
    shaped = half_a > 0.0 && std::isfinite(half_a) && std::isfinite(b) && std::isfinite(half_c) &&
             std::isfinite(limit);
  }

  bool empty() const { return shaped && limit < 0.0; }

  // Narrow the inclusive row range [y0, y1].
  void rows(int& y0, int& y1) const {
    if (!shaped) return;
    const double det = 4.0 * half_a * half_c - b * b;
    if (!(det > 0.0)) return;
    const double reach = std::sqrt(4.0 * limit * half_a / det);
    const double lo = std::ceil(std::max(-1e9, my - reach - 0.5)) - 1.0;
    const double hi = std::floor(std::min(1e9, my + reach - 0.5)) + 1.0;
    y0 = std::max(y0, int(lo));
    y1 = std::min(y1, int(hi));
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

template <typename scalar_t>
Bins bin_gaussians(const torch::Tensor& means2d, const torch::Tensor& conics, const torch::Tensor& opacities,
                   const torch::Tensor& feats, const torch::Tensor& radii, const torch::Tensor& order,
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
  const int64_t* ord = order.data_ptr<int64_t>();
  std::vector<int64_t> packed_src;
  std::vector<int64_t> cam_start(cams + 1, 0), tile_count(cams * tiles, 0);
  std::vector<int64_t> rec_off(1, 0);
  for (int64_t c = 0; c < cams; ++c) {
    for (int64_t k = 0; k < n; ++k) {
      const int64_t cg = c * n + ord[c * n + k];
      const Rect& r = rect_of[cg];
      if (r.x1 < r.x0 || r.y1 < r.y0) continue;
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
  b.entry_of = torch::empty({total}, i64);
  int32_t* ent = b.entries.data_ptr<int32_t>();
  int64_t* eof = b.entry_of.data_ptr<int64_t>();
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
        eof[slot + (tx - tx0)] = pos;
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

template <typename scalar_t>
std::vector<torch::Tensor> forward_impl(const torch::Tensor& means2d, const torch::Tensor& conics,
                                        const torch::Tensor& opacities, const torch::Tensor& feats,
                                        const torch::Tensor& radii, const torch::Tensor& order,
                                        const torch::Tensor& visible, int64_t width, int64_t height) {
  const int64_t cams = means2d.size(0), nf = feats.size(2);
  const int64_t tiles_x = (width + kTile - 1) / kTile, tiles_y = (height + kTile - 1) / kTile;
  const int64_t tiles = tiles_x * tiles_y;
  Bins b = bin_gaussians<scalar_t>(means2d, conics, opacities, feats, radii, order, visible, width, height);
  auto opts = means2d.options();
  torch::Tensor out = torch::empty({cams, height, width, nf}, opts);
  torch::Tensor alpha = torch::empty({cams, height, width}, opts);
  torch::Tensor t_final = torch::empty({cams, height, width}, opts.dtype(torch::kFloat64));
  torch::Tensor last = torch::empty({cams, height, width}, opts.dtype(torch::kInt32));
  torch::Tensor pair_count = torch::zeros({cams * tiles}, opts.dtype(torch::kInt64));

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

#pragma omp parallel num_threads(num_threads())
  {
    std::vector<double> trans(kTilePixels), acc(kTilePixels * nf);
    std::vector<int32_t> stop(kTilePixels);
    std::vector<uint8_t> done(kTilePixels);
#pragma omp for schedule(dynamic, 1)
    for (int64_t ct = 0; ct < cams * tiles; ++ct) {
      const int64_t c = ct / tiles;
      const TileBox tb = tile_box(ct % tiles, tiles_x, width, height);
      int active = (tb.x1 - tb.x0 + 1) * (tb.y1 - tb.y0 + 1);
      std::fill(trans.begin(), trans.end(), 1.0);
      std::fill(acc.begin(), acc.end(), 0.0);
      std::fill(stop.begin(), stop.end(), 0);
      std::fill(done.begin(), done.end(), 0);
      int64_t pairs = 0;
      const int64_t begin = toff[ct], count = toff[ct + 1] - begin;
      for (int64_t e = 0; e < count && active > 0; ++e) {
        const int64_t s = ent[begin + e];
        const Splat<scalar_t> sp(rec + s * stride, rects[s], tb);
        const EllipseSpans span(sp.mx, sp.my, sp.qa, sp.qb, sp.qc, sp.opac);
        if (span.empty()) continue;
        int ry0 = sp.y0, ry1 = sp.y1;
        span.rows(ry0, ry1);
        for (int y = ry0; y <= ry1; ++y) {
          int cx0 = sp.x0, cx1 = sp.x1;
          if (!span.columns(y, cx0, cx1)) continue;
          const scalar_t py = scalar_t(y) + scalar_t(0.5);
          for (int x = cx0; x <= cx1; ++x) {
            const int p = (y - tb.y0) * kTile + (x - tb.x0);
            if (done[p]) continue;
            scalar_t dx, dy, sigma, falloff, a;
            eval_alpha<scalar_t>(sp.mx, sp.my, sp.qa, sp.qb, sp.qc, sp.opac, scalar_t(x) + scalar_t(0.5), py, dx,
                                 dy, sigma, falloff, a);
            if (sigma < scalar_t(0) || a < scalar_t(kAlphaMin)) continue;
            const double t_next = trans[p] * (1.0 - double(a));
            if (t_next < kTransmittanceMin) {
              done[p] = 1;
              --active;
              continue;
            }
            const double w = double(a) * trans[p];
            double* ap = &acc[p * nf];
            for (int64_t k = 0; k < nf; ++k) ap[k] += w * double(sp.feats[k]);
            trans[p] = t_next;
            stop[p] = int32_t(e + 1);
            ++pairs;
          }
        }
      }
      pc_p[ct] = pairs;
      for (int y = tb.y0; y <= tb.y1; ++y) {
        for (int x = tb.x0; x <= tb.x1; ++x) {
          const int p = (y - tb.y0) * kTile + (x - tb.x0);
          const int64_t pix = (c * height + y) * width + x;
          for (int64_t k = 0; k < nf; ++k) out_p[pix * nf + k] = scalar_t(acc[p * nf + k]);
          alpha_p[pix] = scalar_t(1.0 - trans[p]);
          tf_p[pix] = trans[p];
          last_p[pix] = stop[p];
        }
      }
    }
  }
  return {out, alpha, pair_count.sum(), t_final, last, b.records, b.rects, b.source, b.tile_offsets, b.entries,
          b.record_offsets, b.entry_of};
}

template <typename scalar_t>
std::vector<torch::Tensor> backward_impl(int64_t cams, int64_t n, const torch::Tensor& t_final,
                                         const torch::Tensor& last, const torch::Tensor& records,
                                         const torch::Tensor& rects_t, const torch::Tensor& source,
                                         const torch::Tensor& tile_offsets, const torch::Tensor& entries,
                                         const torch::Tensor& record_offsets, const torch::Tensor& entry_of,
                                         const torch::Tensor& grad_out, const torch::Tensor& grad_alpha,
                                         int64_t width, int64_t height) {
  const int64_t stride = records.size(1), nf = stride - 6;
  const int64_t tiles_x = (width + kTile - 1) / kTile, tiles_y = (height + kTile - 1) / kTile;
  const int64_t tiles = tiles_x * tiles_y;
  const int64_t total = entries.size(0), packed = records.size(0);
  // Per-(record, tile) partials: means2d (2), conic (3), opacity (1), features (nf).
  std::vector<double> partial(total * stride);

  const scalar_t* rec = records.data_ptr<scalar_t>();
  const double* tf_p = t_final.data_ptr<double>();
  const int32_t* last_p = last.data_ptr<int32_t>();
  const Rect* rects = reinterpret_cast<const Rect*>(rects_t.data_ptr<int32_t>());
  const int64_t* toff = tile_offsets.data_ptr<int64_t>();
  const int32_t* ent = entries.data_ptr<int32_t>();
  const scalar_t* go_p = grad_out.data_ptr<scalar_t>();
  const scalar_t* ga_p = grad_alpha.data_ptr<scalar_t>();

#pragma omp parallel num_threads(num_threads())
  {
    std::vector<double> trans(kTilePixels), t_end(kTilePixels), g_alpha_out(kTilePixels);
    std::vector<double> behind(kTilePixels * nf), g_out(kTilePixels * nf);
    std::vector<int32_t> stop(kTilePixels);
    std::vector<double> g(stride);
#pragma omp for schedule(dynamic, 1)
    for (int64_t ct = 0; ct < cams * tiles; ++ct) {
      const int64_t c = ct / tiles;
      const TileBox tb = tile_box(ct % tiles, tiles_x, width, height);
      const int64_t begin = toff[ct], count = toff[ct + 1] - begin;
      int32_t max_stop = 0;
      std::fill(behind.begin(), behind.end(), 0.0);
      for (int y = tb.y0; y <= tb.y1; ++y) {
        for (int x = tb.x0; x <= tb.x1; ++x) {
          const int p = (y - tb.y0) * kTile + (x - tb.x0);
          const int64_t pix = (c * height + y) * width + x;
          trans[p] = t_end[p] = tf_p[pix];
          stop[p] = last_p[pix];
          g_alpha_out[p] = double(ga_p[pix]);
          for (int64_t k = 0; k < nf; ++k) g_out[p * nf + k] = double(go_p[pix * nf + k]);
          max_stop = std::max(max_stop, stop[p]);
        }
      }
      std::fill(partial.begin() + (begin + max_stop) * stride, partial.begin() + (begin + count) * stride, 0.0);
      // Back to front: rebuild each pair's transmittance from the final one, as 3DGS does.
      for (int64_t e = max_stop - 1; e >= 0; --e) {
        const int64_t s = ent[begin + e];
        const Splat<scalar_t> sp(rec + s * stride, rects[s], tb);
        std::fill(g.begin(), g.end(), 0.0);
        const EllipseSpans span(sp.mx, sp.my, sp.qa, sp.qb, sp.qc, sp.opac);
        int ry0 = sp.y0, ry1 = span.empty() ? sp.y0 - 1 : sp.y1;
        span.rows(ry0, ry1);
        for (int y = ry0; y <= ry1; ++y) {
          int cx0 = sp.x0, cx1 = sp.x1;
          if (!span.columns(y, cx0, cx1)) continue;
          const scalar_t py = scalar_t(y) + scalar_t(0.5);
          for (int x = cx0; x <= cx1; ++x) {
            const int p = (y - tb.y0) * kTile + (x - tb.x0);
            if (e >= stop[p]) continue;
            scalar_t dx, dy, sigma, falloff, a;
            eval_alpha<scalar_t>(sp.mx, sp.my, sp.qa, sp.qb, sp.qc, sp.opac, scalar_t(x) + scalar_t(0.5), py, dx,
                                 dy, sigma, falloff, a);
            if (sigma < scalar_t(0) || a < scalar_t(kAlphaMin)) continue;
            const double ad = double(a), inv_1ma = 1.0 / (1.0 - ad);
            const double t_i = trans[p] * inv_1ma;
            const double w = ad * t_i;
            double* bp = &behind[p * nf];
            const double* gp = &g_out[p * nf];
            double g_a = g_alpha_out[p] * t_end[p] * inv_1ma;  // alpha output = 1 - T_final
            for (int64_t k = 0; k < nf; ++k) {
              const double fk = double(sp.feats[k]);
              g_a += gp[k] * (t_i * fk - bp[k] * inv_1ma);
              g[6 + k] += w * gp[k];
              bp[k] += w * fk;
            }
            trans[p] = t_i;
            if (sp.opac * falloff <= scalar_t(kAlphaMax)) {  // below the clamp alpha = o * exp(-sigma)
              g[5] += g_a * double(falloff);
              const double g_sigma = -g_a * ad;
              const double ddx = double(dx), ddy = double(dy);
              g[0] += g_sigma * (double(sp.qa) * ddx + double(sp.qb) * ddy);
              g[1] += g_sigma * (double(sp.qb) * ddx + double(sp.qc) * ddy);
              g[2] += g_sigma * 0.5 * ddx * ddx;
              g[3] += g_sigma * ddx * ddy;
              g[4] += g_sigma * 0.5 * ddy * ddy;
            }
          }
        }
        std::copy(g.begin(), g.end(), partial.begin() + (begin + e) * stride);
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
  const int64_t* eof = entry_of.data_ptr<int64_t>();
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
        const double* part = &partial[eof[k] * stride];
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

std::vector<torch::Tensor> forward(const torch::Tensor& means2d, const torch::Tensor& conics,
                                   const torch::Tensor& opacities, const torch::Tensor& feats,
                                   const torch::Tensor& radii, const torch::Tensor& order,
                                   const torch::Tensor& visible, int64_t width, int64_t height) {
  TORCH_CHECK(means2d.device().is_cpu(), "tile rasterizer: tensors must be on the CPU");
  TORCH_CHECK(means2d.dim() == 3 && means2d.size(2) == 2, "tile rasterizer: means2d must be [C, N, 2]");
  const auto c = means2d.size(0), n = means2d.size(1);
  TORCH_CHECK(conics.sizes() == torch::IntArrayRef({c, n, 3}), "tile rasterizer: conics must be [C, N, 3]");
  TORCH_CHECK(opacities.dim() == 1 && opacities.size(0) == n, "tile rasterizer: opacities must be [N]");
  TORCH_CHECK(feats.dim() == 3 && feats.size(0) == c && feats.size(1) == n, "tile rasterizer: feats must be [C, N, F]");
  TORCH_CHECK(radii.sizes() == torch::IntArrayRef({c, n}) && order.sizes() == radii.sizes() &&
                  visible.sizes() == radii.sizes(),
              "tile rasterizer: radii, order and visible must be [C, N]");
  for (const auto* t : {&means2d, &conics, &opacities, &feats, &radii}) {
    TORCH_CHECK(t->is_contiguous() && t->scalar_type() == means2d.scalar_type(),
                "tile rasterizer: float inputs must be contiguous and share one dtype");
  }
  TORCH_CHECK(order.scalar_type() == torch::kInt64 && visible.scalar_type() == torch::kBool,
              "tile rasterizer: order must be int64 and visible bool");
  TORCH_CHECK(width > 0 && height > 0 && width < (1 << 30) && height < (1 << 30), "tile rasterizer: bad image size");
  std::vector<torch::Tensor> result;
  AT_DISPATCH_FLOATING_TYPES(means2d.scalar_type(), "tile_raster_forward", [&] {
    result = forward_impl<scalar_t>(means2d, conics, opacities, feats, radii, order.contiguous(),
                                    visible.contiguous(), width, height);
  });
  return result;
}

std::vector<torch::Tensor> backward(int64_t cams, int64_t n, const torch::Tensor& t_final, const torch::Tensor& last,
                                    const torch::Tensor& records, const torch::Tensor& rects,
                                    const torch::Tensor& source, const torch::Tensor& tile_offsets,
                                    const torch::Tensor& entries, const torch::Tensor& record_offsets,
                                    const torch::Tensor& entry_of, const torch::Tensor& grad_out,
                                    const torch::Tensor& grad_alpha, int64_t width, int64_t height) {
  TORCH_CHECK(records.dim() == 2 && records.size(1) >= 6, "tile rasterizer: records must be [S, 6 + F]");
  std::vector<torch::Tensor> result;
  AT_DISPATCH_FLOATING_TYPES(records.scalar_type(), "tile_raster_backward", [&] {
    result = backward_impl<scalar_t>(cams, n, t_final, last, records, rects, source, tile_offsets, entries,
                                     record_offsets, entry_of, grad_out.to(records.scalar_type()).contiguous(),
                                     grad_alpha.to(records.scalar_type()).contiguous(), width, height);
  });
  return result;
}

}  // namespace

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  m.doc() = "Tile-based CPU Gaussian compositing with an analytic backward (3DGS semantics)";
  m.def("forward", &forward, "Bin and composite projected Gaussians; returns images and saved state");
  m.def("backward", &backward, "Gradients w.r.t. means2d, conics, per-camera opacities and features");
}
