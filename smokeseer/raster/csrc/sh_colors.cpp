// View-dependent colours from real spherical harmonics (degrees 0-3) with their analytic backward.
//
// Same basis, sign convention and normalisation as smokeseer/raster/sh.py (3DGS's), the same +0.5
// offset and clamp at 0 as raster.api.view_colors; evaluated in float64 per (camera, Gaussian) and
// stored in the input dtype. Why compiled: in torch the basis, the product with the coefficients
// and their backward are a dozen full-size temporaries per render (a tenth of a standard Stage-3
// iteration), where the arithmetic is a few dozen operations per Gaussian. Per-Gaussian gradients
// sum the cameras in index order, so results do not depend on the thread count.

#include "sh_colors.h"

#include <ATen/Parallel.h>

#include <algorithm>
#include <cmath>
#include <limits>

namespace smokeseer {
namespace {

const double kPi = 3.14159265358979323846;
const double C0 = 0.5 * std::sqrt(1.0 / kPi);
const double C1 = std::sqrt(3.0 / (4.0 * kPi));
const double C2_XY = 0.5 * std::sqrt(15.0 / kPi);
const double C2_Z = 0.25 * std::sqrt(5.0 / kPi);
const double C2_XX = 0.25 * std::sqrt(15.0 / kPi);
const double C3_A = 0.25 * std::sqrt(35.0 / (2.0 * kPi));
const double C3_B = 0.5 * std::sqrt(105.0 / kPi);
const double C3_C = 0.25 * std::sqrt(21.0 / (2.0 * kPi));
const double C3_D = 0.25 * std::sqrt(7.0 / kPi);
const double C3_E = 0.25 * std::sqrt(105.0 / kPi);
constexpr int kMaxBases = 16;

// The unit direction from the camera to the Gaussian, as sh.sh_basis_along normalises it (the
// length clamped at the square root of the dtype's smallest normal, so a zero direction gives DC only).
struct Direction {
  double u[3], inv;
  bool clamped;  // shorter than the clamp: u = v / constant
};

template <typename scalar_t>
Direction direction(const scalar_t* mean, const scalar_t* cam) {
  Direction d;
  double v[3];
  for (int i = 0; i < 3; ++i) v[i] = double(mean[i]) - double(cam[i]);
  const double norm = std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]);
  const double floor = std::sqrt(double(std::numeric_limits<scalar_t>::min()));
  d.clamped = norm < floor;
  d.inv = 1.0 / std::max(norm, floor);
  for (int i = 0; i < 3; ++i) d.u[i] = v[i] * d.inv;
  return d;
}

