// View-dependent colours from real spherical harmonics with their analytic backward (see sh_colors.cpp).
#pragma once

#include <ATen/ATen.h>

#include <vector>

namespace smokeseer {

// colours [C,N,D] = max(sum_k basis_k(dir) coeffs[n,k,:] + 0.5, 0), dir = means[n] - campos[c]
at::Tensor sh_forward(const at::Tensor& coeffs, const at::Tensor& means, const at::Tensor& campos, int64_t degree);

// (d coeffs [N,K',D], d means [N,3]) given d colours [C,N,D]
std::vector<at::Tensor> sh_backward(const at::Tensor& coeffs, const at::Tensor& means, const at::Tensor& campos,
                                    int64_t degree, const at::Tensor& g_colors);

}  // namespace smokeseer
