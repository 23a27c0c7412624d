// DoeStage (include/qdo/physics/doe.hpp): the launcher of kernels/doe.cl. The host versions of the same
// maps are in doe_reference.cpp.
#include <cmath>

#include "physics/device_buffers.hpp"
#include "qdo/physics/doe.hpp"
#include "qdo/runtime/error.hpp"

namespace qdo {

DoeStage::DoeStage(Runtime& rt, const SystemConfig& cfg, Precision p) : rt_(rt), cfg_(cfg), prec_(p) {
  k_expand_ = rt_.kernel("doe.cl", "expand_params", p);
  k_quantize_ = rt_.kernel("doe.cl", "quantize_blend", p);
}

void DoeStage::write(const cl::Buffer& heights, const std::vector<Map2D>& maps) {
  std::vector<double> all;
  all.reserve(maps.size() * cfg_.n * cfg_.n);
  for (const Map2D& height_m : maps) {
    if (height_m.rows != cfg_.n || height_m.cols != cfg_.n)
      reject("height_m", to_str(height_m.rows) + " x " + to_str(height_m.cols), "a square N x N map with N = " + to_str(cfg_.n));
    const double hmax = cfg_.h_max_m();
    for (std::size_t i = 0; i < height_m.data.size(); ++i) {
      const double h = height_m.data[i];
      if (!std::isfinite(h) || h < 0 || h > 2 * hmax)
        reject("height_m[" + to_str(i / cfg_.n) + "][" + to_str(i % cfg_.n) + "]", h,
               "finite heights in [0, 2 h_max] = [0, " + to_str(2 * hmax) + "] m");
    }
    all.insert(all.end(), height_m.data.begin(), height_m.data.end());
  }
  if (prec_ == Precision::F64) {
    rt_.queue().enqueueWriteBuffer(heights, CL_TRUE, 0, all.size() * 8, all.data());
  } else {
    const std::vector<float> f(all.begin(), all.end());
    rt_.queue().enqueueWriteBuffer(heights, CL_TRUE, 0, f.size() * 4, f.data());
  }
}

void DoeStage::expand(const cl::Buffer& heights, Parameterization kind, const std::vector<double>& params,
                      const Quantizer* q, double alpha) {
  const std::size_t n = cfg_.n;
  if (params.size() != parameter_count(kind, n))
    reject("params.size()", params.size(), "exactly " + to_str(parameter_count(kind, n)) + " for this parameterization and N");
  for (std::size_t i = 0; i < params.size(); ++i)
    if (!std::isfinite(params[i])) reject("params[" + to_str(i) + "]", params[i], "finite heights in metres");
  if (q) {
    q->validate();
    if (!(alpha >= 0 && alpha <= 1)) reject("alpha", alpha, "within [0, 1]");
  }
  const double hmax = cfg_.h_max_m();
  const cl::Buffer pbuf = detail::upload_real(rt_, params, prec_);
  const int kind_code = kind == Parameterization::Full2D ? 0 : kind == Parameterization::Radial ? 1 : 2;
  rt_.launch_1d(k_expand_, n * n, prec_, pbuf, heights, int(n), kind_code, Real{hmax});
  if (q) {
    std::vector<double> table;
    for (int l = 0; l < q->levels; ++l) table.push_back(q->level_value(l));
    const cl::Buffer obuf = detail::upload_real(rt_, table, prec_);
    rt_.launch_1d(k_quantize_, n * n, prec_, heights, int(n * n), Real{hmax}, int(q->levels),
                  int(q->placement == Placement::Inclusive ? 0 : 1), obuf, Real{alpha});
  }
  rt_.queue().finish();  // pbuf and obuf are released when this function returns
}

}  // namespace qdo
