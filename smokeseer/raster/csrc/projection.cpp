// EWA projection of 3D Gaussians (3DGS / gsplat semantics) with its analytic backward.
//
// Same maths as smokeseer/raster/projection.py, evaluated per (camera, Gaussian) in float64 and
// stored in the input dtype. The backward recomputes the forward intermediates. Per-Gaussian
// gradients sum the cameras in index order; view-matrix gradients sum fixed blocks of Gaussians
// in block order, so results do not depend on the thread count.

#include "projection.h"

#include <ATen/Parallel.h>

#include <algorithm>
#include <cmath>
#include <vector>

namespace smokeseer {
namespace {

constexpr double kEps2d = 0.3;        // low-pass dilation of the 2D covariance, px^2
constexpr double kSigmaExtent = 3.0;  // footprint half-width in standard deviations
constexpr int64_t kBlock = 1024;      // Gaussians per view-matrix gradient block

struct Camera {
  double r[3][3], t[3], fx, fy, cx, cy, u_lo, u_hi, v_lo, v_hi;
};

template <typename scalar_t>
Camera load_camera(const scalar_t* vm, const scalar_t* k, int64_t width, int64_t height) {
  Camera cam;
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) cam.r[i][j] = double(vm[4 * i + j]);
    cam.t[i] = double(vm[4 * i + 3]);
  }
  cam.fx = double(k[0]);
  cam.fy = double(k[4]);
  cam.cx = double(k[2]);
  cam.cy = double(k[5]);
  const double tan_x = 0.5 * double(width) / cam.fx, tan_y = 0.5 * double(height) / cam.fy;
  cam.u_lo = -(cam.cx / cam.fx + 0.3 * tan_x);
  cam.u_hi = (double(width) - cam.cx) / cam.fx + 0.3 * tan_x;
  cam.v_lo = -(cam.cy / cam.fy + 0.3 * tan_y);
  cam.v_hi = (double(height) - cam.cy) / cam.fy + 0.3 * tan_y;
  return cam;
}

// Everything the forward computes for one (camera, Gaussian), kept for the backward.
struct Projected {
  double m[3], p[3], qn[4], qnorm, rq[3][3], rs[3][3], mm[3][3];
  double u, v, u_lim, v_lim, inv_z, a_rows[2][3], a0[3], a1[3], cov_a, cov_b, cov_c, cross[3], det;
  double conic[3], mean2d[2], radius;
  bool u_free, v_free, in_depth, visible;
};

