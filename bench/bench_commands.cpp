// Whole-command timings (the target: `qdo simulate` at least as fast as `qdo image`): one scene and
// design through `qdo simulate` (f32 and f64) and, as the baseline measured in the same run,
// `qdo image` (Camera with its default skipping tolerance 3e-7, as users run it). With
// --qdo-before PATH, the same `qdo simulate` f32 and `qdo image` f32 through another build (e.g.
// an older build to compare against) are timed too. Each command runs once first (kernel caches warm), then --repeats
// times; median, min and max wall time of the whole process are reported: PSF, imaging and
// writing every output included. Error column: the largest |f32 - f64| of simulate's sensor.h5
// (units of full scale; f64 is the reference). `qdo image` writes no HDF5 image, so its row has
// none.
//
//   bench_commands [--qdo build/qdo] [--qdo-before PATH] [--scene FILE] [--preset small] [--repeats 5]
//                  [--out FILE.md]
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "qdo/data/data_root.hpp"
#include "qdo/data/io.hpp"

#include "bench_util.hpp"

namespace fs = std::filesystem;

namespace {

// Wall time in seconds of one run of the shell command `cmd` (output discarded); exits on failure.
double run_once(const std::string& cmd) {
  const auto t0 = qdo::bench::Clock::now();
  const int status = std::system((cmd + " > /dev/null 2>&1").c_str());
  const double s = qdo::bench::seconds_since(t0);
  if (!WIFEXITED(status) || WEXITSTATUS(status) != 0) {
    std::fprintf(stderr, "bench_commands: failed: %s\n", cmd.c_str());
    std::exit(1);
  }
  return s;
}

}  // namespace

int main(int argc, char** argv) {
  std::string qdo = "build/qdo", before, scene, preset = "small", out;
  int repeats = 5;
  for (int i = 1; i < argc; i += 2) {  // --help, or a flag without its value, prints the usage (exit 2)
    const std::string k = i + 1 < argc ? argv[i] : "--help", v = i + 1 < argc ? argv[i + 1] : "";
    if (k == "--qdo") qdo = v;
    else if (k == "--qdo-before") before = v;
    else if (k == "--scene") scene = v;
    else if (k == "--preset") preset = v;
    else if (k == "--repeats") repeats = std::max(1, std::atoi(v.c_str()));
    else if (k == "--out") out = v;
    else {
      std::fprintf(stderr, "bench_commands: unknown option %s\n", k.c_str());
      return 2;
    }
  }
  const fs::path work = fs::temp_directory_path() / ("qdo_bench_commands_" + std::to_string(::getpid()));
  fs::create_directories(work);
  if (scene.empty()) scene = qdo::resolve_dataset("cave", "--scene") + "/balloons_256.mat";  // under the data root
  const std::string common = " --preset " + preset + " --design lens:550 --scene " + scene;
  struct Row {
    std::string label, binary, args, dir;
  };
  std::vector<Row> rows = {
      {"`qdo image` f32, default tolerance (baseline)", qdo, "image" + common + " --precision f32", "image_f32"},
      {"`qdo simulate` f32", qdo, "simulate" + common + " --precision f32", "simulate_f32"},
      {"`qdo simulate` f64", qdo, "simulate" + common + " --precision f64", "simulate_f64"},
  };
  if (!before.empty()) {
    rows.push_back({"`qdo simulate` f32, " + before, before, "simulate" + common + " --precision f32", "before_f32"});
    rows.push_back({"`qdo image` f32, default tolerance, " + before, before, "image" + common + " --precision f32", "before_image_f32"});
  }
  std::vector<qdo::bench::Timing> st;
  for (const Row& r : rows) {
    const std::string cmd = r.binary + " " + r.args + " --out " + (work / r.dir).string();
    run_once(cmd);  // warm-up: kernel and FFT-plan caches
    std::vector<double> t;
    for (int k = 0; k < repeats; ++k) t.push_back(run_once(cmd));
    st.push_back(qdo::bench::summarize(t));
    std::fprintf(stderr, "%s: median %.3f s\n", r.label.c_str(), st.back().median);
  }
  const auto a = qdo::h5_read((work / "simulate_f32" / "sensor.h5").string(), "/rgb");
  const auto b = qdo::h5_read((work / "simulate_f64" / "sensor.h5").string(), "/rgb");
  double err = 0;
  for (std::size_t i = 0; i < a.data.size(); ++i) err = std::max(err, std::fabs(a.data[i] - b.data[i]));
  std::string md = "| command (whole process, preset " + preset + ", " + fs::path(scene).filename().string() +
                   ") | median s | min s | max s | runs | max abs err vs f64 |\n|---|---:|---:|---:|---:|---:|\n";
  char line[512];
  char errtext[32];
  std::snprintf(errtext, sizeof errtext, "%.2e", err);
  for (std::size_t i = 0; i < rows.size(); ++i) {
    const std::string e = rows[i].dir == "simulate_f32" ? errtext : rows[i].dir == "simulate_f64" ? "0 (reference)" : "-";
    std::snprintf(line, sizeof line, "| %s | %.3f | %.3f | %.3f | %d | %s |\n", rows[i].label.c_str(), st[i].median, st[i].min,
                  st[i].max, repeats, e.c_str());
    md += line;
  }
  std::fputs(md.c_str(), stdout);
  if (!out.empty()) std::ofstream(out) << md;
  std::error_code ec;
  fs::remove_all(work, ec);
  return 0;
}
