// Stability suite (doctest suite "stress", STABILITY.md): long and interrupted design runs.
// 10,000 steps without drift and bit-identical across a mid-run resume; `qdo design` killed
// with kill -9 at any point resumes bit-identically from its last checkpoint, leaving no
// half-written file; a kill between the log and the checkpoint, or a damaged log.csv, loses
// no row and is named.
//
// Cases whose name ends in "[slow]" run under the CTest label "stress" (ctest -L stress);
// the others with the default label (CTest entry "stress-quick").
#include <png.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <random>
#include <set>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "stress_common.hpp"
#include "qdo/design/design.hpp"
#include "qdo/design/design_run.hpp"
#include "qdo/physics/doe.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"
#include "qdo/design/run.hpp"
#include "qdo/design/run_folder.hpp"
#include "qdo/physics/simulator.hpp"

using namespace qdo;
using namespace qdo::test;
using namespace qdo::test::stress_suite;
namespace fs = std::filesystem;

namespace {

// True when the checkpoint at `path` reads and holds a step other than `before` (a file that
// does not read is a failure of the atomic writes and is reported by the caller's checks).
bool load_checkpoint_step_changed(const std::string& path, long before) {
  try {
    return load_checkpoint(path, 16, 4, false, true).step != before;  // the release recipe's pinned top level
  } catch (const InputError& e) {
    FAIL_CHECK("checkpoint unreadable while the run was going: " << std::string(e.what()));  // doctest prints a char* as a pointer
    return true;
  }
}

}  // namespace