template <typename scalar_t>
void project_one(const Camera& cam, const scalar_t* mean, const scalar_t* quat, const scalar_t* scale,
                 double near_plane, double far_plane, int64_t width, int64_t height, Projected& o) {
  for (int i = 0; i < 3; ++i) o.m[i] = double(mean[i]);
  for (int i = 0; i < 3; ++i) {
    o.p[i] = cam.r[i][0] * o.m[0] + cam.r[i][1] * o.m[1] + cam.r[i][2] * o.m[2] + cam.t[i];
  }
  const double z = o.p[2];
  o.in_depth = z >= near_plane && z <= far_plane;
  const double zs = o.in_depth ? z : 1.0;
  o.inv_z = 1.0 / zs;
  o.u = o.p[0] / zs;
  o.v = o.p[1] / zs;
  o.u_lim = std::min(std::max(o.u, cam.u_lo), cam.u_hi);
  o.v_lim = std::min(std::max(o.v, cam.v_lo), cam.v_hi);
  o.u_free = o.u > cam.u_lo && o.u < cam.u_hi;
  o.v_free = o.v > cam.v_lo && o.v < cam.v_hi;

  double q[4];
  for (int i = 0; i < 4; ++i) q[i] = double(quat[i]);
  o.qnorm = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
  for (int i = 0; i < 4; ++i) o.qn[i] = q[i] / o.qnorm;
  const double w = o.qn[0], x = o.qn[1], y = o.qn[2], zq = o.qn[3];
  const double rq[3][3] = {{1 - 2 * (y * y + zq * zq), 2 * (x * y - w * zq), 2 * (x * zq + w * y)},
                           {2 * (x * y + w * zq), 1 - 2 * (x * x + zq * zq), 2 * (y * zq - w * x)},
                           {2 * (x * zq - w * y), 2 * (y * zq + w * x), 1 - 2 * (x * x + y * y)}};
  for (int i = 0; i < 3; ++i) {
    for (int k = 0; k < 3; ++k) {
      o.rq[i][k] = rq[i][k];
      o.rs[i][k] = rq[i][k] * double(scale[k]);
    }
  }
  for (int i = 0; i < 3; ++i) {
    for (int k = 0; k < 3; ++k) {
      o.mm[i][k] = cam.r[i][0] * o.rs[0][k] + cam.r[i][1] * o.rs[1][k] + cam.r[i][2] * o.rs[2][k];
    }
  }
  for (int k = 0; k < 3; ++k) {
    o.a_rows[0][k] = o.mm[0][k] - o.u_lim * o.mm[2][k];
    o.a_rows[1][k] = o.mm[1][k] - o.v_lim * o.mm[2][k];
    o.a0[k] = cam.fx * o.inv_z * o.a_rows[0][k];
    o.a1[k] = cam.fy * o.inv_z * o.a_rows[1][k];
  }
  o.cov_a = o.a0[0] * o.a0[0] + o.a0[1] * o.a0[1] + o.a0[2] * o.a0[2];
  o.cov_b = o.a0[0] * o.a1[0] + o.a0[1] * o.a1[1] + o.a0[2] * o.a1[2];
  o.cov_c = o.a1[0] * o.a1[0] + o.a1[1] * o.a1[1] + o.a1[2] * o.a1[2];
  o.cross[0] = o.a0[1] * o.a1[2] - o.a0[2] * o.a1[1];
  o.cross[1] = o.a0[2] * o.a1[0] - o.a0[0] * o.a1[2];
  o.cross[2] = o.a0[0] * o.a1[1] - o.a0[1] * o.a1[0];
  const double det0 = o.cross[0] * o.cross[0] + o.cross[1] * o.cross[1] + o.cross[2] * o.cross[2];
  o.det = det0 + kEps2d * (o.cov_a + o.cov_c) + kEps2d * kEps2d;
  o.conic[0] = (o.cov_c + kEps2d) / o.det;
  o.conic[1] = -o.cov_b / o.det;
  o.conic[2] = (o.cov_a + kEps2d) / o.det;
  const double half_diff = 0.5 * (o.cov_a - o.cov_c);
  const double lam_max = 0.5 * (o.cov_a + o.cov_c) + kEps2d +
                         std::sqrt(std::max(half_diff * half_diff + o.cov_b * o.cov_b, 0.01));
  o.radius = std::ceil(kSigmaExtent * std::sqrt(lam_max));
  o.mean2d[0] = cam.fx * o.u + cam.cx;
  o.mean2d[1] = cam.fy * o.v + cam.cy;
  const bool on_screen = o.mean2d[0] + o.radius > 0 && o.mean2d[0] - o.radius < double(width) &&
                         o.mean2d[1] + o.radius > 0 && o.mean2d[1] - o.radius < double(height);
  o.visible = o.in_depth && on_screen && std::isfinite(o.radius) && std::isfinite(o.det) &&
              std::isfinite(o.conic[0]) && std::isfinite(o.conic[1]) && std::isfinite(o.conic[2]);
}

// True when x survives the cast to the output dtype (float32 outputs must not overflow to inf).
template <typename scalar_t>
bool representable(double x) {
  return std::isfinite(x) && std::isfinite(scalar_t(x));
}

