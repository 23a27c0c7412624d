#include "qdo/runtime/fftw2.hpp"

#include <fftw3.h>

#include <memory>
#include <mutex>

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

}  // namespace qdo
