// The qdo commands end to end (doctest suite "commands"): config, design (its run folder, the
// lock against a second writer, --resume with other options), eval and gradcheck, run as a user
// would (the qdo binary through the shell), checking what each one writes.
// The shared run and the tiny configuration are in commands_common.hpp.
#include <nlohmann/json.hpp>

#include <algorithm>
#include <cstdint>
#include <fstream>
#include <set>
#include <sstream>

#include <csignal>
#include <fcntl.h>
#include <sys/file.h>
#include <sys/wait.h>
#include <unistd.h>

#include "commands_common.hpp"
#include "qdo/design/design_run.hpp"
#include "qdo/evaluate/eval.hpp"
#include "qdo/physics/doe.hpp"
#include "qdo/data/io.hpp"
#include "qdo/design/run.hpp"
#include "qdo/physics/simulator.hpp"

using namespace qdo;
using namespace qdo::test;
using namespace qdo::test::commands_suite;
namespace fs = std::filesystem;
using nlohmann::json;

namespace {

std::vector<double> split_doubles(const std::string& s, char sep) {
  std::vector<double> v;
  std::stringstream ss(s);
  std::string item;
  while (std::getline(ss, item, sep)) v.push_back(std::stod(item));
  return v;
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
    REQUIRE(log.header.size() == 8);
    CHECK(log.header[7] == "deviation_nm");
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
    const H5Dataset ps = h5_read((run / "psf.h5").string(), "/psf_sensor");
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
                            "level offsets a (qdo+a, wiener)", "objective wiener vs PSF", "objective wiener on the device (f64)"})
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
}