TEST_SUITE("stress") {
  TEST_CASE("checkpoint rotation: a kill -9 at any instant of save_checkpoint leaves a complete checkpoint.h5") {
    // Regression: the rotation used to rename checkpoint.h5 to
    // checkpoint.prev.h5 and then write the new one, so a kill in between left no checkpoint.h5.
    // A child process saves checkpoints in a loop (2^16 weights: a few MB per file, so a write
    // takes milliseconds and a kill lands inside one); the parent kills it a seeded random delay
    // after its first new save, 24 times. After every kill checkpoint.h5 loads, its step never goes back, and the
    // previous checkpoint, when there is one, loads too and is older.
    const auto dir = temp_dir("stress_rotation");
    const std::string ck = (dir / "checkpoint.h5").string(), prev = checkpoint_prev_path(ck);
    const std::size_t nw = std::size_t(1) << 16, levels = 4;
    auto state = [&](long step) {
      DesignState s;
      s.w.assign(nw, 0.5 * std::sin(double(step)));
      s.offsets = {0.0, 0.01, 0.02, 0.03};
      s.adam_w.m.assign(nw, 0.0);
      s.adam_w.v.assign(nw, 1e-6);
      s.adam_a.m.assign(levels, 0.0);
      s.adam_a.v.assign(levels, 1e-6);
      s.step = s.adam_w.t = s.adam_a.t = step;
      return s;
    };
    save_checkpoint(ck, state(0));
    std::mt19937_64 rng(31);
    long last = 0;
    int advanced = 0;
    for (int round = 0; round < 24; ++round) {
      CAPTURE(round);
      const pid_t pid = ::fork();
      REQUIRE(pid >= 0);
      if (pid == 0) {  // the child: HDF5 writes only, then never returns into doctest
        try {
          for (long k = last + 1;; ++k) save_checkpoint(ck, state(k));
        } catch (...) {
        }
        ::_exit(1);
      }
      // Wait for the child's first new checkpoint (at most 20 s: a loaded machine), then kill it
      // 0 to 20 ms later, inside one of the following saves.
      for (int t = 0; t < 4000; ++t) {
        DesignState seen;
        if (input_error([&] { seen = load_checkpoint(ck, nw, levels); }).empty() && seen.step > last) break;
        std::this_thread::sleep_for(std::chrono::milliseconds(5));
      }
      std::this_thread::sleep_for(std::chrono::microseconds(long(rng() % 20000)));
      ::kill(pid, SIGKILL);
      int status = 0;
      ::waitpid(pid, &status, 0);
      CHECK((WIFSIGNALED(status) && WTERMSIG(status) == SIGKILL));  // killed mid-loop, not failed
      REQUIRE(fs::exists(ck));
      DesignState now;
      CHECK(input_error([&] { now = load_checkpoint(ck, nw, levels); }).empty());
      CHECK(now.step >= last);
      advanced += now.step > last;
      if (fs::exists(prev)) {
        DesignState before;
        CHECK(input_error([&] { before = load_checkpoint(prev, nw, levels); }).empty());
        CHECK(before.step <= now.step);
      }
      last = now.step;
    }
    CHECK(advanced == 24);  // the child saved before every kill
    // Leftovers of a kill are the next checkpoint (complete or absent) and ".tmp-" files.
    for (const auto& e : fs::directory_iterator(dir)) {
      const std::string name = e.path().filename().string();
      CAPTURE(name);
      CHECK((name == "checkpoint.h5" || name == "checkpoint.prev.h5" || name == "checkpoint.next.h5" ||
             name.find(".tmp-") != std::string::npos));
    }
    fs::remove_all(dir);
  }

  TEST_CASE("a checkpoint read while its run saves the next one reads one whole checkpoint, every time") {
    // Under load, a reader (a sweep's collect, a resume check, this suite) read each dataset
    // through its own open of checkpoint.h5 and so mixed two checkpoints when the run renamed the
    // next one in between: "checksum mismatch". A child saves in a loop while the parent reads 300
    // times; every read loads, its step never goes back, and its datasets belong to that step.
    const auto dir = temp_dir("stress_read_while_saving");
    const std::string ck = (dir / "checkpoint.h5").string();
    const std::size_t nw = std::size_t(1) << 14, levels = 4;
    auto state = [&](long step) {
      DesignState s;
      s.w.assign(nw, 0.5 * std::sin(double(step)));
      s.offsets = {0.0, 0.01, 0.02, 0.03};
      s.adam_w.m.assign(nw, double(step));
      s.adam_w.v.assign(nw, 1e-6);
      s.adam_a.m.assign(levels, double(step));
      s.adam_a.v.assign(levels, 1e-6);
      s.step = s.adam_w.t = s.adam_a.t = step;
      return s;
    };
    save_checkpoint(ck, state(0));
    const pid_t pid = ::fork();
    REQUIRE(pid >= 0);
    if (pid == 0) {  // the child: HDF5 writes only, then never returns into doctest
      try {
        for (long k = 1;; ++k) save_checkpoint(ck, state(k));
      } catch (...) {
      }
      ::_exit(1);
    }
    long last = 0, changed = 0;
    std::string first_error;
    for (int i = 0; i < 300; ++i) {
      DesignState seen;
      const std::string err = input_error([&] { seen = load_checkpoint(ck, nw, levels); });
      if (!err.empty()) {
        if (first_error.empty()) first_error = err;
        continue;
      }
      CHECK(seen.step >= last);
      CHECK(seen.adam_w.m.front() == double(seen.step));  // the datasets of one checkpoint
      changed += seen.step != last;
      last = seen.step;
    }
    ::kill(pid, SIGKILL);
    int status = 0;
    ::waitpid(pid, &status, 0);
    CHECK_MESSAGE(first_error.empty(), first_error);
    CHECK(changed > 0);  // the reads overlapped the saves
    fs::remove_all(dir);
  }

  TEST_CASE("a run killed between its log write and its checkpoint keeps every log row after resuming") {
    // Regression: the checkpoint used to be saved before log.csv, so a kill between the two lost
    // the rows in between for good. Now the log is written first; a kill in the new window
    // leaves the log ahead of the checkpoint, and the resume redoes those rows. Reproduced here
    // by restoring the previous checkpoint after a completed segment.
    const auto dir = temp_dir("stress_logloss");
    DesignRunOptions o;
    o.cfg = tiny_config(32, 3);
    o.objective = Objective::PsfTarget;
    o.target = target_spec_from_string("lens:500");
    o.design.steps_per_epoch = 2;
    o.design.t0_epochs = 1;
    o.design.t1_epochs = 3;
    o.epochs = 6;
    o.checkpoint_every = 3;
    o.out = (dir / "run").string();
    o.quiet = true;
    o.max_steps = 3;
    run_design(runtime(), o, false);
    const std::string old_ckpt = slurp(o.out + "/checkpoint.h5");
    o.max_steps = 6;
    run_design(runtime(), o, true);  // log rows up to step 5 written ...
    spit(o.out + "/checkpoint.h5", old_ckpt);  // ... and killed before the step-6 checkpoint was
    o.max_steps = -1;
    run_design(runtime(), o, true);
    std::istringstream in(slurp(o.out + "/log.csv"));
    std::size_t lines = 0;
    for (std::string l; std::getline(in, l);) ++lines;
    CHECK(lines == 1 + 12);  // header + one row per step
    fs::remove_all(dir);
  }

  TEST_CASE("a run folder with a corrupt log.csv resumes or fails with an InputError naming it") {
    // Regression: a damaged log.csv used to throw std::invalid_argument ("stol"); now an
    // InputError names RUN/log.csv and the line.
    const auto dir = temp_dir("stress_log");
    DesignRunOptions o;
    o.cfg = tiny_config(32, 3);
    o.objective = Objective::PsfTarget;
    o.target = target_spec_from_string("lens:500");
    o.design.steps_per_epoch = 2;
    o.design.t0_epochs = 1;
    o.design.t1_epochs = 2;
    o.epochs = 3;
    o.checkpoint_every = 2;
    o.max_steps = 2;
    o.out = (dir / "run").string();
    o.quiet = true;
    run_design(runtime(), o, false);
    spit(o.out + "/log.csv", "step,loss\ngarbage\n");
    o.max_steps = -1;
    CHECK(has(input_error([&] { run_design(runtime(), o, true); }), "log.csv"));
    fs::remove_all(dir);
  }

  TEST_CASE("10,000 design steps: no drift in the invariants; same seed, same bits; a mid-run resume is bit-identical [slow]") {
    // N = 32, 3 bands, float32 (the design default), qdo+a with offsets, L_aq, height noise and
    // a constant learning rate, so the design keeps moving for all 10,000 steps.
    const SystemConfig c = tiny_config(32, 3);
    RealStack target;
    {
      Simulator t(runtime(), c, Precision::F32);
      t.set_heights(lens_design(c, 500));
      t.compute_psf();
      target = t.psf_sensor();
    }
    const PsfObjective obj = psf_target_objective(target);
    DesignOptions o;
    o.mode = DesignMode::QDOA;
    o.parameterization = Parameterization::Radial;
    o.quantizer.levels = 4;
    o.steps_per_epoch = 100;
    o.t0_epochs = 5;
    o.t1_epochs = 40;
    o.lr_optics = 2e-3;
    o.lr_offsets = 2e-3;
    o.lr_decay_per_epoch = 1.0;
    o.beta_aq = 0.01;
    o.height_noise_m = 5e-9;
    o.seed = 11;
    const long steps = 10000, half = 5000;
    std::vector<double> start(parameter_count(o.parameterization, c.n));
    {
      std::mt19937_64 rng(5);
      for (double& v : start) v = (0.2 + 0.6 * double(rng() >> 11) * 0x1.0p-53) * c.h_max_m();
    }
    Simulator sim(runtime(), c, Precision::F32);
    Designer d(sim, o);
    DesignState s = d.initial_state(start);
    double first_loss = 0, last_loss = 0;
    std::size_t nonfinite = 0;
    for (long k = 0; k < steps; ++k) {
      const StepReport r = d.step(s, obj);
      if (k == 0) first_loss = r.loss;
      last_loss = r.loss;
      nonfinite += !std::isfinite(r.loss) || !std::isfinite(r.loss_aq);
      if ((k + 1) % 1000 == 0) {
        CAPTURE(k + 1);
        CHECK(s.step == k + 1);
        CHECK(s.adam_w.t == k + 1);
        CHECK(std::all_of(s.w.begin(), s.w.end(), [](double w) { return w >= -1 && w <= 1; }));
        CHECK(s.offsets[0] == 0.0);
        CHECK(std::all_of(s.offsets.begin(), s.offsets.end(), [](double a) { return std::fabs(a) <= 1; }));
        CHECK(std::all_of(s.adam_w.v.begin(), s.adam_w.v.end(), [](double v) { return v >= 0 && std::isfinite(v); }));
        CHECK(all_finite(s.adam_w.m));
        sim.set_heights(d.training_heights(s));
        sim.compute_psf();
        check_unit_planes(sim.psf_sensor(), 2e-5, "design PSF");
        const Map2D fab = d.fabricated_heights(s);
        const std::set<double> distinct(fab.data.begin(), fab.data.end());
        CHECK(distinct.size() <= 4);
      }
    }
    CHECK(nonfinite == 0);
    CAPTURE(first_loss);
    CAPTURE(last_loss);
    CHECK(last_loss < first_loss);
    MESSAGE("loss " << first_loss << " -> " << last_loss << " after " << steps << " steps");
    // Gradients at the final state still match central differences (float64 kernels).
    {
      Simulator s64(runtime(), c, Precision::F64);
      DesignOptions o64 = o;
      o64.height_noise_m = 0;
      Designer d64(s64, o64);
      const auto g = d64.gradient(s, obj);
      for (std::size_t k : {2ul, 7ul, 12ul}) {
        DesignState a = s, b = s;
        a.w[k] = std::min(1.0, a.w[k] + 1e-7);
        b.w[k] = std::max(-1.0, b.w[k] - 1e-7);
        const double fd = (d64.gradient(a, obj).report.loss - d64.gradient(b, obj).report.loss) / (a.w[k] - b.w[k]);
        CAPTURE(k);
        CHECK(std::fabs(fd - g.g_w[k]) <= 1e-4 * std::fabs(g.g_w[k]) + 1e-8);
      }
    }
    // Same seed, same device and build: bit-identical, also across a checkpoint round trip and
    // a fresh Simulator / Designer at step 5,000.
    const auto dir = temp_dir("stress_long");
    const std::string ck = (dir / "checkpoint.h5").string();
    {
      Simulator sim2(runtime(), c, Precision::F32);
      Designer d2(sim2, o);
      DesignState s2 = d2.initial_state(start);
      for (long k = 0; k < half; ++k) d2.step(s2, obj);
      save_checkpoint(ck, s2);
    }
    Simulator sim3(runtime(), c, Precision::F32);
    Designer d3(sim3, o);
    DesignState s3 = load_checkpoint(ck, s.w.size(), 4);
    for (long k = half; k < steps; ++k) d3.step(s3, obj);
    CHECK(s3.step == s.step);
    CHECK(s3.w == s.w);
    CHECK(s3.offsets == s.offsets);
    CHECK(s3.adam_w.m == s.adam_w.m);
    CHECK(s3.adam_w.v == s.adam_w.v);
    CHECK(s3.adam_a.v == s.adam_a.v);
    fs::remove_all(dir);
  }

  TEST_CASE("kill -9 of `qdo design` at any point: the last checkpoint loads and resumes bit-identically, no half-written file [slow]") {
    const auto dir = temp_dir("stress_kill");
    const std::string cfg = (dir / "cfg.json").string();
    write_text_atomic(cfg, config_to_json_text(tiny_config(32, 3)));
    auto args = [&](const std::string& out, bool resume) {
      // The default recipe (release): height noise per step, the top level pinned (load_checkpoint's pin_top).
      std::vector<std::string> a = {QDO_QDO_BINARY, "design", "--config", cfg, "--mode", "qdo+a", "--levels", "4", "--recipe", "release",
                                    "--objective", "psf-target", "--target", "lens:500", "--init", "random", "--seed", "3",
                                    "--epochs", "30", "--steps-per-epoch", "10", "--t0", "3", "--t1", "20",
                                    "--checkpoint-every", "7", "--precision", "f64", "--out", out};
      if (resume) a.push_back("--resume");
      return a;
    };
    const std::string log = (dir / "log.txt").string();
    const std::string ref_run = (dir / "ref").string(), run = (dir / "run").string();
    {
      Child ref(args(ref_run, false), log);
      REQUIRE(ref.exit_code() == 0);
    }
    const long total = 300;
    // Everything in the run folder that is not a temporary file is complete and readable.
    auto check_folder = [&](int round) {
      CAPTURE(round);
      std::size_t temps = 0;
      if (!fs::exists(run)) return;  // killed before the folder was made
      for (const auto& e : fs::directory_iterator(run)) {
        const std::string f = e.path().string(), name = e.path().filename().string();
        CAPTURE(name);
        if (name.find(".tmp-") != std::string::npos) {
          ++temps;  // a write the kill interrupted: never under the final name
          continue;
        }
        if (name == "checkpoint.h5") {
          CHECK(input_error([&] { load_checkpoint(f, 16, 4, false, true); }).empty());
        } else if (name == "design.h5" || name == "design_full.h5") {
          CHECK(input_error([&] { read_design(f); }).empty());
        } else if (name == "psf.h5") {
          CHECK(input_error([&] { read_psf_stack_file(f); }).empty());
        } else if (name == "prior.h5") {
          CHECK(input_error([&] { h5_has(f, "/cov"); }).empty());
        } else if (name == "config.json") {
          CHECK(input_error([&] { design_run_options_from_json(slurp(f), f); }).empty());
        } else if (name == "log.csv") {
          const std::string text = slurp(f);
          CHECK((!text.empty() && text.back() == '\n'));
          std::istringstream in(text);
          std::string line;
          std::getline(in, line);
          CHECK(line.rfind("step,", 0) == 0);
          long prev = -1, rows = 0;  // rows are numbered from step 0
          while (std::getline(in, line)) {
            const long st = std::stol(line.substr(0, line.find(',')));
            CHECK(st > prev);  // complete rows, in order, none repeated
            CHECK(std::count(line.begin(), line.end(), ',') == 7);
            prev = st;
            ++rows;
          }
          // After the last resume every step has exactly one row (the log is written before the
          // checkpoint, so no kill leaves a gap).
          if (round == 99) CHECK(rows == total);
        } else if (e.path().extension() == ".png") {
          png_image img;
          std::memset(&img, 0, sizeof img);
          img.version = PNG_IMAGE_VERSION;
          bool ok = png_image_begin_read_from_file(&img, f.c_str()) != 0;
          if (ok) {
            img.format = PNG_FORMAT_RGB;
            std::vector<unsigned char> buf(PNG_IMAGE_SIZE(img));
            ok = png_image_finish_read(&img, nullptr, buf.data(), 0, nullptr) != 0;
          }
          png_image_free(&img);
          CHECK(ok);
        }
      }
      if (temps) MESSAGE("round " << round << ": " << temps << " temporary file(s) left by the kill (ignored by resume)");
    };
    // Kill after a growing delay past the latest checkpoint (round 0 also before the first
    // one), resuming from whatever is on disk, until the run completes on its own.
    int kills = 0;
    for (int round = 0; round < 12; ++round) {
      const bool resume = fs::exists(fs::path(run) / "checkpoint.h5");
      long before = -1;
      if (resume) before = load_checkpoint((fs::path(run) / "checkpoint.h5").string(), 16, 4, false, true).step;
      Child child(args(run, resume), log);
      if (round < 8) {
        const auto ck = fs::path(run) / "checkpoint.h5";
        // Wait for the process to make progress (a new checkpoint), or to finish.
        for (int t = 0; t < 6000 && child.running(); ++t) {
          std::error_code ec;
          if (round == 0 && t >= 5) break;  // round 0: early, during start-up
          if (fs::exists(ck, ec) && load_checkpoint_step_changed(ck.string(), before)) break;
          std::this_thread::sleep_for(std::chrono::milliseconds(5));
        }
        std::this_thread::sleep_for(std::chrono::milliseconds(3 * round * round));
        if (child.running()) {
          child.kill9();
          ++kills;
          check_folder(round);
          continue;
        }
      }
      CHECK(child.exit_code() == 0);
      break;
    }
    CHECK(kills >= 4);
    check_folder(99);
    const DesignState a = load_checkpoint(ref_run + "/checkpoint.h5", 16, 4, false, true),
                      b = load_checkpoint(run + "/checkpoint.h5", 16, 4, false, true);
    CHECK(b.step == total);
    CHECK(a.w == b.w);
    CHECK(a.offsets == b.offsets);
    CHECK(a.adam_w.v == b.adam_w.v);
    CHECK(read_design(ref_run + "/design.h5").height_m.data == read_design(run + "/design.h5").height_m.data);
    fs::remove_all(dir);
  }
}