template <typename scalar_t>
std::vector<at::Tensor> forward_impl(const at::Tensor& means, const at::Tensor& quats, const at::Tensor& scales,
                                     const at::Tensor& viewmats, const at::Tensor& ks, int64_t width, int64_t height,
                                     double near_plane, double far_plane) {
  const int64_t n = means.size(0), cams = viewmats.size(0);
  auto opts = means.options();
  at::Tensor means2d = at::empty({cams, n, 2}, opts);
  at::Tensor conics = at::empty({cams, n, 3}, opts);
  at::Tensor depths = at::empty({cams, n}, opts);
  at::Tensor radii = at::empty({cams, n}, opts);
  at::Tensor visible = at::empty({cams, n}, opts.dtype(at::kBool));
  at::Tensor sort_depths = at::empty({cams, n}, opts.dtype(at::kDouble));
  const scalar_t* mp = means.data_ptr<scalar_t>();
  const scalar_t* qp = quats.data_ptr<scalar_t>();
  const scalar_t* sp = scales.data_ptr<scalar_t>();
  std::vector<Camera> cameras;
  for (int64_t c = 0; c < cams; ++c) {
    cameras.push_back(load_camera(viewmats.data_ptr<scalar_t>() + 16 * c, ks.data_ptr<scalar_t>() + 9 * c, width,
                                  height));
  }
  scalar_t* m2 = means2d.data_ptr<scalar_t>();
  scalar_t* cn = conics.data_ptr<scalar_t>();
  scalar_t* dp = depths.data_ptr<scalar_t>();
  scalar_t* rp = radii.data_ptr<scalar_t>();
  bool* vp = visible.data_ptr<bool>();
  double* sdp = sort_depths.data_ptr<double>();
  at::parallel_for(0, n, 512, [&](int64_t lo, int64_t hi) {
    Projected o;
    for (int64_t c = 0; c < cams; ++c) {
      for (int64_t g = lo; g < hi; ++g) {
        project_one(cameras[c], mp + 3 * g, qp + 4 * g, sp + 3 * g, near_plane, far_plane, width, height, o);
        const int64_t i = c * n + g;
        const bool vis = o.visible && representable<scalar_t>(o.radius) &&
                         representable<scalar_t>(o.mean2d[0]) && representable<scalar_t>(o.mean2d[1]);
        m2[2 * i] = vis ? scalar_t(o.mean2d[0]) : scalar_t(0);
        m2[2 * i + 1] = vis ? scalar_t(o.mean2d[1]) : scalar_t(0);
        for (int k = 0; k < 3; ++k) cn[3 * i + k] = vis ? scalar_t(o.conic[k]) : scalar_t(0);
        dp[i] = scalar_t(o.p[2]);
        sdp[i] = o.p[2];
        rp[i] = vis ? scalar_t(o.radius) : scalar_t(0);
        vp[i] = vis;
      }
    }
  });
  return {means2d, conics, depths, radii, visible, sort_depths};
}

