// Every qdo command end to end on a tiny configuration (N = 32, 3 bands), run as a user would
// (the qdo binary through the shell), checking what each one writes, every documented exit code,
// and `qdo simulate`'s image against the library's.
//
// One qdo+a run (`qdo design --max-steps 2`) is made on first use and shared by the cases that
// consume a run folder (eval, sweep-psf --adaptive-from, tolerance, export, simulate). `qdo demo`
// has no --config, so it runs on the small preset (N = 256, 31 bands) with 2 steps per design.
// No case needs ../shared. Warm, the suite takes about 15-25 s on 2 CPU cores (PoCL).
#include <nlohmann/json.hpp>

#include <algorithm>
#include <cstdint>
#include <cstdlib>
#include <fstream>
#include <set>
#include <sstream>

#include <csignal>
#include <fcntl.h>
#include <sys/file.h>
#include <sys/wait.h>
#include <unistd.h>

#include "common.hpp"
#include "qdo/design_run.hpp"
#include "qdo/eval.hpp"
#include "qdo/doe.hpp"
#include "qdo/fab.hpp"
#include "qdo/io.hpp"
#include "qdo/cpu_reference.hpp"
#include "qdo/optics.hpp"
#include "qdo/release.hpp"
#include "qdo/run.hpp"
#include "qdo/simulator.hpp"

using namespace qdo;
using namespace qdo::test;
namespace fs = std::filesystem;
using nlohmann::json;

namespace {

json read_json(const fs::path& p) { return json::parse(slurp(p)); }

// Data rows of a CSV file (lines after the header, empty lines ignored).
std::size_t csv_rows(const fs::path& p) {
  std::istringstream s(slurp(p));
  std::string line;
  std::size_t n = 0;
  std::getline(s, line);
  while (std::getline(s, line))
    if (!line.empty()) ++n;
  return n;
}

std::vector<double> split_doubles(const std::string& s, char sep) {
  std::vector<double> v;
  std::stringstream ss(s);
  std::string item;
  while (std::getline(ss, item, sep)) v.push_back(std::stod(item));
  return v;
}

// The tiny system of the other tests (tiny_config: N = 32, 3 bands), as a --config file.
SystemConfig tiny() { return tiny_config(32, 3); }

// A temporary folder removed when the test binary exits (for the files shared between cases).
struct ScratchDir {
  fs::path dir;
  explicit ScratchDir(const std::string& tag) : dir(temp_dir(tag)) {}
  ScratchDir(const ScratchDir&) = delete;
  ScratchDir& operator=(const ScratchDir&) = delete;
  ~ScratchDir() {
    std::error_code ec;
    fs::remove_all(dir, ec);
  }
};

const fs::path& tiny_config_file() {
  static const ScratchDir d("cmd_cfg");
  static const fs::path p = [] {
    const fs::path f = d.dir / "tiny.json";
    std::ofstream(f) << config_to_json_text(tiny()) << "\n";
    return f;
  }();
  return p;
}

std::string cfg_arg() { return "--config " + tiny_config_file().string(); }

constexpr int kSteps = 2;   // --max-steps of the shared run
constexpr int kLevels = 4;

// The shared qdo+a run: `qdo design --max-steps 2` on the tiny configuration, made once.
struct SharedRun {
  fs::path dir;
  Run result;
};
const SharedRun& shared_run() {
  static const ScratchDir d("cmd_run");
  static const SharedRun r = [] {
    SharedRun s;
    s.dir = d.dir / "run";
    s.result = qdo_run("design " + cfg_arg() + " --mode qdo+a --levels " + std::to_string(kLevels) +
                       " --epochs 5 --steps-per-epoch 2 --t0 1 --t1 4 --synthetic-scenes 3 --seed 3 --max-steps " +
                       std::to_string(kSteps) + " --out " + s.dir.string());
    return s;
  }();
  return r;
}

// Sum of each plane of a planes x rows x cols dataset.
std::vector<double> plane_sums(const H5Dataset& d) {
  REQUIRE(d.shape.size() == 3);
  const std::size_t plane = d.shape[1] * d.shape[2];
  std::vector<double> s(d.shape[0], 0.0);
  for (std::size_t p = 0; p < d.shape[0]; ++p)
    for (std::size_t i = 0; i < plane; ++i) s[p] += d.data[p * plane + i];
  return s;
}

}  // namespace