// basis[k] for k < (degree + 1)^2, and with `grad` its derivative along each axis of the unit
// direction (the basis as a polynomial in x, y, z).
void basis(int degree, const double* u, double* b, double (*grad)[3]) {
  const double x = u[0], y = u[1], z = u[2];
  const double xx = x * x, yy = y * y, zz = z * z;
  b[0] = C0;
  if (grad) grad[0][0] = grad[0][1] = grad[0][2] = 0.0;
  if (degree >= 1) {
    b[1] = -C1 * y;
    b[2] = C1 * z;
    b[3] = -C1 * x;
    if (grad) {
      const double g[3][3] = {{0, -C1, 0}, {0, 0, C1}, {-C1, 0, 0}};
      for (int k = 0; k < 3; ++k)
        for (int a = 0; a < 3; ++a) grad[1 + k][a] = g[k][a];
    }
  }
  if (degree >= 2) {
    b[4] = C2_XY * x * y;
    b[5] = -C2_XY * y * z;
    b[6] = C2_Z * (2.0 * zz - xx - yy);
    b[7] = -C2_XY * x * z;
    b[8] = C2_XX * (xx - yy);
    if (grad) {
      const double g[5][3] = {{C2_XY * y, C2_XY * x, 0.0},
                              {0.0, -C2_XY * z, -C2_XY * y},
                              {-2.0 * C2_Z * x, -2.0 * C2_Z * y, 4.0 * C2_Z * z},
                              {-C2_XY * z, 0.0, -C2_XY * x},
                              {2.0 * C2_XX * x, -2.0 * C2_XX * y, 0.0}};
      for (int k = 0; k < 5; ++k)
        for (int a = 0; a < 3; ++a) grad[4 + k][a] = g[k][a];
    }
  }
  if (degree >= 3) {
    b[9] = -C3_A * y * (3.0 * xx - yy);
    b[10] = C3_B * x * y * z;
    b[11] = -C3_C * y * (4.0 * zz - xx - yy);
    b[12] = C3_D * z * (2.0 * zz - 3.0 * xx - 3.0 * yy);
    b[13] = -C3_C * x * (4.0 * zz - xx - yy);
    b[14] = C3_E * z * (xx - yy);
    b[15] = -C3_A * x * (xx - 3.0 * yy);
    if (grad) {
      const double g[7][3] = {{-6.0 * C3_A * x * y, -C3_A * (3.0 * xx - 3.0 * yy), 0.0},
                              {C3_B * y * z, C3_B * x * z, C3_B * x * y},
                              {2.0 * C3_C * x * y, -C3_C * (4.0 * zz - xx - 3.0 * yy), -8.0 * C3_C * y * z},
                              {-6.0 * C3_D * x * z, -6.0 * C3_D * y * z, C3_D * (6.0 * zz - 3.0 * xx - 3.0 * yy)},
                              {-C3_C * (4.0 * zz - 3.0 * xx - yy), 2.0 * C3_C * x * y, -8.0 * C3_C * x * z},
                              {2.0 * C3_E * x * z, -2.0 * C3_E * y * z, C3_E * (xx - yy)},
                              {-C3_A * (3.0 * xx - 3.0 * yy), 6.0 * C3_A * x * y, 0.0}};
      for (int k = 0; k < 7; ++k)
        for (int a = 0; a < 3; ++a) grad[9 + k][a] = g[k][a];
    }
  }
}

void check(const at::Tensor& coeffs, const at::Tensor& means, const at::Tensor& campos, int64_t degree) {
  TORCH_CHECK(degree >= 0 && degree <= 3, "sh colours: degree must be in 0..3");
  TORCH_CHECK(coeffs.dim() == 3 && coeffs.size(1) >= (degree + 1) * (degree + 1),
              "sh colours: coeffs must be [N, K >= (degree + 1)^2, D]");
  TORCH_CHECK(means.dim() == 2 && means.size(1) == 3 && means.size(0) == coeffs.size(0),
              "sh colours: means must be [N, 3]");
  TORCH_CHECK(campos.dim() == 2 && campos.size(1) == 3 && campos.size(0) >= 1, "sh colours: campos must be [C >= 1, 3]");
  TORCH_CHECK(coeffs.scalar_type() == means.scalar_type() && campos.scalar_type() == means.scalar_type(),
              "sh colours: one dtype for coeffs, means and campos");
}

}  // namespace

at::Tensor sh_forward(const at::Tensor& coeffs_in, const at::Tensor& means_in, const at::Tensor& campos_in,
                      int64_t degree) {
  check(coeffs_in, means_in, campos_in, degree);
  const at::Tensor coeffs = coeffs_in.contiguous(), means = means_in.contiguous(), campos = campos_in.contiguous();
  const int64_t c_count = campos.size(0), n = means.size(0), kk = coeffs.size(1), dd = coeffs.size(2);
  const int nb = int((degree + 1) * (degree + 1));
  at::Tensor out = at::empty({c_count, n, dd}, coeffs.options());
  AT_DISPATCH_FLOATING_TYPES(coeffs.scalar_type(), "sh_forward", [&] {
    const scalar_t *cf = coeffs.data_ptr<scalar_t>(), *mp = means.data_ptr<scalar_t>(), *cp = campos.data_ptr<scalar_t>();
    scalar_t* op = out.data_ptr<scalar_t>();
    at::parallel_for(0, n, 1024, [&](int64_t lo, int64_t hi) {
      double b[kMaxBases];
      for (int64_t i = lo; i < hi; ++i) {
        for (int64_t c = 0; c < c_count; ++c) {
          const Direction d = direction(mp + 3 * i, cp + 3 * c);
          basis(int(degree), d.u, b, nullptr);
          for (int64_t ch = 0; ch < dd; ++ch) {
            double s = 0.0;
            for (int k = 0; k < nb; ++k) s += b[k] * double(cf[(i * kk + k) * dd + ch]);
            op[(c * n + i) * dd + ch] = scalar_t(std::max(s + 0.5, 0.0));
          }
        }
      }
    });
  });
  return out;
}