template <typename scalar_t>
std::vector<at::Tensor> backward_impl(const at::Tensor& means, const at::Tensor& quats, const at::Tensor& scales,
                                      const at::Tensor& viewmats, const at::Tensor& ks, int64_t width, int64_t height,
                                      double near_plane, double far_plane, const at::Tensor& g_means2d,
                                      const at::Tensor& g_conics, const at::Tensor& g_depths) {
  const int64_t n = means.size(0), cams = viewmats.size(0);
  const int64_t blocks = (n + kBlock - 1) / kBlock;
  auto opts = means.options();
  at::Tensor g_means = at::zeros({n, 3}, opts);
  at::Tensor g_quats = at::zeros({n, 4}, opts);
  at::Tensor g_scales = at::zeros({n, 3}, opts);
  std::vector<double> g_view_blocks(blocks * cams * 12, 0.0);  // per block: [C][R (9), t (3)]
  const scalar_t* mp = means.data_ptr<scalar_t>();
  const scalar_t* qp = quats.data_ptr<scalar_t>();
  const scalar_t* sp = scales.data_ptr<scalar_t>();
  const scalar_t* gm2 = g_means2d.data_ptr<scalar_t>();
  const scalar_t* gcn = g_conics.data_ptr<scalar_t>();
  const scalar_t* gdp = g_depths.data_ptr<scalar_t>();
  std::vector<Camera> cameras;
  for (int64_t c = 0; c < cams; ++c) {
    cameras.push_back(load_camera(viewmats.data_ptr<scalar_t>() + 16 * c, ks.data_ptr<scalar_t>() + 9 * c, width,
                                  height));
  }
  scalar_t* out_m = g_means.data_ptr<scalar_t>();
  scalar_t* out_q = g_quats.data_ptr<scalar_t>();
  scalar_t* out_s = g_scales.data_ptr<scalar_t>();

  at::parallel_for(0, blocks, 1, [&](int64_t block_lo, int64_t block_hi) {
    Projected o;
    for (int64_t block = block_lo; block < block_hi; ++block) {
      for (int64_t g = block * kBlock; g < std::min(n, (block + 1) * kBlock); ++g) {
        double acc_m[3] = {0, 0, 0}, acc_q[4] = {0, 0, 0, 0}, acc_s[3] = {0, 0, 0};
        for (int64_t c = 0; c < cams; ++c) {
          const Camera& cam = cameras[c];
          const int64_t i = c * n + g;
          project_one(cam, mp + 3 * g, qp + 4 * g, sp + 3 * g, near_plane, far_plane, width, height, o);
          o.visible = o.visible && representable<scalar_t>(o.radius) && representable<scalar_t>(o.mean2d[0]) &&
                      representable<scalar_t>(o.mean2d[1]);
          double g_p[3] = {0.0, 0.0, double(gdp[i])};  // depth output is the view z of every Gaussian
          double g_mm[3][3] = {};
          if (o.visible) {
            const double zs = o.p[2];
            double g_u = cam.fx * double(gm2[2 * i]), g_v = cam.fy * double(gm2[2 * i + 1]);
            const double gc_a = double(gcn[3 * i]), gc_b = double(gcn[3 * i + 1]), gc_c = double(gcn[3 * i + 2]);
            const double g_det = -(gc_a * o.conic[0] + gc_b * o.conic[1] + gc_c * o.conic[2]) / o.det;
            const double g_cov_a = gc_c / o.det + kEps2d * g_det;
            const double g_cov_c = gc_a / o.det + kEps2d * g_det;
            const double g_cov_b = -gc_b / o.det;
            // d|a0 x a1|^2 = 2 (a1 x cr) . da0 + 2 (cr x a0) . da1
            const double* cr = o.cross;
            const double a1xcr[3] = {o.a1[1] * cr[2] - o.a1[2] * cr[1], o.a1[2] * cr[0] - o.a1[0] * cr[2],
                                     o.a1[0] * cr[1] - o.a1[1] * cr[0]};
            const double crxa0[3] = {cr[1] * o.a0[2] - cr[2] * o.a0[1], cr[2] * o.a0[0] - cr[0] * o.a0[2],
                                     cr[0] * o.a0[1] - cr[1] * o.a0[0]};
            double g_a0[3], g_a1[3];
            for (int k = 0; k < 3; ++k) {
              g_a0[k] = 2 * g_cov_a * o.a0[k] + g_cov_b * o.a1[k] + 2 * g_det * a1xcr[k];
              g_a1[k] = 2 * g_cov_c * o.a1[k] + g_cov_b * o.a0[k] + 2 * g_det * crxa0[k];
            }
            double g_inv_z = 0.0, g_u_lim = 0.0, g_v_lim = 0.0;
            for (int k = 0; k < 3; ++k) {
              g_inv_z += cam.fx * g_a0[k] * o.a_rows[0][k] + cam.fy * g_a1[k] * o.a_rows[1][k];
              const double g_row0 = cam.fx * o.inv_z * g_a0[k], g_row1 = cam.fy * o.inv_z * g_a1[k];
              g_mm[0][k] += g_row0;
              g_mm[1][k] += g_row1;
              g_mm[2][k] += -o.u_lim * g_row0 - o.v_lim * g_row1;
              g_u_lim -= g_row0 * o.mm[2][k];
              g_v_lim -= g_row1 * o.mm[2][k];
            }
            if (o.u_free) g_u += g_u_lim;
            if (o.v_free) g_v += g_v_lim;
            g_p[0] += g_u / zs;
            g_p[1] += g_v / zs;
            g_p[2] += -(g_u * o.u + g_v * o.v) / zs - g_inv_z / (zs * zs);
          }
          double* g_view = g_view_blocks.data() + (block * cams + c) * 12;
          for (int r = 0; r < 3; ++r) {
            for (int j = 0; j < 3; ++j) {
              acc_m[j] += cam.r[r][j] * g_p[r];
              g_view[3 * r + j] += g_p[r] * o.m[j];
            }
            g_view[9 + r] += g_p[r];
          }
          if (!o.visible) continue;
          // M = R RS: dR += dM RS^T, dRS = R^T dM; RS = Rq diag(s).
          double g_rq[3][3];
          for (int r = 0; r < 3; ++r) {
            for (int j = 0; j < 3; ++j) {
              double s = 0.0;
              for (int k = 0; k < 3; ++k) s += g_mm[r][k] * o.rs[j][k];
              g_view[3 * r + j] += s;
            }
          }
          for (int j = 0; j < 3; ++j) {
            for (int k = 0; k < 3; ++k) {
              double g_rs = 0.0;
              for (int r = 0; r < 3; ++r) g_rs += cam.r[r][j] * g_mm[r][k];
              acc_s[k] += g_rs * o.rq[j][k];
              g_rq[j][k] = g_rs * double(sp[3 * g + k]);
            }
          }
          const double w = o.qn[0], x = o.qn[1], y = o.qn[2], z = o.qn[3];
          const double(&G)[3][3] = g_rq;
          const double g_qn[4] = {
              2 * (-z * G[0][1] + y * G[0][2] + z * G[1][0] - x * G[1][2] - y * G[2][0] + x * G[2][1]),
              2 * (y * G[0][1] + z * G[0][2] + y * G[1][0] - 2 * x * G[1][1] - w * G[1][2] + z * G[2][0] +
                   w * G[2][1] - 2 * x * G[2][2]),
              2 * (-2 * y * G[0][0] + x * G[0][1] + w * G[0][2] + x * G[1][0] + z * G[1][2] - w * G[2][0] +
                   z * G[2][1] - 2 * y * G[2][2]),
              2 * (-2 * z * G[0][0] - w * G[0][1] + x * G[0][2] + w * G[1][0] - 2 * z * G[1][1] + y * G[1][2] +
                   x * G[2][0] + y * G[2][1])};
          const double dot = o.qn[0] * g_qn[0] + o.qn[1] * g_qn[1] + o.qn[2] * g_qn[2] + o.qn[3] * g_qn[3];
          for (int k = 0; k < 4; ++k) acc_q[k] += (g_qn[k] - o.qn[k] * dot) / o.qnorm;
        }
        for (int k = 0; k < 3; ++k) out_m[3 * g + k] = scalar_t(acc_m[k]);
        for (int k = 0; k < 4; ++k) out_q[4 * g + k] = scalar_t(acc_q[k]);
        for (int k = 0; k < 3; ++k) out_s[3 * g + k] = scalar_t(acc_s[k]);
      }
    }
  });
  at::Tensor g_viewmats = at::zeros({cams, 4, 4}, viewmats.options());
  scalar_t* gv = g_viewmats.data_ptr<scalar_t>();
  for (int64_t c = 0; c < cams; ++c) {
    double sum[12] = {};
    for (int64_t block = 0; block < blocks; ++block) {
      for (int j = 0; j < 12; ++j) sum[j] += g_view_blocks[(block * cams + c) * 12 + j];
    }
    for (int r = 0; r < 3; ++r) {
      for (int j = 0; j < 3; ++j) gv[16 * c + 4 * r + j] = scalar_t(sum[3 * r + j]);
      gv[16 * c + 4 * r + 3] = scalar_t(sum[9 + r]);
    }
  }
  return {g_means, g_quats, g_scales, g_viewmats};
}

