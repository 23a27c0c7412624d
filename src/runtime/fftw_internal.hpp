// FFTW helpers shared by the FFTW backend (fft_fftw.cpp) and the fused host propagation of CPU
// devices (propagate_fftw.cpp): float/double traits, the planner lock, and the wisdom file kept
// beside the kernel cache. Private to src/runtime.
#pragma once
#include <fftw3.h>

#include <filesystem>
#include <mutex>
#include <string>

namespace qdo::fftw_detail {

// FFTW's planner and wisdom are process-global and not thread-safe: every plan creation and
// destruction holds this lock (execution does not need it).
std::mutex& planner_mutex();
// fftw(f)_init_threads, once per process (call with the planner lock held).
void init_threads_once();

// float / double through one interface.
template <typename R>
struct Fftw;
template <>
struct Fftw<float> {
  using complex = fftwf_complex;
  using plan = fftwf_plan;
  static void init_threads() { fftwf_init_threads(); }
  static void threads(int n) { fftwf_plan_with_nthreads(n); }
  static plan guru(int rank, const fftwf_iodim64* dims, int hrank, const fftwf_iodim64* hdims, complex* data, int sign,
                   unsigned flags) {
    return fftwf_plan_guru64_dft(rank, dims, hrank, hdims, data, data, sign, flags);
  }
  static void execute(plan p, complex* data) { fftwf_execute_dft(p, data, data); }
  static void destroy(plan p) { fftwf_destroy_plan(p); }
  static complex* alloc(std::size_t n) { return fftwf_alloc_complex(n); }
  static void free(complex* p) { fftwf_free(p); }
  static int import_wisdom(const char* f) { return fftwf_import_wisdom_from_filename(f); }
  static int export_wisdom(const char* f) { return fftwf_export_wisdom_to_filename(f); }
  static int alignment(const float* p) { return fftwf_alignment_of(const_cast<float*>(p)); }
  static const char* tag() { return "f32"; }
};
template <>
struct Fftw<double> {
  using complex = fftw_complex;
  using plan = fftw_plan;
  static void init_threads() { fftw_init_threads(); }
  static void threads(int n) { fftw_plan_with_nthreads(n); }
  static plan guru(int rank, const fftw_iodim64* dims, int hrank, const fftw_iodim64* hdims, complex* data, int sign,
                   unsigned flags) {
    return fftw_plan_guru64_dft(rank, dims, hrank, hdims, data, data, sign, flags);
  }
  static void execute(plan p, complex* data) { fftw_execute_dft(p, data, data); }
  static void destroy(plan p) { fftw_destroy_plan(p); }
  static complex* alloc(std::size_t n) { return fftw_alloc_complex(n); }
  static void free(complex* p) { fftw_free(p); }
  static int import_wisdom(const char* f) { return fftw_import_wisdom_from_filename(f); }
  static int export_wisdom(const char* f) { return fftw_export_wisdom_to_filename(f); }
  static int alignment(const double* p) { return fftw_alignment_of(const_cast<double*>(p)); }
  static const char* tag() { return "f64"; }
};

// The wisdom file of one precision ("f32"/"f64") in the kernel cache folder; empty without one.
std::filesystem::path wisdom_file(const char* tag);
// Imports the wisdom file of F's precision if there is one (planner lock held). A file FFTW cannot
// parse is ignored (and rewritten by the next save_wisdom).
template <typename F>
void load_wisdom() {
  const std::filesystem::path wf = wisdom_file(F::tag());
  if (!wf.empty() && std::filesystem::exists(wf)) F::import_wisdom(wf.string().c_str());
}
// Writes the process's wisdom of F's precision to the file: to a temporary, then renamed, so a
// concurrent reader never sees half a file (planner lock held).
void save_wisdom_file(const std::filesystem::path& wf, int (*export_fn)(const char*));
template <typename F>
void save_wisdom() {
  save_wisdom_file(wisdom_file(F::tag()), &F::export_wisdom);
}

}  // namespace qdo::fftw_detail