std::vector<at::Tensor> sh_backward(const at::Tensor& coeffs_in, const at::Tensor& means_in,
                                    const at::Tensor& campos_in, int64_t degree, const at::Tensor& g_in) {
  check(coeffs_in, means_in, campos_in, degree);
  const at::Tensor coeffs = coeffs_in.contiguous(), means = means_in.contiguous(), campos = campos_in.contiguous();
  const int64_t c_count = campos.size(0), n = means.size(0), kk = coeffs.size(1), dd = coeffs.size(2);
  TORCH_CHECK(g_in.dim() == 3 && g_in.size(0) == c_count && g_in.size(1) == n && g_in.size(2) == dd,
              "sh colours: the colour gradient must be [C, N, D]");
  const at::Tensor g = g_in.to(coeffs.scalar_type()).contiguous();
  const int nb = int((degree + 1) * (degree + 1));
  // Coefficients past the degree's get no gradient; the rest are written for every Gaussian.
  at::Tensor g_coeffs = kk > nb ? at::zeros_like(coeffs) : at::empty_like(coeffs), g_means = at::empty_like(means);
  AT_DISPATCH_FLOATING_TYPES(coeffs.scalar_type(), "sh_backward", [&] {
    const scalar_t *cf = coeffs.data_ptr<scalar_t>(), *mp = means.data_ptr<scalar_t>(), *cp = campos.data_ptr<scalar_t>();
    const scalar_t* gp = g.data_ptr<scalar_t>();
    scalar_t *gcf = g_coeffs.data_ptr<scalar_t>(), *gm = g_means.data_ptr<scalar_t>();
    at::parallel_for(0, n, 1024, [&](int64_t lo, int64_t hi) {
      double b[kMaxBases], db[kMaxBases][3];
      for (int64_t i = lo; i < hi; ++i) {
        double gmean[3] = {0.0, 0.0, 0.0};
        for (int64_t c = 0; c < c_count; ++c) {
          const Direction d = direction(mp + 3 * i, cp + 3 * c);
          basis(int(degree), d.u, b, db);
          double gb[kMaxBases] = {0.0};
          for (int64_t ch = 0; ch < dd; ++ch) {
            double s = 0.0;
            for (int k = 0; k < nb; ++k) s += b[k] * double(cf[(i * kk + k) * dd + ch]);
            // Clamped at 0: no gradient (torch's clamp_min passes it at equality).
            const double gc = s + 0.5 < 0.0 ? 0.0 : double(gp[(c * n + i) * dd + ch]);
            for (int k = 0; k < nb; ++k) {
              scalar_t& out = gcf[(i * kk + k) * dd + ch];
              out = scalar_t((c == 0 ? 0.0 : double(out)) + b[k] * gc);
              gb[k] += double(cf[(i * kk + k) * dd + ch]) * gc;
            }
          }
          // d/d unit direction, then through u = v / max(|v|, eps): (g - u (u . g)) / |v| when not clamped.
          double gu[3] = {0.0, 0.0, 0.0};
          for (int k = 1; k < nb; ++k)
            for (int a = 0; a < 3; ++a) gu[a] += gb[k] * db[k][a];
          const double ug = d.clamped ? 0.0 : d.u[0] * gu[0] + d.u[1] * gu[1] + d.u[2] * gu[2];
          for (int a = 0; a < 3; ++a) gmean[a] += (gu[a] - d.u[a] * ug) * d.inv;
        }
        for (int a = 0; a < 3; ++a) gm[3 * i + a] = scalar_t(gmean[a]);
      }
    });
  });
  return {g_coeffs, g_means};
}

}  // namespace smokeseer