void check(const at::Tensor& means, const at::Tensor& quats, const at::Tensor& scales, const at::Tensor& viewmats,
           const at::Tensor& ks) {
  const int64_t n = means.size(0), c = viewmats.size(0);
  TORCH_CHECK(means.dim() == 2 && means.size(1) == 3 && quats.sizes() == at::IntArrayRef({n, 4}) &&
                  scales.sizes() == at::IntArrayRef({n, 3}),
              "projection: means [N, 3], quats [N, 4] and scales [N, 3] expected");
  TORCH_CHECK(viewmats.sizes() == at::IntArrayRef({c, 4, 4}) && ks.sizes() == at::IntArrayRef({c, 3, 3}),
              "projection: viewmats [C, 4, 4] and Ks [C, 3, 3] expected");
  for (const auto* t : {&means, &quats, &scales, &viewmats, &ks}) {
    TORCH_CHECK(t->device().is_cpu() && t->is_contiguous() && t->scalar_type() == means.scalar_type(),
                "projection: CPU tensors, contiguous, one floating dtype expected");
  }
}

}  // namespace

std::vector<at::Tensor> project_forward(const at::Tensor& means, const at::Tensor& quats, const at::Tensor& scales,
                                        const at::Tensor& viewmats, const at::Tensor& ks, int64_t width,
                                        int64_t height, double near_plane, double far_plane) {
  check(means, quats, scales, viewmats, ks);
  std::vector<at::Tensor> result;
  AT_DISPATCH_FLOATING_TYPES(means.scalar_type(), "project_forward", [&] {
    result = forward_impl<scalar_t>(means, quats, scales, viewmats, ks, width, height, near_plane, far_plane);
  });
  return result;
}

std::vector<at::Tensor> project_backward(const at::Tensor& means, const at::Tensor& quats, const at::Tensor& scales,
                                         const at::Tensor& viewmats, const at::Tensor& ks, int64_t width,
                                         int64_t height, double near_plane, double far_plane,
                                         const at::Tensor& g_means2d, const at::Tensor& g_conics,
                                         const at::Tensor& g_depths) {
  check(means, quats, scales, viewmats, ks);
  std::vector<at::Tensor> result;
  AT_DISPATCH_FLOATING_TYPES(means.scalar_type(), "project_backward", [&] {
    result = backward_impl<scalar_t>(means, quats, scales, viewmats, ks, width, height, near_plane, far_plane,
                                     g_means2d.to(means.scalar_type()).contiguous(),
                                     g_conics.to(means.scalar_type()).contiguous(),
                                     g_depths.to(means.scalar_type()).contiguous());
  });
  return result;
}

}  // namespace smokeseer
