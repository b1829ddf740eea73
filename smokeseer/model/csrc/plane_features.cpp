// Products of bilinear plane lookups for the factorised space-time deformation field
// (smokeseer/model/planes.py): out[n, f] = prod_p bilinear(planes[p], coords[n, p])[f] over three
// planes, and the planes' gradient. One pass per point, features contiguous (planes [3, H, W, F]),
// no per-plane intermediate tensors: torch's grid_sample spends most of the field's time in its
// backward scatter (docs/experiments/2026-12-05-planes-deformation.md).
//
// Coordinates follow grid_sample(align_corners=True, padding_mode="border"): x along W and y
// along H, -1 and 1 on the centres of the outer cells, clamped to them outside (NaN reads cell 0).
#include <torch/extension.h>

#include <algorithm>
#include <cmath>
#include <vector>

#ifdef _OPENMP
#include <omp.h>
#endif

namespace {

template <typename T>
struct Tap {
  int64_t at;  // offset of the lower-left cell's first feature
  T w00, w01, w10, w11;
};

template <typename T>
inline T clamp_cell(T c, int64_t n) {
  // fmax/fmin return the other operand for NaN, so a NaN coordinate reads cell 0.
  return std::fmin(std::fmax((c + T(1)) * T(0.5) * static_cast<T>(n - 1), T(0)), static_cast<T>(n - 1));
}

template <typename T>
inline Tap<T> tap(const T* xy, int64_t H, int64_t W, int64_t F) {
  const T u = clamp_cell(xy[0], W), v = clamp_cell(xy[1], H);
  const int64_t u0 = std::min<int64_t>(static_cast<int64_t>(u), W - 2);
  const int64_t v0 = std::min<int64_t>(static_cast<int64_t>(v), H - 2);
  const T fx = u - static_cast<T>(u0), fy = v - static_cast<T>(v0);
  return {(v0 * W + u0) * F, (1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy};
}

template <typename T>
inline void lookup(const T* plane, const Tap<T>& t, int64_t W, int64_t F, T* out) {
  const T* a = plane + t.at;
  const T* b = a + W * F;
  for (int64_t f = 0; f < F; ++f) out[f] = t.w00 * a[f] + t.w01 * a[f + F] + t.w10 * b[f] + t.w11 * b[f + F];
}

void check(const torch::Tensor& planes, const torch::Tensor& coords) {
  TORCH_CHECK(planes.device().is_cpu() && coords.device().is_cpu(), "plane_features: CPU tensors only");
  TORCH_CHECK((planes.scalar_type() == torch::kFloat32 || planes.scalar_type() == torch::kFloat64) &&
                  coords.scalar_type() == planes.scalar_type(),
              "plane_features: float32 or float64 tensors, both of one type");
  TORCH_CHECK(planes.dim() == 4 && planes.size(0) == 3 && planes.size(1) >= 2 && planes.size(2) >= 2,
              "plane_features: planes must be [3, H >= 2, W >= 2, F]");
  TORCH_CHECK(coords.dim() == 3 && coords.size(1) == 3 && coords.size(2) == 2, "plane_features: coords must be [N, 3, 2]");
  TORCH_CHECK(planes.is_contiguous() && coords.is_contiguous(), "plane_features: contiguous tensors only");
}

}  // namespace

template <typename T>
void forward_impl(const T* P, const T* C, T* O, int64_t N, int64_t H, int64_t W, int64_t F) {
  const int64_t stride = H * W * F;
#pragma omp parallel
  {
    std::vector<T> v(F);
#pragma omp for schedule(static)
    for (int64_t n = 0; n < N; ++n) {
      T* o = O + n * F;
      lookup(P, tap(C + n * 6, H, W, F), W, F, o);
      for (int p = 1; p < 3; ++p) {
        lookup(P + p * stride, tap(C + n * 6 + 2 * p, H, W, F), W, F, v.data());
        for (int64_t f = 0; f < F; ++f) o[f] *= v[f];
      }
    }
  }
}

template <typename T>
void backward_impl(const T* G, const T* P, const T* C, T* GP, int threads, int64_t N, int64_t H, int64_t W,
                   int64_t F) {
  const int64_t stride = H * W * F;
#pragma omp parallel num_threads(threads)
  {
    int me = 0;
#ifdef _OPENMP
    me = omp_get_thread_num();
#endif
    T* mine = GP + static_cast<int64_t>(me) * 3 * stride;
    std::vector<T> v(3 * F), g(F);
    Tap<T> t[3];
#pragma omp for schedule(static)
    for (int64_t n = 0; n < N; ++n) {
      for (int p = 0; p < 3; ++p) {
        t[p] = tap(C + n * 6 + 2 * p, H, W, F);
        lookup(P + p * stride, t[p], W, F, v.data() + p * F);
      }
      const T* go = G + n * F;
      for (int p = 0; p < 3; ++p) {
        const T* va = v.data() + ((p + 1) % 3) * F;
        const T* vb = v.data() + ((p + 2) % 3) * F;
        for (int64_t f = 0; f < F; ++f) g[f] = go[f] * va[f] * vb[f];
        T* a = mine + p * stride + t[p].at;
        T* b = a + W * F;
        const Tap<T>& w = t[p];
        for (int64_t f = 0; f < F; ++f) {
          a[f] += w.w00 * g[f];
          a[f + F] += w.w01 * g[f];
          b[f] += w.w10 * g[f];
          b[f + F] += w.w11 * g[f];
        }
      }
    }
  }
}

torch::Tensor plane_product_forward(const torch::Tensor& planes, const torch::Tensor& coords) {
  check(planes, coords);
  const int64_t H = planes.size(1), W = planes.size(2), F = planes.size(3), N = coords.size(0);
  auto out = torch::empty({N, F}, planes.options());
  AT_DISPATCH_FLOATING_TYPES(planes.scalar_type(), "plane_product_forward", [&] {
    forward_impl<scalar_t>(planes.data_ptr<scalar_t>(), coords.data_ptr<scalar_t>(), out.data_ptr<scalar_t>(), N, H,
                           W, F);
  });
  return out;
}

torch::Tensor plane_product_backward(const torch::Tensor& grad_out, const torch::Tensor& planes,
                                     const torch::Tensor& coords) {
  check(planes, coords);
  TORCH_CHECK(grad_out.scalar_type() == planes.scalar_type() && grad_out.is_contiguous() && grad_out.dim() == 2 &&
                  grad_out.size(0) == coords.size(0) && grad_out.size(1) == planes.size(3),
              "plane_features: grad_out must be contiguous [N, F] of the planes' type");
  const int64_t H = planes.size(1), W = planes.size(2), F = planes.size(3), N = coords.size(0);
  int threads = 1;
#ifdef _OPENMP
  threads = std::max(1, std::min<int>(omp_get_max_threads(), static_cast<int>((N + 4095) / 4096)));
#endif
  // One gradient buffer per thread, summed in thread order: the same bytes for the same thread count.
  auto grads = torch::zeros({threads, 3, H, W, F}, planes.options());
  AT_DISPATCH_FLOATING_TYPES(planes.scalar_type(), "plane_product_backward", [&] {
    backward_impl<scalar_t>(grad_out.data_ptr<scalar_t>(), planes.data_ptr<scalar_t>(), coords.data_ptr<scalar_t>(),
                            grads.data_ptr<scalar_t>(), threads, N, H, W, F);
  });
  return threads == 1 ? grads[0] : grads.sum(0);
}

PYBIND11_MODULE(TORCH_EXTENSION_NAME, m) {
  m.def("plane_product_forward", &plane_product_forward, "product of three bilinear plane lookups");
  m.def("plane_product_backward", &plane_product_backward, "its gradient with respect to the planes");
}
