// EWA projection of 3D Gaussians with its analytic backward (see projection.cpp).
#pragma once

#include <ATen/ATen.h>

#include <vector>

namespace smokeseer {

// (means2d [C,N,2], conics [C,N,3], depths [C,N], radii [C,N], visible [C,N] bool,
//  depths in float64 [C,N]: the front-to-back sort key, free of float32 ties)
std::vector<at::Tensor> project_forward(const at::Tensor& means, const at::Tensor& quats, const at::Tensor& scales,
                                        const at::Tensor& viewmats, const at::Tensor& ks, int64_t width,
                                        int64_t height, double near_plane, double far_plane);

// (d means [N,3], d quats [N,4], d scales [N,3], d viewmats [C,4,4])
std::vector<at::Tensor> project_backward(const at::Tensor& means, const at::Tensor& quats, const at::Tensor& scales,
                                         const at::Tensor& viewmats, const at::Tensor& ks, int64_t width,
                                         int64_t height, double near_plane, double far_plane,
                                         const at::Tensor& g_means2d, const at::Tensor& g_conics,
                                         const at::Tensor& g_depths);

}  // namespace smokeseer
