#include "qdo/runtime/fftw2.hpp"

#include <fftw3.h>

#include <memory>
#include <mutex>
#include <vector>

#include "qdo/runtime/error.hpp"

namespace qdo {
namespace {

std::mutex& planner_mutex() {
  static std::mutex m;
  return m;
}

struct PlanDeleter {
  void operator()(fftw_plan_s* p) const {
    std::lock_guard<std::mutex> lock(planner_mutex());
    fftw_destroy_plan(p);
  }
};

}  // namespace

void fftw2(ComplexStack& s, bool forward, bool scale_inverse) {
  if (s.size() == 0) return;
  std::unique_ptr<fftw_plan_s, PlanDeleter> plan;
  {
    std::lock_guard<std::mutex> lock(planner_mutex());
    const int dims[2] = {static_cast<int>(s.rows), static_cast<int>(s.cols)};
    const int dist = static_cast<int>(s.plane_size());
    auto* p = reinterpret_cast<fftw_complex*>(s.data.data());
    plan.reset(fftw_plan_many_dft(2, dims, static_cast<int>(s.planes), p, nullptr, 1, dist, p, nullptr, 1, dist,
                                  forward ? FFTW_FORWARD : FFTW_BACKWARD, FFTW_ESTIMATE));
  }
  if (!plan) throw Error("FFTW could not plan a " + to_str(s.rows) + " x " + to_str(s.cols) + " transform");
  fftw_execute(plan.get());
  if (!forward && scale_inverse) {
    const double f = 1.0 / double(s.plane_size());
    for (cdouble& v : s.data) v *= f;
  }
}

ComplexStack rfftw2(const RealStack& x) {
  const std::size_t hc = x.cols / 2 + 1;
  ComplexStack out(x.planes, x.rows, hc);
  if (x.size() == 0) return out;
  std::vector<double> in = x.data;  // FFTW takes a non-const input
  std::unique_ptr<fftw_plan_s, PlanDeleter> plan;
  {
    std::lock_guard<std::mutex> lock(planner_mutex());
    const int dims[2] = {static_cast<int>(x.rows), static_cast<int>(x.cols)};
    plan.reset(fftw_plan_many_dft_r2c(2, dims, static_cast<int>(x.planes), in.data(), nullptr, 1, static_cast<int>(x.rows * x.cols),
                                      reinterpret_cast<fftw_complex*>(out.data.data()), nullptr, 1, static_cast<int>(x.rows * hc),
                                      FFTW_ESTIMATE));
  }
  if (!plan) throw Error("FFTW could not plan a real " + to_str(x.rows) + " x " + to_str(x.cols) + " transform");
  fftw_execute(plan.get());
  return out;
}

RealStack irfftw2(ComplexStack& half, std::size_t cols) {
  if (half.cols != cols / 2 + 1) throw Error("irfftw2: a half spectrum of " + to_str(half.cols) + " columns for " + to_str(cols) + " columns");
  RealStack out(half.planes, half.rows, cols);
  if (out.size() == 0) return out;
  std::unique_ptr<fftw_plan_s, PlanDeleter> plan;
  {
    std::lock_guard<std::mutex> lock(planner_mutex());
    const int dims[2] = {static_cast<int>(half.rows), static_cast<int>(cols)};
    plan.reset(fftw_plan_many_dft_c2r(2, dims, static_cast<int>(half.planes), reinterpret_cast<fftw_complex*>(half.data.data()), nullptr, 1,
                                      static_cast<int>(half.rows * half.cols), out.data.data(), nullptr, 1, static_cast<int>(half.rows * cols),
                                      FFTW_ESTIMATE));
  }
  if (!plan) throw Error("FFTW could not plan a real " + to_str(half.rows) + " x " + to_str(cols) + " transform");
  fftw_execute(plan.get());
  const double f = 1.0 / double(half.rows * cols);
  for (double& v : out.data) v *= f;
  return out;
}

}  // namespace qdo