TEST_SUITE("commands") {
  TEST_CASE("qdo config prints JSON that round-trips through --config") {
    const Run r = qdo_run("config --preset small");
    CAPTURE(r.out);
    REQUIRE(r.code == 0);
    // The printed text is exactly the small preset, and it parses back to the same configuration.
    CHECK(r.out == config_to_json_text(preset_config("small")) + "\n");
    const SystemConfig back = config_from_json_text(r.out, "qdo config output");
    CHECK(config_to_json_text(back) == config_to_json_text(preset_config("small")));
    // Fed back through --config, qdo prints the same text again.
    const auto dir = temp_dir("cmd_config");
    std::ofstream(dir / "small.json") << r.out;
    const Run again = qdo_run("config --config " + (dir / "small.json").string());
    CHECK(again.code == 0);
    CHECK(again.out == r.out);
    // A customised file (the tiny system of these tests) keeps every override.
    const Run t = qdo_run("config " + cfg_arg());
    CHECK(t.code == 0);
    CHECK(t.out == config_to_json_text(tiny()) + "\n");
    const SystemConfig tb = config_from_json_text(t.out, "tiny");
    CHECK(tb.n == 32);
    CHECK(tb.bands == 3);
    CHECK(tb.padding_px == 8);
    CHECK(tb.srf_interpolate);
    // Both --preset and --config, an unknown key, a bad value: input errors (exit 2).
    CHECK(qdo_run("config --preset small " + cfg_arg()).code == 2);
    std::ofstream(dir / "unknown.json") << R"({"preset": "small", "nn": 3})";
    const Run unk = qdo_run("config --config " + (dir / "unknown.json").string());
    CHECK(unk.code == 2);
    CHECK(unk.out.find("nn") != std::string::npos);
    std::ofstream(dir / "bad.json") << R"({"preset": "small", "bands": 0})";
    const Run bad = qdo_run("config --config " + (dir / "bad.json").string());
    CHECK(bad.code == 2);
    CHECK(bad.out.find("bands") != std::string::npos);
    fs::remove_all(dir);
  }

  TEST_CASE("qdo design --max-steps 2 writes a complete run folder") {
    const SharedRun& s = shared_run();
    CAPTURE(s.result.out);
    REQUIRE(s.result.code == 0);
    const fs::path& run = s.dir;
    for (const char* f : {"config.json", "checkpoint.h5", "log.csv", "prior.h5", "design.h5", "design_full.h5", "psf.h5", "design.png",
                          "psf.png", "loss.png"})
      CHECK_MESSAGE(fs::exists(run / f), f);
    // config.json holds every option given.
    const DesignRunOptions o = design_run_options_from_json(slurp(run / "config.json"), "config.json");
    CHECK(o.design.mode == DesignMode::QDOA);
    CHECK(o.design.quantizer.levels == kLevels);
    CHECK(o.epochs == 5);
    CHECK(o.design.steps_per_epoch == 2);
    CHECK(o.synthetic_scenes == 3);
    CHECK(o.design.seed == 3);
    CHECK(config_to_json_text(o.cfg) == config_to_json_text(tiny()));
    // The checkpoint stopped at step 2 (of 5 epochs x 2 steps), with one offset per level.
    const DesignState st = load_checkpoint((run / "checkpoint.h5").string(), parameter_count(o.design.parameterization, 32), kLevels);
    CHECK(st.step == kSteps);
    CHECK(st.offsets.size() == std::size_t(kLevels));
    // log.csv: one row per step, finite losses, alpha in [0, 1], L ascending level heights in [0, h_max].
    const CsvTable log = read_csv((run / "log.csv").string());
    REQUIRE(log.header.size() == 7);
    CHECK(log.header[0] == "step");
    CHECK(log.header[1] == "loss");
    CHECK(log.header[6] == "level_heights_nm");
    const auto& steps = log.column("step");
    REQUIRE(steps.size() == std::size_t(kSteps));
    std::vector<double> last_levels_nm;
    for (std::size_t i = 0; i < steps.size(); ++i) {
      CHECK(steps[i] == double(i));  // the step index the update started from
      CHECK(std::isfinite(log.column("loss")[i]));
      CHECK(log.column("loss")[i] > 0);
      CHECK(log.column("alpha")[i] >= 0);
      CHECK(log.column("alpha")[i] <= 1);
      CHECK(log.column("lr")[i] > 0);
      last_levels_nm = split_doubles(log.raw[6][i], ';');
      REQUIRE(last_levels_nm.size() == std::size_t(kLevels));
      for (std::size_t l = 0; l < last_levels_nm.size(); ++l) {
        CHECK(last_levels_nm[l] >= -1e-9);
        CHECK(last_levels_nm[l] <= tiny().h_max_m() * 1e9 + 1e-6);
        if (l) CHECK(last_levels_nm[l] > last_levels_nm[l - 1]);
      }
    }
    // design.h5: only the L level heights occur, /levels_m is the last logged level table, pitch as configured.
    const Design d = read_design((run / "design.h5").string());
    REQUIRE(d.height_m.rows == 32);
    CHECK(d.pitch_m == doctest::Approx(tiny().pitch_m));
    REQUIRE(d.levels_m.size() == std::size_t(kLevels));
    const std::set<double> distinct(d.height_m.data.begin(), d.height_m.data.end());
    CHECK(distinct.size() <= std::size_t(kLevels));
    CHECK(distinct.size() >= 2);
    for (double v : distinct) CHECK(std::find(d.levels_m.begin(), d.levels_m.end(), v) != d.levels_m.end());
    for (std::size_t l = 0; l < d.levels_m.size(); ++l) CHECK(d.levels_m[l] * 1e9 == doctest::Approx(last_levels_nm[l]).epsilon(1e-6));
    // design_full.h5: the continuous map on the same grid, not quantized.
    const Design full = read_design((run / "design_full.h5").string());
    CHECK(full.height_m.rows == 32);
    CHECK(std::set<double>(full.height_m.data.begin(), full.height_m.data.end()).size() > std::size_t(kLevels));
    // psf.h5: design.h5's PSF stack on the sensor grid (the library's), each band summing to 1.
    const H5Dataset ps = h5_read((run / "psf.h5").string(), "/psf");
    REQUIRE(ps.shape == std::vector<std::size_t>{3, tiny().sensor_size_px(), tiny().sensor_size_px()});
    for (double sum : plane_sums(ps)) CHECK(sum == doctest::Approx(1.0).epsilon(1e-4));
    {
      Simulator sim(runtime(), tiny(), Precision::F32);  // the run's precision (default f32)
      sim.set_heights(d.height_m);
      sim.compute_psf();
      CHECK(diff(ps.data, sim.psf_sensor().data).rel_l2 <= 10 * kEps32);
    }
    // Starting again into the same folder without --resume is refused (input error, exit 2), the run untouched.
    const auto stamp = fs::last_write_time(run / "checkpoint.h5");
    const Run again = qdo_run("design " + cfg_arg() + " --mode qdo+a --levels 4 --max-steps 1 --out " + run.string());
    CHECK(again.code == 2);
    CHECK(again.out.find("--resume") != std::string::npos);
    CHECK(fs::last_write_time(run / "checkpoint.h5") == stamp);
    // --resume on a copy continues from the checkpoint with config.json's options: one more step,
    // the first two log rows kept as they were.
    const auto copy_dir = temp_dir("cmd_resume");
    const fs::path copy = copy_dir / "run";
    fs::copy(run, copy, fs::copy_options::recursive);
    const Run res = qdo_run("design --resume --max-steps 3 --out " + copy.string());
    CAPTURE(res.out);
    REQUIRE(res.code == 0);
    CHECK(load_checkpoint((copy / "checkpoint.h5").string(), parameter_count(o.design.parameterization, 32), kLevels).step == 3);
    const CsvTable log3 = read_csv((copy / "log.csv").string());
    REQUIRE(log3.column("step").size() == 3);
    for (std::size_t c = 0; c < 5; ++c)  // step, loss, loss_aq, alpha, lr (not the step time)
      for (std::size_t i = 0; i < 2; ++i) CHECK(log3.raw[c][i] == log.raw[c][i]);
    fs::remove_all(copy_dir);
  }

  TEST_CASE("qdo eval writes metrics that parse, are plausible and equal the library's") {
    const SharedRun& s = shared_run();
    REQUIRE(s.result.code == 0);
    const auto dir = temp_dir("cmd_eval");
    const Run r = qdo_run("eval " + s.dir.string() + " --synthetic-scenes 2 --renders 1 --out " + (dir / "ev").string());
    CAPTURE(r.out);
    REQUIRE(r.code == 0);
    const json m = read_json(dir / "ev" / "metrics.json");
    CHECK(m.at("decoder") == "matched");
    CHECK(m.at("levels") == kLevels);
    CHECK(m.at("full_precision") == false);
    const double psnr = m.at("mean").at("psnr_db").get<double>(), ssim = m.at("mean").at("ssim").get<double>();
    CHECK(psnr > 10);  // a Wiener reconstruction of smooth synthetic scenes: well above noise ...
    CHECK(psnr < 80);  // ... and not a perfect copy
    CHECK(ssim > 0);
    CHECK(ssim <= 1);
    CHECK(m.at("deviation_nm").get<double>() > 0);
    CHECK(m.at("deviation_nm").get<double>() < tiny().h_max_m() * 1e9);
    // metrics.csv: one row per test scene (plus the mean), PSNR column agreeing with metrics.json's mean.
    const CsvTable csv = read_csv((dir / "ev" / "metrics.csv").string());
    REQUIRE(!csv.column("psnr_db").empty());
    for (double v : csv.column("psnr_db")) CHECK(std::isfinite(v));
    CHECK(fs::exists(dir / "ev" / "reconstructions.h5"));
    CHECK(fs::exists(dir / "ev" / "render_0.png"));
    // The library on the same run and options gives the same numbers.
    EvalOptions e;
    e.run = s.dir.string();
    e.synthetic_scenes = 2;
    e.renders = 0;
    e.out = (dir / "lib").string();
    const EvalResult lib = evaluate_run(runtime(), e);
    CHECK(psnr == doctest::Approx(lib.mean.psnr).epsilon(1e-6));
    CHECK(ssim == doctest::Approx(lib.mean.ssim).epsilon(1e-6));
    CHECK(m.at("deviation_nm").get<double>() == doctest::Approx(lib.deviation_nm).epsilon(1e-9));
    // The paper's DO (decoder for H_f) differs from the matched decoder; a missing RUN is an input error.
    const Run mis = qdo_run("eval " + s.dir.string() + " --synthetic-scenes 2 --renders 0 --decoder mismatch --out " + (dir / "mis").string());
    CHECK(mis.code == 0);
    CHECK(read_json(dir / "mis" / "metrics.json").at("mean").at("psnr_db").get<double>() != psnr);
    CHECK(qdo_run("eval --out " + (dir / "x").string()).code == 2);
    CHECK(qdo_run("eval " + (dir / "no_such_run").string() + " --out " + (dir / "x").string()).code == 2);
    fs::remove_all(dir);
  }

  TEST_CASE("qdo gradcheck passes every row on the tiny configuration") {
    const Run r = qdo_run("gradcheck " + cfg_arg() + " --mode qdo+a --levels 4 --seed 1");
    CAPTURE(r.out);
    REQUIRE(r.code == 0);
    CHECK(r.out.find("parameter group") != std::string::npos);
    CHECK(r.out.find("FAIL") == std::string::npos);
    // Rows: PSF chain (OpenCL vs CPU, CPU vs differences), weights end to end, level offsets (qdo+a),
    // the objective with respect to the PSF, the device objective against the CPU one.
    std::size_t ok_rows = 0;
    std::istringstream lines(r.out);
    for (std::string line; std::getline(lines, line);) {
      if (line.size() < 4 || line.compare(line.size() - 2, 2, "ok") != 0) continue;
      ++ok_rows;
      // "... max_rel_err tolerance  ok": the error is within the tolerance printed next to it.
      std::istringstream w(line);
      std::vector<std::string> words;
      for (std::string x; w >> x;) words.push_back(x);
      REQUIRE(words.size() >= 3);
      CHECK(std::stod(words[words.size() - 3]) <= std::stod(words[words.size() - 2]));
    }
    CHECK(ok_rows == 6);
    for (const char* row : {"PSF chain: OpenCL", "PSF chain: CPU adjoint vs central differences", "weights w (qdo+a, wiener",
                            "level offsets a (qdo+a)", "objective wiener vs PSF", "objective wiener on the device (f64)"})
      CHECK_MESSAGE(r.out.find(row) != std::string::npos, row);
    // On a device without float64 (QDO_DISABLE_FP64=1) the check runs in float32 with its looser
    // tolerances and a larger difference step; it passes (it failed falsely with a 1e-5 step,
    // which drowned in float32 round-off).
    const Run f32 = qdo_run("gradcheck " + cfg_arg() + " --mode qdo+a --levels 4 --seed 1", "QDO_DISABLE_FP64=1");
    CAPTURE(f32.out);
    CHECK(f32.out.find("OpenCL f32 adjoint") != std::string::npos);
    CHECK(f32.code == 0);
    // ... and without float64 the wiener objective runs on the CPU: no device row, a note instead.
    CHECK(f32.out.find("objective wiener on the device") == std::string::npos);
    CHECK(f32.out.find("runs on the CPU (double) instead") != std::string::npos);
    CHECK(f32.out.find("FAIL") == std::string::npos);
    // Exit code 5: a wrong gradient (fault injection scales the weight gradient by 1.5) fails its
    // row, and only that row.
    const Run bad = qdo_run("gradcheck " + cfg_arg() + " --mode qdo+a --levels 4 --seed 1", "QDO_GRADCHECK_FAULT=1");
    CAPTURE(bad.out);
    CHECK(bad.code == 5);
    const std::size_t row = bad.out.find("weights w (qdo+a");
    REQUIRE(row != std::string::npos);
    CHECK(bad.out.substr(row, bad.out.find('\n', row) - row).find("FAIL") != std::string::npos);
    CHECK(bad.out.find("FAIL") == bad.out.rfind("FAIL"));
    CHECK(qdo_run("gradcheck " + cfg_arg() + " --mode nonsense").code == 2);
  }

  TEST_CASE("qdo sweep-psf --adaptive-from: one unit-sum PSF stack per requested variant") {
    const SharedRun& s = shared_run();
    REQUIRE(s.result.code == 0);
    const auto dir = temp_dir("cmd_sweeppsf");
    const Run r = qdo_run("sweep-psf --design " + s.dir.string() + " --levels 2,4 --adaptive-from " + s.dir.string() + " --out " +
                          dir.string());
    CAPTURE(r.out);
    REQUIRE(r.code == 0);
    const std::vector<std::string> labels = {"full", "L2", "L4", "L4-adaptive"};
    const json j = read_json(dir / "sweep.json");
    REQUIRE(j.size() == labels.size());
    for (std::size_t k = 0; k < labels.size(); ++k) {
      CAPTURE(labels[k]);
      CHECK(j[k].at("variant") == labels[k]);
      CHECK(j[k].at("rel_l2").size() == 3);
      const H5Dataset p = h5_read((dir / "psf.h5").string(), "/psf_" + labels[k]);
      REQUIRE(p.shape.size() == 3);
      CHECK(p.shape[0] == 3);
      CHECK(p.shape[1] == tiny().sensor_size_px());
      for (double sum : plane_sums(p)) CHECK(sum == doctest::Approx(1.0).epsilon(1e-4));
    }
    CHECK(j[0].at("levels") == 0);
    CHECK(j[0].at("deviation_nm").get<double>() == 0.0);
    for (double v : j[0].at("rel_l2")) CHECK(v == 0.0);
    for (double v : j[0].at("peak_ratio")) CHECK(v == doctest::Approx(1.0));
    CHECK(j[1].at("levels") == 2);
    CHECK(j[3].at("levels") == kLevels);
    // Coarser quantization moves the heights further from H_f.
    CHECK(j[1].at("deviation_nm").get<double>() > j[2].at("deviation_nm").get<double>());
    CHECK(j[2].at("deviation_nm").get<double>() > 0);
    // The adaptive variant is the run's own fabricated design: its deviation is design.h5's.
    const Design fab = read_design((s.dir / "design.h5").string()), full = read_design((s.dir / "design_full.h5").string());
    double dev = 0;
    for (std::size_t i = 0; i < fab.height_m.data.size(); ++i) dev += std::fabs(fab.height_m.data[i] - full.height_m.data[i]);
    dev /= double(fab.height_m.data.size());
    CHECK(j[3].at("deviation_nm").get<double>() == doctest::Approx(dev * 1e9).epsilon(1e-6));
    // ... and its PSF stack is the run's psf.h5 (same heights, same f32 PSF chain, batched here).
    CHECK(diff(h5_read((dir / "psf.h5").string(), "/psf_L4-adaptive").data, h5_read((s.dir / "psf.h5").string(), "/psf").data).rel_l2 <=
          10 * kEps32);
    CHECK(csv_rows(dir / "sweep.csv") == labels.size() * 3);
    CHECK(fs::exists(dir / "psf_L4-adaptive.png"));
    // --adaptive-from needs a qdo+a run folder.
    CHECK(qdo_run("sweep-psf --design " + s.dir.string() + " --levels 2 --adaptive-from " + (dir / "nope").string() + " --out " +
                  (dir / "x").string()).code == 2);
    fs::remove_all(dir);
  }

  TEST_CASE("qdo sweep: one table row per grid cell, DO trained once") {
    const auto dir = temp_dir("cmd_sweep");
    const Run r = qdo_run("sweep " + cfg_arg() + " --grid levels=2,4 --grid mode=do,do-refit --epochs 2 --steps-per-epoch 1 --t0 0.5 "
                          "--t1 1.5 --synthetic-scenes 3 --eval-scenes 2 --out " + dir.string());
    CAPTURE(r.out);
    REQUIRE(r.code == 0);
    // Cells: the full-precision reference + 2 levels x 2 modes.
    const CsvTable t1 = read_csv((dir / "table1.csv").string());
    REQUIRE(t1.column("psnr_db").size() == 5);
    std::set<std::string> cells;
    for (std::size_t i = 0; i < 5; ++i) {
      cells.insert(t1.raw[0][i] + "/" + t1.raw[1][i]);
      CHECK(std::isfinite(t1.column("psnr_db")[i]));
      CHECK(t1.column("psnr_db")[i] > 10);
      CHECK(t1.column("ssim")[i] > 0);
      CHECK(t1.column("ssim")[i] <= 1);
    }
    CHECK(cells.size() == 5);
    CHECK(cells.count("2/do") == 1);
    CHECK(cells.count("4/do-refit") == 1);
    // Table 2: do and do-refit share the DOE, so their deviation is the same; 2 levels deviate more than 4.
    const CsvTable t2 = read_csv((dir / "table2.csv").string());
    std::map<std::string, double> dev;
    for (std::size_t i = 0; i < t2.column("deviation_nm").size(); ++i) dev[t2.raw[0][i] + "/" + t2.raw[1][i]] = t2.column("deviation_nm")[i];
    REQUIRE(dev.count("2/do"));
    REQUIRE(dev.count("2/do-refit"));
    REQUIRE(dev.count("4/do"));
    CHECK(dev["2/do"] == dev["2/do-refit"]);
    CHECK(dev["2/do"] > dev["4/do"]);
    // One training run (DO, full precision), finished.
    CHECK(fs::exists(dir / "runs" / "do" / "DONE"));
    CHECK(fs::exists(dir / "table1.md"));
    CHECK(fs::exists(dir / "psnr_vs_levels.png"));
    CHECK(csv_rows(dir / "runs" / "do" / "log.csv") == 2);
    // sweep-psf --adaptive-from refuses a run that is not qdo+a (input error naming the mode).
    const Run ad = qdo_run("sweep-psf --design " + (dir / "runs" / "do").string() + " --levels 2 --adaptive-from " +
                           (dir / "runs" / "do").string() + " --out " + (dir / "x").string());
    CHECK(ad.code == 2);
    CHECK(ad.out.find("qdo+a") != std::string::npos);
    // An unknown grid axis is an input error.
    CHECK(qdo_run("sweep " + cfg_arg() + " --grid colour=red --out " + (dir / "y").string()).code == 2);
    fs::remove_all(dir);
  }

  TEST_CASE("qdo tolerance: zero perturbation gives zero spread, errors give per-source scenarios") {
    const SharedRun& s = shared_run();
    REQUIRE(s.result.code == 0);
    const auto dir = temp_dir("cmd_tol");
    const std::string common = " --trials 2 --synthetic-scenes 2 --oversample 1 --seed 5 ";
    {
      const Run r = qdo_run("tolerance " + s.dir.string() + common + "--etch-depth-error-nm 0 --overlay-um 0 --out " + (dir / "zero").string());
      CAPTURE(r.out);
      REQUIRE(r.code == 0);
      const json j = read_json(dir / "zero" / "tolerance.json");
      REQUIRE(j.at("scenarios").size() == 1);
      const json& all = j.at("scenarios")[0];
      CHECK(all.at("scenario") == "all");
      CHECK(all.at("trials") == 2);
      const double nominal = j.at("nominal").at("psnr_db").get<double>();
      CHECK(std::isfinite(nominal));
      CHECK(std::fabs(all.at("calibrated").at("psnr_db").at("std").get<double>()) < 1e-9);
      CHECK(all.at("calibrated").at("psnr_db").at("mean").get<double>() == doctest::Approx(nominal).epsilon(1e-9));
      CHECK(all.at("nominal_decoder").at("psnr_db").at("mean").get<double>() == doctest::Approx(nominal).epsilon(1e-9));
      const CsvTable t = read_csv((dir / "zero" / "tolerance.csv").string());
      REQUIRE(t.column("psf_rel_change").size() == 2);
      for (double v : t.column("psf_rel_change")) CHECK(v < 1e-12);
      for (double v : t.column("height_rms_change_nm")) CHECK(v < 1e-9);
    }
    {
      const Run r = qdo_run("tolerance " + s.dir.string() + common + "--etch-depth-error-nm 30 --overlay-um 2 --out " + (dir / "err").string());
      CAPTURE(r.out);
      REQUIRE(r.code == 0);
      const json j = read_json(dir / "err" / "tolerance.json");
      // auto: binary-coded masks cannot make qdo+a's learned (non-uniform) levels, so nested: L - 1 masks.
      CHECK(j.at("scheme") == "nested");
      CHECK(j.at("masks").size() == std::size_t(kLevels - 1));
      std::vector<std::string> names;
      for (const auto& sc : j.at("scenarios")) names.push_back(sc.at("scenario"));
      CHECK(names == std::vector<std::string>{"all", "etch depth", "overlay"});
      const CsvTable t = read_csv((dir / "err" / "tolerance.csv").string());
      REQUIRE(t.column("psf_rel_change").size() == 3 * 2);
      for (std::size_t i = 0; i < t.raw[0].size(); ++i) {
        CAPTURE(t.raw[0][i]);
        CHECK(t.column("psf_rel_change")[i] > 0);  // every trial moves the PSF
        CHECK(std::isfinite(t.column("psnr_db")[i]));
      }
      for (const char* f : {"tolerance.md", "psnr_by_scenario.png"}) CHECK(fs::exists(dir / "err" / f));
    }
    CHECK(qdo_run("tolerance " + s.dir.string() + " --trials 0 --out " + (dir / "x").string()).code == 2);
    CHECK(qdo_run("tolerance " + s.dir.string() + " --overlay-um -1 --out " + (dir / "x").string()).code == 2);
    fs::remove_all(dir);
  }

  TEST_CASE("qdo export writes a GDSII mask set and a manifest that rebuild design.h5") {
    const SharedRun& s = shared_run();
    REQUIRE(s.result.code == 0);
    const auto dir = temp_dir("cmd_export");
    // qdo+a's learned levels are not subset sums of binary etch depths: binary masks are refused
    // (input error naming the alternatives), nested masks (L - 1 layers, free step heights) work.
    const Run bin = qdo_run("export " + s.dir.string() + " --scheme binary --out " + (dir / "bin").string());
    CHECK(bin.code == 2);
    CHECK(bin.out.find("--scheme nested") != std::string::npos);
    const Run r = qdo_run("export " + s.dir.string() + " --scheme nested --out " + dir.string());
    CAPTURE(r.out);
    REQUIRE(r.code == 0);
    // GDSII: HEADER (length 6, type 0x00 0x02, version 600), then BGNLIB (length 28, 0x01 0x02); ENDLIB last.
    const std::string g = slurp(dir / "masks.gds");
    REQUIRE(g.size() > 64);
    const std::vector<std::uint8_t> head(g.begin(), g.begin() + 10), tail(g.end() - 4, g.end());
    CHECK(head == std::vector<std::uint8_t>{0x00, 0x06, 0x00, 0x02, 0x02, 0x58, 0x00, 0x1C, 0x01, 0x02});
    CHECK(tail == std::vector<std::uint8_t>{0x00, 0x04, 0x04, 0x00});
    // The manifest lists the design's L levels with their heights and the L - 1 nested masks.
    const Design d = read_design((s.dir / "design.h5").string());
    const json m = read_json(dir / "manifest.json");
    CHECK(m.at("scheme") == "nested");
    REQUIRE(m.at("levels").size() == std::size_t(kLevels));
    for (std::size_t l = 0; l < std::size_t(kLevels); ++l)
      CHECK(m.at("levels")[l].at("height_nm").get<double>() == doctest::Approx(d.levels_m[l] * 1e9).epsilon(1e-9));
    std::size_t pixels = 0;
    for (const auto& l : m.at("levels")) pixels += l.at("pixels").get<std::size_t>();
    CHECK(pixels == 32 * 32);
    CHECK(m.at("masks").size() == std::size_t(kLevels - 1));
    CHECK(m.at("grid").at("n") == 32);
    // Read back from the GDS and the manifest alone, the masks rebuild design.h5.
    const fab::Reconstruction rec = fab::reconstruct_export(dir.string());
    REQUIRE(rec.height_m.data.size() == d.height_m.data.size());
    double worst = 0;
    for (std::size_t i = 0; i < d.height_m.data.size(); ++i) worst = std::max(worst, std::fabs(rec.height_m.data[i] - d.height_m.data[i]));
    CHECK(worst < 1e-12);  // metres; well under the 0.001 nm level tolerance
    CHECK(std::count_if(rec.level_of_pixel.begin(), rec.level_of_pixel.end(), [](std::int32_t v) { return v < 0; }) == 0);
    CHECK(fs::exists(dir / "manifest.md"));
    CHECK(fs::exists(dir / "mask_L1.png"));
    // A bad scheme, or a fab constraint the design breaks (fewer levels allowed than it has): exit 2.
    CHECK(qdo_run("export " + s.dir.string() + " --scheme stencil --out " + (dir / "x").string()).code == 2);
    CHECK(qdo_run("export " + s.dir.string() + " --scheme nested --max-levels 2 --out " + (dir / "y").string()).code == 2);
    fs::remove_all(dir);
  }

  TEST_CASE("qdo simulate --formation release equals the release reference; its refusals") {
    const auto dir = temp_dir("cmd_release");
    SystemConfig c = tiny();
    c.aperture_edge = ApertureEdge::Strict;
    const fs::path cfg_file = dir / "strict.json";
    std::ofstream(cfg_file) << config_to_json_text(c) << "\n";
    const std::string cfg = "--config " + cfg_file.string();
    const RealStack scene = random_cube(c.bands, 14, 14, 5);  // S = 14, N = 32: G = 50
    write_cube((dir / "scene.h5").string(), scene, c.wavelengths_nm());
    for (const Precision p : {Precision::F32, Precision::F64}) {
      if (p == Precision::F64 && !runtime().has_fp64()) continue;
      CAPTURE(to_string(p));
      const fs::path out = dir / to_string(p);
      const Run r = qdo_run("simulate " + cfg + " --design lens:550 --formation release --scene " + (dir / "scene.h5").string() +
                            " --precision " + to_string(p) + " --out " + out.string());
      CAPTURE(r.out);
      REQUIRE(r.code == 0);
      CHECK(r.out.find("formation: release") != std::string::npos);
      Simulator sim(runtime(), c, Precision::F64);
      sim.set_heights(lens_design(c, 550));
      sim.compute_psf();
      RealStack want = ref::sensor_integrate(ref::release_blur(scene, sim.psf_native()), sim.srf());
      ref::add_noise(want, c.read_noise_sigma, c.full_well_photons, c.noise_seed, 0);
      for (double& v : want.data) v = std::min(v, 1.0);  // the command clips at full scale
      const H5Dataset rgb = h5_read((out / "sensor.h5").string(), "/rgb");
      REQUIRE(rgb.shape == std::vector<std::size_t>{3, 14, 14});
      // The PSF itself in float32 (1e-6) dominates the float32 tolerance.
      CHECK(diff(rgb.data, want.data).rel_l2 <= (p == Precision::F64 ? 1e-12 : 2e-5));
    }
    const std::string base = "simulate " + cfg + " --design flat --out " + (dir / "x").string();
    Run r = qdo_run(base + " --formation tf");
    CHECK(r.code == 2);
    CHECK(r.out.find("--formation") != std::string::npos);
    write_cube((dir / "wide.h5").string(), random_cube(c.bands, 14, 12, 6), c.wavelengths_nm());
    r = qdo_run(base + " --formation release --scene " + (dir / "wide.h5").string());
    CHECK(r.code == 2);
    CHECK(r.out.find("square") != std::string::npos);
    write_cube((dir / "big.h5").string(), random_cube(c.bands, 31, 31, 7), c.wavelengths_nm());
    r = qdo_run(base + " --formation release --scene " + (dir / "big.h5").string());
    CHECK(r.code == 2);
    CHECK(r.out.find("PSF size N") != std::string::npos);
    CHECK_FALSE(fs::exists(dir / "x"));
    fs::remove_all(dir);
  }

  TEST_CASE("qdo simulate's sensor image equals the library's") {
    const SharedRun& s = shared_run();
    REQUIRE(s.result.code == 0);
    const auto dir = temp_dir("cmd_sim");
    const SystemConfig c = tiny();
    // A random 3-band scene in our cube format.
    const RealStack scene = random_cube(c.bands, 24, 20, 11);
    write_cube((dir / "scene.h5").string(), scene, c.wavelengths_nm());
    const std::string design = (s.dir / "design.h5").string();
    for (const Precision p : {Precision::F32, Precision::F64}) {
      if (p == Precision::F64 && !runtime().has_fp64()) continue;  // f32 alone is still compared
      CAPTURE(to_string(p));
      const fs::path out = dir / to_string(p);
      const Run r = qdo_run("simulate " + cfg_arg() + " --design " + design + " --scene " + (dir / "scene.h5").string() +
                            " --precision " + to_string(p) + " --out " + out.string());
      CAPTURE(r.out);
      REQUIRE(r.code == 0);
      Simulator sim(runtime(), c, p);
      sim.set_heights(read_design(design).height_m);
      sim.compute_psf();
      const RealStack want = sim.sensor_image(scene);
      const H5Dataset rgb = h5_read((out / "sensor.h5").string(), "/rgb");
      REQUIRE(rgb.shape == std::vector<std::size_t>{3, want.rows, want.cols});
      CHECK(want.rows == 24);
      CHECK(want.cols == 20);
      const auto dd = diff(rgb.data, want.data);
      CHECK(dd.rel_l2 <= 10 * eps(p));
      CHECK(dd.max_abs <= 10 * eps(p));
      // The PSF the command wrote is the library's too, and the design it used is design.h5.
      const H5Dataset psf = h5_read((out / "psf.h5").string(), "/psf_sensor");
      CHECK(diff(psf.data, sim.psf_sensor().data).max_abs <= 10 * eps(p));
      CHECK(h5_read((out / "psf.h5").string(), "/height_m").data == read_design(design).height_m.data);
      for (const char* f : {"sensor.png", "scene.png", "psf.png"}) CHECK(fs::exists(out / f));
    }
    fs::remove_all(dir);
  }

  TEST_CASE("cubes mean what they say: band axis checked or resampled, radiance rule, sensor clipped at full scale") {
    const auto dir = temp_dir("cmd_cubes");
    const SystemConfig c = tiny();  // 3 bands: 450, 500, 550 nm
    const RealStack scene = random_cube(c.bands, 16, 16, 5);
    // A band axis 10 nm off the configuration's: refused before any work, naming both grids.
    write_cube((dir / "shifted.h5").string(), scene, {460, 510, 560});
    const fs::path out = dir / "out";
    Run r = qdo_run("simulate " + cfg_arg() + " --design flat --scene " + (dir / "shifted.h5").string() + " --out " + out.string());
    CAPTURE(r.out);
    CHECK(r.code == 2);
    CHECK(r.out.find("460 ... 560 nm") != std::string::npos);
    CHECK(r.out.find("450 ... 550 nm") != std::string::npos);
    CHECK_FALSE(fs::exists(out));
    // A reversed axis with --resample-bands: the cube is reordered, with a note, and images as
    // the correctly ordered cube does.
    RealStack reversed(c.bands, 16, 16);
    for (std::size_t b = 0; b < c.bands; ++b)
      std::copy(scene.plane(c.bands - 1 - b), scene.plane(c.bands - 1 - b) + 256, reversed.plane(b));
    write_cube((dir / "reversed.h5").string(), reversed, {550, 500, 450});
    write_cube((dir / "ordered.h5").string(), scene, c.wavelengths_nm());
    r = qdo_run("simulate " + cfg_arg() + " --design flat --scene " + (dir / "reversed.h5").string() + " --out " +
                (dir / "rev").string() + " --resample-bands");
    CAPTURE(r.out);
    REQUIRE(r.code == 0);
    CHECK(r.out.find("resampled") != std::string::npos);
    REQUIRE(qdo_run("simulate " + cfg_arg() + " --design flat --scene " + (dir / "ordered.h5").string() + " --out " +
                    (dir / "ord").string()).code == 0);
    CHECK(h5_read((dir / "rev" / "sensor.h5").string(), "/rgb").data == h5_read((dir / "ord" / "sensor.h5").string(), "/rgb").data);

    // Radiance: strongly negative refused (exit 2, naming the file); an HDR cube (values up to
    // 543) divided by its maximum, with a note, so the image stays within full scale.
    RealStack neg = scene;
    neg.data[17] = -0.5;
    write_cube((dir / "neg.h5").string(), neg, c.wavelengths_nm());
    r = qdo_run("simulate " + cfg_arg() + " --design flat --scene " + (dir / "neg.h5").string() + " --out " + (dir / "n").string());
    CHECK(r.code == 2);
    CHECK(r.out.find("neg.h5") != std::string::npos);
    CHECK(r.out.find("negative") != std::string::npos);
    CHECK_FALSE(fs::exists(dir / "n"));
    RealStack hdr = scene;
    for (double& v : hdr.data) v *= 543.0;
    write_cube((dir / "hdr.h5").string(), hdr, c.wavelengths_nm());
    r = qdo_run("simulate " + cfg_arg() + " --design flat --scene " + (dir / "hdr.h5").string() + " --out " + (dir / "h").string());
    CAPTURE(r.out);
    REQUIRE(r.code == 0);
    CHECK(r.out.find("divided by that maximum") != std::string::npos);
    const H5Dataset hdr_rgb = h5_read((dir / "h" / "sensor.h5").string(), "/rgb");
    CHECK(*std::max_element(hdr_rgb.data.begin(), hdr_rgb.data.end()) <= 1.0);

    // The sensor saturates: with read noise sigma 0.5 many values exceed full scale; they read as
    // 1, and the fraction is printed and stored with the image.
    SystemConfig noisy = c;
    noisy.read_noise_sigma = 0.5;
    std::ofstream(dir / "noisy.json") << config_to_json_text(noisy) << "\n";
    r = qdo_run("simulate --config " + (dir / "noisy.json").string() + " --design flat --scene " + (dir / "ordered.h5").string() +
                " --out " + (dir / "noisy").string());
    CAPTURE(r.out);
    REQUIRE(r.code == 0);
    const H5Dataset rgb = h5_read((dir / "noisy" / "sensor.h5").string(), "/rgb");
    const auto at_full = std::count(rgb.data.begin(), rgb.data.end(), 1.0);
    CHECK(*std::max_element(rgb.data.begin(), rgb.data.end()) == 1.0);
    CHECK(at_full > 0);
    CHECK(rgb.num_attrs.at("clipped_fraction") == doctest::Approx(double(at_full) / double(rgb.data.size())));
    CHECK(rgb.num_attrs.at("max_before_clip") > 1.0);
    CHECK(r.out.find("clipped at full scale") != std::string::npos);
    fs::remove_all(dir);
  }

  TEST_CASE("a failed command leaves no output set, no folder it created and no temporary files") {
    const auto dir = temp_dir("cmd_nopartial");
    // An unknown device: exit 2 or 4, and the --out folder (and its parent) it would have made are gone.
    const fs::path nested = dir / "new" / "out";
    Run r = qdo_run("simulate " + cfg_arg() + " --design flat --device no-such-device-xyz --out " + nested.string());
    CAPTURE(r.out);
    CHECK((r.code == 2 || r.code == 4));
    CHECK_FALSE(fs::exists(dir / "new"));
    // A failure after some outputs were computed: psf.png is taken by a folder, so the set cannot be
    // written whole; none of it is (sensor.h5, sensor.png, scene.png, psf.h5 would come first), no
    // *.tmp-* file stays, and the folder the user made is kept with only what was there.
    const fs::path out = dir / "out";
    fs::create_directories(out / "psf.png");
    std::ofstream(out / "mine.txt") << "keep";
    r = qdo_run("simulate " + cfg_arg() + " --design flat --out " + out.string());
    CAPTURE(r.out);
    CHECK(r.code == 2);
    CHECK(r.out.find("psf.png") != std::string::npos);
    std::set<std::string> left;
    for (const auto& e : fs::directory_iterator(out)) left.insert(e.path().filename().string());
    CHECK(left == std::set<std::string>{"mine.txt", "psf.png"});
    // qdo design: a bad option is refused before anything is read, computed or made.
    for (const std::string bad : {"--lr -1", "--decay -0.5", "--decay 1.5", "--beta -1", "--t0 50 --t1 40", "--height-noise-nm -3",
                                  "--init lens:abc", "--objective psf-target --target lens:1e999"}) {
      CAPTURE(bad);
      const fs::path run = dir / "run";
      r = qdo_run("design " + cfg_arg() + " --mode qdo+a --levels 4 --epochs 60 --synthetic-scenes 3 " + bad + " --out " + run.string());
      CAPTURE(r.out);
      CHECK(r.code == 2);
      CHECK(r.out.find("argument '") != std::string::npos);
      CHECK_FALSE(fs::exists(run));
    }
    fs::remove_all(dir);
  }

  TEST_CASE("documented exit codes: 0 ok, 2 bad input (an uncreatable --out too), 3 accuracy refusal, 4 device error") {
    const auto dir = temp_dir("cmd_codes");
    const std::string out = (dir / "out").string();
    // 0: help.
    const Run help = qdo_run("--help");
    CHECK(help.code == 0);
    CHECK(help.out.find("usage:") != std::string::npos);
    const Run devices = qdo_run("devices");
    CHECK(devices.code == 0);
    CHECK(devices.out.find("default: ") != std::string::npos);
    // 2: no command, an unknown command, an unknown option, a bad value, a missing --out.
    CHECK(qdo_run("").code == 2);
    const Run unk = qdo_run("frobnicate");
    CHECK(unk.code == 2);
    CHECK(unk.out.find("unknown command") != std::string::npos);
    CHECK(qdo_run("psf " + cfg_arg() + " --design flat --frob 1 --out " + out).code == 2);
    CHECK(qdo_run("psf " + cfg_arg() + " --design lens:-5 --out " + out).code == 2);
    CHECK(qdo_run("psf " + cfg_arg() + " --design flat").code == 2);
    CHECK_FALSE(fs::exists(out));  // nothing was written by any of these
    // An unknown --device is an input error too. (It is checked when the runtime starts, after the
    // output folder was created: the folder is left behind, empty.)
    const Run nodevice = qdo_run("psf " + cfg_arg() + " --design flat --device no-such-device-anywhere --out " + out);
    CHECK(nodevice.code == 2);
    CHECK(nodevice.out.find("no-such-device-anywhere") != std::string::npos);
    // 3: strict_sampling refuses an under-sampled transfer function. The tiny system keeps the paper's
    // sampling ratio, so its longer bands are under-sampled; a lens for 450 nm puts 0.8 % of the field
    // energy at 500 nm beyond the limit (1e-4 allowed).
    SystemConfig strict = tiny();
    strict.strict_sampling = true;
    std::ofstream(dir / "strict.json") << config_to_json_text(strict);
    const Run refused = qdo_run("psf --config " + (dir / "strict.json").string() + " --design lens:450 --out " + (dir / "strict").string());
    CAPTURE(refused.out);
    CHECK(refused.code == 3);
    CHECK(refused.out.find("refused") != std::string::npos);
    CHECK(refused.out.find("strict_sampling") != std::string::npos);
    // The same system without strict mode computes (and flags) it: exit 0.
    CHECK(qdo_run("psf " + cfg_arg() + " --design lens:450 --out " + (dir / "lax").string()).code == 0);
    // 4: a device error, here no OpenCL platform at all (an empty ICD vendor directory), on a command
    // that needs the device (test_cli checks the message for `qdo devices`).
    fs::create_directories(dir / "no_vendors");
    const Run nodev = qdo_run("psf " + cfg_arg() + " --design flat --out " + (dir / "nodev").string(),
                              "OCL_ICD_VENDORS=" + (dir / "no_vendors").string());
    CAPTURE(nodev.out);
    CHECK(nodev.code == 4);
    CHECK(nodev.out.find("device error") != std::string::npos);
    // 2 as well: an output folder that cannot be created (a regular file in its path) names --out.
    std::ofstream(dir / "a_file") << "x";
    const Run other = qdo_run("psf " + cfg_arg() + " --design flat --out " + (dir / "a_file" / "sub").string());
    CAPTURE(other.out);
    CHECK(other.code == 2);
    CHECK(other.out.find("argument '--out'") != std::string::npos);
    CHECK(other.out.find("a folder that can be created") != std::string::npos);
    // 5 (gradient check failed): see the gradcheck case.
    fs::remove_all(dir);
  }

  TEST_CASE("qdo design refuses a run folder another process writes, naming its pid; a holder killed by kill -9 blocks nothing") {
    const auto dir = temp_dir("cmd_lock");
    const std::string run = (dir / "run").string();
    const std::string design = "design " + cfg_arg() +
                               " --mode qdo --levels 4 --epochs 5 --steps-per-epoch 2 --t0 1 --t1 4 --synthetic-scenes 3 --seed 3";
    REQUIRE(qdo_run(design + " --max-steps 1 --out " + run).code == 0);
    const std::string me = "pid " + std::to_string(::getpid());
    {
      // This process holds the folder (the API qdo design uses): a fresh design and a resume
      // into it are both refused, exit 2, with the holder's pid.
      const RunLock held(run);
      const Run resumed = qdo_run(design + " --resume --max-steps 2 --out " + run);
      CAPTURE(resumed.out);
      CHECK(resumed.code == 2);
      CHECK(resumed.out.find(me) != std::string::npos);
      CHECK(resumed.out.find("'out'") != std::string::npos);
      fs::create_directories(dir / "empty");
      const RunLock held2((dir / "empty").string());
      const Run fresh = qdo_run(design + " --max-steps 1 --out " + (dir / "empty").string());
      CAPTURE(fresh.out);
      CHECK(fresh.code == 2);
      CHECK(fresh.out.find(me) != std::string::npos);
      CHECK_FALSE(fs::exists(dir / "empty" / "config.json"));
    }
    // A holder killed with kill -9 while holding the lock (a child process that takes the same
    // flock and waits): the kernel releases it, the stale .lock file with its pid remains, and
    // --resume goes on.
    int ready[2];
    REQUIRE(::pipe(ready) == 0);
    const std::string lock_path = run + "/.lock";
    const pid_t child = ::fork();
    REQUIRE(child >= 0);
    if (child == 0) {  // only async-signal-safe calls after fork
      const int fd = ::open(lock_path.c_str(), O_RDWR | O_CREAT, 0644);
      if (fd < 0 || ::flock(fd, LOCK_EX | LOCK_NB) != 0) ::_exit(1);
      char c = 'x';
      if (::write(ready[1], &c, 1) != 1) ::_exit(1);
      for (;;) ::pause();
    }
    ::close(ready[1]);
    char c = 0;
    REQUIRE(::read(ready[0], &c, 1) == 1);
    ::close(ready[0]);
    const Run blocked = qdo_run(design + " --resume --max-steps 2 --out " + run);
    CHECK(blocked.code == 2);
    ::kill(child, SIGKILL);
    int st = 0;
    ::waitpid(child, &st, 0);
    const Run resumed = qdo_run(design + " --resume --max-steps 2 --out " + run);
    CAPTURE(resumed.out);
    CHECK(resumed.code == 0);
    CHECK(csv_rows(fs::path(run) / "log.csv") == 2);
    fs::remove_all(dir);
  }

  TEST_CASE("qdo design --resume refuses options that differ from the run's config.json, naming each") {
    const auto dir = temp_dir("cmd_resume_opts");
    const std::string run = (dir / "run").string();
    const std::string design = "design " + cfg_arg() +
                               " --mode qdo --levels 4 --epochs 5 --steps-per-epoch 2 --t0 1 --t1 4 --synthetic-scenes 3 --seed 3";
    REQUIRE(qdo_run(design + " --lr 0.01 --max-steps 1 --out " + run).code == 0);
    const std::string before = slurp(fs::path(run) / "checkpoint.h5");
    const Run lr = qdo_run(design + " --lr 0.02 --resume --max-steps 2 --out " + run);
    CAPTURE(lr.out);
    CHECK(lr.code == 2);
    CHECK(lr.out.find("--lr: stored 0.01, given 0.02") != std::string::npos);
    // Several at once, each named; nothing in the folder changed.
    const Run many = qdo_run("design " + cfg_arg() + " --mode do --levels 8 --epochs 9 --resume --out " + run);
    CAPTURE(many.out);
    CHECK(many.code == 2);
    CHECK(many.out.find("--mode: stored \"qdo\", given \"do\"") != std::string::npos);
    CHECK(many.out.find("--levels: stored 4, given 8") != std::string::npos);
    CHECK(many.out.find("--epochs: stored 5, given 9") != std::string::npos);
    // Another system (--preset small instead of the tiny --config): the differing fields are named.
    const Run sys = qdo_run("design --preset small --resume --out " + run);
    CAPTURE(sys.out);
    CHECK(sys.code == 2);
    CHECK(sys.out.find("--preset: system.") != std::string::npos);
    CHECK(slurp(fs::path(run) / "checkpoint.h5") == before);
    CHECK(csv_rows(fs::path(run) / "log.csv") == 1);
    // The same options (and --max-steps, which may change) go on; so does a bare --resume.
    const Run same = qdo_run(design + " --lr 0.01 --resume --max-steps 2 --out " + run);
    CAPTURE(same.out);
    CHECK(same.code == 0);
    CHECK(csv_rows(fs::path(run) / "log.csv") == 2);
    const Run bare = qdo_run("design --resume --max-steps 3 --out " + run);
    CAPTURE(bare.out);
    CHECK(bare.code == 0);
    CHECK(csv_rows(fs::path(run) / "log.csv") == 3);
    fs::remove_all(dir);
  }

  TEST_CASE("qdo demo deletes nothing it did not make: a user's files in DIR/do or DIR/qdoa are refused, exit 2") {
    const auto dir = temp_dir("cmd_demo_owned");
    fs::create_directories(dir / "do");
    std::ofstream(dir / "do" / "notes.txt") << "mine";
    const Run r = qdo_run("demo --preset small --levels 2 --epochs 2 --steps-per-epoch 1 --data " + (dir / "no_cave").string() +
                          " --out " + dir.string());
    CAPTURE(r.out);
    CHECK(r.code == 2);
    CHECK(r.out.find((dir / "do").string()) != std::string::npos);
    CHECK(slurp(dir / "do" / "notes.txt") == "mine");
    CHECK_FALSE(fs::exists(dir / "qdoa"));  // checked before any work
    // A file where demo's run folder would go is refused too.
    fs::remove_all(dir / "do");
    std::ofstream(dir / "qdoa") << "also mine";
    const Run f = qdo_run("demo --preset small --levels 2 --epochs 2 --steps-per-epoch 1 --out " + dir.string());
    CHECK(f.code == 2);
    CHECK(slurp(dir / "qdoa") == "also mine");
    fs::remove_all(dir);
  }

  TEST_CASE("qdo demo at the smallest size it accepts writes its runs, evaluations and summary") {
    const auto dir = temp_dir("cmd_demo");
    // demo has no --config: the small preset (N = 256, 31 bands) is its smallest system; 2 epochs of
    // 1 step each is its smallest schedule. --data names a missing folder so the CAVE rows are left out.
    const Run r = qdo_run("demo --preset small --levels 2 --epochs 2 --steps-per-epoch 1 --data " + (dir / "no_cave").string() +
                          " --out " + dir.string());
    CAPTURE(r.out);
    REQUIRE(r.code == 0);
    for (const char* run : {"qdoa", "do"}) {
      CAPTURE(run);
      CHECK(csv_rows(dir / run / "log.csv") == 2);
      const Design d = read_design((dir / run / "design.h5").string());
      CHECK(d.height_m.rows == 256);
      CHECK(d.levels_m.size() == 2);
      CHECK(std::set<double>(d.height_m.data.begin(), d.height_m.data.end()).size() <= 2);
    }
    CHECK(design_run_options_from_json(slurp(dir / "qdoa" / "config.json"), "qdoa").design.mode == DesignMode::QDOA);
    CHECK(design_run_options_from_json(slurp(dir / "do" / "config.json"), "do").design.mode == DesignMode::DO);
    // Four evaluation cells on the synthetic test set, each with finite metrics, none on CAVE.
    std::size_t cells = 0;
    for (const auto& e : fs::directory_iterator(dir / "eval")) {
      const std::string name = e.path().filename().string();
      CAPTURE(name);
      CHECK(name.find("_synthetic") != std::string::npos);
      const json m = read_json(e.path() / "metrics.json");
      CHECK(std::isfinite(m.at("mean").at("psnr_db").get<double>()));
      ++cells;
    }
    CHECK(cells == 4);
    const std::string md = slurp(dir / "summary.md");
    CHECK(md.find("# qdo demo") != std::string::npos);
    std::size_t rows = 0;
    for (std::size_t at = md.find("| synthetic |"); at != std::string::npos; at = md.find("| synthetic |", at + 1)) ++rows;
    CHECK(rows == 4);
    CHECK(md.find("CAVE") == std::string::npos);
    CHECK(fs::file_size(dir / "chart_scene.png") > 100);
    CHECK(fs::file_size(dir / "chart_sensor_qdoa.png") > 100);
    // A rerun over its own output replaces its run files and keeps anything else put there.
    std::ofstream(dir / "do" / "notes.txt") << "mine";
    const Run again = qdo_run("demo --preset small --levels 2 --epochs 2 --steps-per-epoch 1 --data " + (dir / "no_cave").string() +
                              " --out " + dir.string());
    CAPTURE(again.out);
    CHECK(again.code == 0);
    CHECK(slurp(dir / "do" / "notes.txt") == "mine");
    CHECK(csv_rows(dir / "do" / "log.csv") == 2);
    // --epochs below 2 is refused (input error) before any device work.
    const Run one = qdo_run("demo --epochs 1 --out " + (dir / "x").string());
    CHECK(one.code == 2);
    CHECK(one.out.find("--epochs") != std::string::npos);
    fs::remove_all(dir);
  }
}
