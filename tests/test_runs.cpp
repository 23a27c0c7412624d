// `qdo design` run folders and `qdo eval`: resume equals an uninterrupted run, L fabricated
// heights, no half-written outputs after a failure, corrupt checkpoints named, eval outputs.
#include <hdf5.h>

#include <chrono>
#include <cstring>
#include <fstream>
#include <iterator>
#include <set>
#include <thread>

#include <fcntl.h>
#include <sys/file.h>
#include <sys/wait.h>
#include <unistd.h>

#include <nlohmann/json.hpp>

#include "common.hpp"
#include "qdo/design/run_folder.hpp"
#include "qdo/design/design_run.hpp"
#include "qdo/evaluate/eval.hpp"
#include "qdo/design/gradcheck.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"
#include "qdo/design/run.hpp"

using namespace qdo;
using namespace qdo::test;

namespace {

DesignRunOptions tiny_run(const std::string& out, DesignMode mode) {
  DesignRunOptions o;
  o.cfg = tiny_config(32, 3);
  o.design.mode = mode;
  o.design.quantizer.levels = 4;
  o.design.steps_per_epoch = 2;
  o.design.t0_epochs = 1;
  o.design.t1_epochs = 4;
  o.design.seed = 5;
  o.epochs = 5;
  o.synthetic_scenes = 3;
  o.checkpoint_every = 3;
  o.precision = runtime().has_fp64() ? Precision::F64 : Precision::F32;
  o.out = out;
  o.quiet = true;
  return o;
}

}  // namespace

TEST_SUITE("runs") {
  TEST_CASE("the PSF path is saved with a run; runs saved before it existed resume on the 2-D path") {
    DesignRunOptions o;
    o.cfg = preset_config("small");
    for (PsfPath p : {PsfPath::Auto, PsfPath::TwoD, PsfPath::Radial}) {
      o.design.psf_path = p;
      const DesignRunOptions back = design_run_options_from_json(design_run_options_to_json(o), "test");
      CHECK(back.design.psf_path == p);
    }
    // An older config.json has no "psf_path": it ran (and must resume) on the 2-D path.
    auto j = nlohmann::json::parse(design_run_options_to_json(o));
    j["design"].erase("psf_path");
    CHECK(design_run_options_from_json(j.dump(), "old").design.psf_path == PsfPath::TwoD);
    j["design"]["psf_path"] = "hankel";
    CHECK_THROWS_AS(design_run_options_from_json(j.dump(), "bad"), InputError);
  }

  TEST_CASE("where the wiener objective runs is saved with a run; runs saved before the device objective resume on the CPU") {
    DesignRunOptions o;
    o.cfg = preset_config("small");
    o.out = "x";
    for (const char* w : {"device", "cpu"}) {
      o.wiener_on = wiener_on_from_string(w);
      CHECK(to_string(design_run_options_from_json(design_run_options_to_json(o), "test").wiener_on) == w);
    }
    auto j = nlohmann::json::parse(design_run_options_to_json(o));
    j["design"].erase("wiener_on");
    CHECK(design_run_options_from_json(j.dump(), "old").wiener_on == WienerOn::Cpu);
    CHECK_THROWS_WITH_AS(wiener_on_from_string("gpu"), doctest::Contains("wiener_on"), InputError);
    j["design"]["wiener_on"] = "gpu";
    CHECK_THROWS_WITH_AS(design_run_options_from_json(j.dump(), "bad"), doctest::Contains("wiener_on"), InputError);
  }

  TEST_CASE("typed options read and write the strings config.json holds; bad ones named with the option") {
    for (const char* v : {"wiener", "wiener-mse", "wiener-mae", "psf-target", "network"}) CHECK(to_string(objective_from_string(v)) == v);
    CHECK_THROWS_WITH_AS(objective_from_string("mse", "--objective"), doctest::Contains("'--objective' = mse"), InputError);
    for (const char* v : {"random", "flat", "lens:550", "lens:550.0", "lens:632.8", "lens:5.5e2"}) CHECK(init_spec_from_string(v).to_string() == v);
    CHECK(init_spec_from_string("lens:5.5e2").wavelength_nm == 550);
    InitSpec lens;
    lens.kind = InitSpec::Kind::Lens;
    lens.wavelength_nm = 632.8;  // made in code: the shortest plain decimal
    CHECK(lens.to_string() == "lens:632.8");
    lens.wavelength_nm = 550;
    CHECK(lens.to_string() == "lens:550");
    for (const char* bad : {"lens:abc", "lens:", "lens:99", "lens:1e999", "spiral"})
      CHECK_THROWS_WITH_AS(init_spec_from_string(bad, "--init"), doctest::Contains("'--init'"), InputError);
    for (const char* v : {"", "lens:500", "some/design.h5"}) CHECK(target_spec_from_string(v).to_string() == v);
    CHECK(target_spec_from_string("some/design.h5").kind == TargetSpec::Kind::File);
    CHECK_THROWS_WITH_AS(target_spec_from_string("lens:x"), doctest::Contains("'target'"), InputError);
    // Through config.json: every typed option as written, and a bad stored one named with the file.
    DesignRunOptions o;
    o.cfg = preset_config("small");
    o.out = "x";
    o.objective = Objective::PsfTarget;
    o.target = target_spec_from_string("lens:550.0");
    o.init = init_spec_from_string("lens:632.8");
    auto j = nlohmann::json::parse(design_run_options_to_json(o));
    CHECK(j["design"]["objective"] == "psf-target");
    CHECK(j["design"]["target"] == "lens:550.0");
    CHECK(j["design"]["init"] == "lens:632.8");
    CHECK(j["design"]["decoder"] == "wiener");
    CHECK(design_run_options_to_json(design_run_options_from_json(j.dump(), "mem")) == design_run_options_to_json(o));
    j["design"]["init"] = "lens:abc";
    CHECK_THROWS_WITH_AS(design_run_options_from_json(j.dump(), "RUN/config.json"),
                         doctest::Contains("file 'RUN/config.json': argument 'init' = lens:abc"), InputError);
  }

  TEST_CASE("a design run with the wiener objective on the device follows the CPU objective's run") {
    if (!skip_unless(runtime().has_fp64(), "the device objective needs float64 for its solve")) return;
    const auto dir = temp_dir("runs_wiener_on");
    std::vector<double> final_loss;
    std::vector<std::vector<double>> levels;
    for (const char* w : {"device", "cpu"}) {
      DesignRunOptions o = tiny_run((dir / w).string(), DesignMode::QDOA);
      o.wiener_on = wiener_on_from_string(w);
      const DesignRunResult r = run_design(runtime(), o, false);
      final_loss.push_back(r.final_loss);
      levels.push_back(r.levels_m);
    }
    // float64 throughout: the two objectives differ by round-off amplified by the solve (the
    // wiener-device suite bounds it), so ten Adam steps end at the same point to ~1e-9.
    CHECK(final_loss[0] == doctest::Approx(final_loss[1]).epsilon(1e-9));
    REQUIRE(levels[0].size() == levels[1].size());
    for (std::size_t l = 0; l < levels[0].size(); ++l) CHECK(levels[0][l] == doctest::Approx(levels[1][l]).epsilon(1e-9));
    std::filesystem::remove_all(dir);
  }

  TEST_CASE("a run's config.json with a key given twice is refused, naming the key path and the file") {
    DesignRunOptions o;
    o.cfg = preset_config("small");
    const std::string text = design_run_options_to_json(o);
    // Repeat "levels" inside "design" and "n" inside "system" (text edits: nlohmann keeps one).
    const std::size_t at = text.find("\"levels\"");
    REQUIRE(at != std::string::npos);
    const std::string twice = text.substr(0, at) + "\"levels\": 2, " + text.substr(at);
    CHECK_THROWS_WITH_AS(design_run_options_from_json(twice, "run/config.json"),
                         doctest::Contains("file 'run/config.json': duplicate key 'design.levels'"), InputError);
    const std::size_t n_at = text.find("\"n\"");
    REQUIRE(n_at != std::string::npos);
    const std::string n_twice = text.substr(0, n_at) + "\"n\": 64, " + text.substr(n_at);
    CHECK_THROWS_WITH_AS(design_run_options_from_json(n_twice, "run/config.json"), doctest::Contains("duplicate key 'system.n'"),
                         InputError);
    CHECK(design_run_options_from_json(text, "run/config.json").cfg.n == o.cfg.n);
  }

  TEST_CASE("a run's config.json with a value the option parsers refuse, or a non-integer count, is refused naming the file") {
    // Found while writing the run_folder fuzz target: a stored mode, placement or precision the
    // parsers refuse was reported as "argument 'mode' = ..." without the file, a stored value
    // out of range (epochs 0) likewise, and a count stored as 1e300 was converted to int
    // (undefined behaviour).
    DesignRunOptions o;
    o.cfg = preset_config("small");
    const std::string text = design_run_options_to_json(o);
    auto edit = [&](const std::string& from, const std::string& to) {
      std::string t = text;
      const std::size_t at = t.find(from);
      REQUIRE(at != std::string::npos);
      return t.replace(at, from.size(), to);
    };
    CHECK_THROWS_WITH_AS(design_run_options_from_json(edit("\"mode\": \"qdo+a\"", "\"mode\": \"bogus\""), "run/config.json"),
                         doctest::Contains("file 'run/config.json': argument 'mode' = bogus"), InputError);
    CHECK_THROWS_WITH_AS(design_run_options_from_json(edit("\"precision\": \"f32\"", "\"precision\": \"f16\""), "run/config.json"),
                         doctest::Contains("file 'run/config.json': argument 'precision'"), InputError);
    for (const char* bad : {"1e300", "-3", "2.5", "\"4\""}) {
      CAPTURE(bad);
      CHECK_THROWS_WITH_AS(design_run_options_from_json(edit("\"levels\": 4", std::string("\"levels\": ") + bad), "run/config.json"),
                           doctest::Contains("file 'run/config.json'"), InputError);
    }
    CHECK_THROWS_WITH_AS(design_run_options_from_json(edit("\"epochs\": 50", "\"epochs\": -1"), "run/config.json"),
                         doctest::Contains("key 'design.epochs' = -1"), InputError);
    // Through the resume loader: a stored value out of range names the file, not an argument.
    const auto dir = temp_dir("runs_cfg_values");
    std::ofstream(dir / "config.json") << edit("\"epochs\": 50", "\"epochs\": 0");
    std::ofstream(dir / "checkpoint.h5") << "x";
    const std::string want = "file '" + (dir / "config.json").string() + "': argument 'epochs' = 0";
    CHECK_THROWS_WITH_AS(load_resume_state(dir.string()), doctest::Contains(want.c_str()), InputError);
    std::filesystem::remove_all(dir);
  }

  TEST_CASE("a resumed run equals an uninterrupted one; the design holds L heights") {
    const auto dir = temp_dir("runs");
    const std::string a = (dir / "a").string(), b = (dir / "b").string();
    run_design(runtime(), tiny_run(a, DesignMode::QDOA), false);
    DesignRunOptions first = tiny_run(b, DesignMode::QDOA);
    first.max_steps = 4;  // "killed" after step 4 (last checkpoint at step 3, then the final one at 4)
    CHECK(run_design(runtime(), first, false).steps_done == 4);
    CHECK_THROWS_WITH_AS(run_design(runtime(), tiny_run(b, DesignMode::QDOA), false), doctest::Contains("--resume"), InputError);
    CHECK(run_design(runtime(), tiny_run(b, DesignMode::QDOA), true).steps_done == 10);
    const std::size_t nw = 16;
    const DesignState sa = load_checkpoint(a + "/checkpoint.h5", nw, 4), sb = load_checkpoint(b + "/checkpoint.h5", nw, 4);
    CHECK(sa.w == sb.w);
    CHECK(sa.offsets == sb.offsets);
    CHECK(sa.adam_w.v == sb.adam_w.v);
    const Design da = read_design(a + "/design.h5"), db = read_design(b + "/design.h5");
    CHECK(da.height_m.data == db.height_m.data);
    const std::set<double> distinct(da.height_m.data.begin(), da.height_m.data.end());
    CHECK(distinct.size() <= 4);
    REQUIRE(da.levels_m.size() == 4);
    for (double v : distinct) CHECK(std::find(da.levels_m.begin(), da.levels_m.end(), v) != da.levels_m.end());
    // The log has one row per step, the resumed one too.
    std::ifstream lf(b + "/log.csv");
    std::size_t lines = 0;
    for (std::string l; std::getline(lf, l);) ++lines;
    CHECK(lines == 11);
    for (const char* f : {"config.json", "prior.h5", "design_full.h5", "psf.h5", "design.png", "psf.png", "loss.png"})
      CHECK(std::filesystem::exists(std::filesystem::path(b) / f));
    // RunFolder names every file the run wrote (demo's rerun cleanup relies on it) and reads its parts.
    const std::vector<std::string>& names = RunFolder::file_names();
    for (const auto& e : std::filesystem::directory_iterator(b)) {
      const std::string f = e.path().filename().string();
      CAPTURE(f);
      CHECK((f == ".lock" || std::find(names.begin(), names.end(), f) != names.end()));
    }
    const RunFolder folder(b);
    CHECK(folder.config().design.quantizer.levels == 4);
    CHECK(folder.design().height_m.data == db.height_m.data);
    const std::size_t s = folder.config().cfg.sensor_size_px();
    CHECK(folder.prior(s).rows == s);
    CHECK_THROWS_WITH_AS(folder.prior(s + 1), doctest::Contains("prior.h5"), InputError);
    CHECK_THROWS_WITH_AS(RunFolder((dir / "none").string()).config(), doctest::Contains("config.json missing"), InputError);
    std::filesystem::remove_all(dir);
  }

  TEST_CASE("a failing run leaves nothing half-written; corrupt checkpoints are named") {
    const auto dir = temp_dir("runs_fail");
    const std::string bad = (dir / "bad.mat").string();
    std::ofstream(bad) << "MATLAB 5.0 MAT-file, truncated";
    DesignRunOptions o = tiny_run((dir / "run").string(), DesignMode::QDO);
    o.data = {bad};
    CHECK_THROWS_WITH_AS(run_design(runtime(), o, false), doctest::Contains("bad.mat"), InputError);
    CHECK_FALSE(std::filesystem::exists(dir / "run" / "design.h5"));
    CHECK_FALSE(std::filesystem::exists(dir / "run" / "config.json"));
    // A truncated checkpoint.
    const std::string run = (dir / "run2").string();
    DesignRunOptions r = tiny_run(run, DesignMode::QDO);
    r.max_steps = 2;
    run_design(runtime(), r, false);
    const auto ck = std::filesystem::path(run) / "checkpoint.h5";
    std::filesystem::resize_file(ck, 300);
    CHECK_THROWS_WITH_AS(run_design(runtime(), tiny_run(run, DesignMode::QDO), true), doctest::Contains("checkpoint.h5"), InputError);
    std::filesystem::remove_all(dir);
  }

  TEST_CASE("a checkpoint whose datasets changed after writing is refused by its checksum") {
    const auto dir = temp_dir("runs_checksum");
    const std::string ck = (dir / "ck.h5").string();
    DesignState st;
    st.w.assign(16, 0.25);
    st.offsets = {0, 0.1, -0.1, 0};
    st.adam_w.m.assign(16, 1e-3);
    st.adam_w.v.assign(16, 1e-6);
    st.step = st.adam_w.t = 12;
    save_checkpoint(ck, st);
    const DesignState back = load_checkpoint(ck, 16, 4);
    CHECK(back.w == st.w);
    CHECK(back.step == 12);
    // One raw byte of one weight flipped on disk (0.25 -> 0.25 * (1 + 2^-44)): still a valid
    // weight, so only the checksum can tell.
    std::string bytes;
    {
      std::ifstream in(ck, std::ios::binary);
      bytes.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
    }
    char pattern[8];
    const double quarter = 0.25;
    std::memcpy(pattern, &quarter, 8);
    const std::size_t at = bytes.find(std::string(pattern, 8));
    REQUIRE(at != std::string::npos);
    bytes[at + 1] = static_cast<char>(bytes[at + 1] ^ 0x01);
    const std::string bad = (dir / "bad.h5").string();
    std::ofstream(bad, std::ios::binary) << bytes;
    CHECK_THROWS_WITH_AS(load_checkpoint(bad, 16, 4), doctest::Contains("bad.h5': checksum mismatch"), InputError);
    // A value overwritten through HDF5 (a valid file whose data changed).
    std::filesystem::copy_file(ck, bad, std::filesystem::copy_options::overwrite_existing);
    {
      const hid_t f = H5Fopen(bad.c_str(), H5F_ACC_RDWR, H5P_DEFAULT);
      REQUIRE(f >= 0);
      const hid_t d = H5Dopen2(f, "/counters", H5P_DEFAULT);
      const double counters[3] = {9, 12, 0};
      REQUIRE(H5Dwrite(d, H5T_NATIVE_DOUBLE, H5S_ALL, H5S_ALL, H5P_DEFAULT, counters) >= 0);
      H5Dclose(d);
      H5Fclose(f);
    }
    CHECK_THROWS_WITH_AS(load_checkpoint(bad, 16, 4), doctest::Contains("checksum mismatch"), InputError);

    // In a run folder: resume refuses the corrupt checkpoint, naming it.
    const std::string run = (dir / "run").string();
    DesignRunOptions r = tiny_run(run, DesignMode::QDO);
    r.max_steps = 2;
    run_design(runtime(), r, false);
    const auto rck = (std::filesystem::path(run) / "checkpoint.h5").string();
    {
      const hid_t f = H5Fopen(rck.c_str(), H5F_ACC_RDWR, H5P_DEFAULT);
      REQUIRE(f >= 0);
      const hid_t d = H5Dopen2(f, "/w", H5P_DEFAULT);
      const hid_t sp = H5Dget_space(d);
      std::vector<double> w(static_cast<std::size_t>(H5Sget_simple_extent_npoints(sp)));
      H5Sclose(sp);
      REQUIRE(H5Dread(d, H5T_NATIVE_DOUBLE, H5S_ALL, H5S_ALL, H5P_DEFAULT, w.data()) >= 0);
      w[0] = w[0] > 0 ? w[0] - 1e-3 : w[0] + 1e-3;
      REQUIRE(H5Dwrite(d, H5T_NATIVE_DOUBLE, H5S_ALL, H5S_ALL, H5P_DEFAULT, w.data()) >= 0);
      H5Dclose(d);
      H5Fclose(f);
    }
    CHECK_THROWS_WITH_AS(run_design(runtime(), tiny_run(run, DesignMode::QDO), true), doctest::Contains("checkpoint.h5': checksum mismatch"),
                         InputError);
    std::filesystem::remove_all(dir);
  }

  TEST_CASE("the previous good checkpoint is kept: a damaged or missing checkpoint resumes from it") {
    const auto dir = temp_dir("runs_prev");
    namespace fs = std::filesystem;
    const std::string a = (dir / "a").string(), b = (dir / "b").string();
    run_design(runtime(), tiny_run(a, DesignMode::QDOA), false);  // uninterrupted: 10 steps
    DesignRunOptions first = tiny_run(b, DesignMode::QDOA);
    first.max_steps = 4;  // checkpoints at steps 3 and 4: checkpoint.h5 (4) and checkpoint.prev.h5 (3)
    run_design(runtime(), first, false);
    const fs::path ck = fs::path(b) / "checkpoint.h5", prev = fs::path(b) / "checkpoint.prev.h5";
    REQUIRE(fs::exists(prev));
    CHECK(checkpoint_prev_path(ck.string()) == prev.string());
    CHECK(load_checkpoint(ck.string(), 16, 4).step == 4);
    CHECK(load_checkpoint(prev.string(), 16, 4).step == 3);
    // Damage checkpoint.h5 (one weight changed through HDF5: only the checksum can tell).
    {
      const hid_t f = H5Fopen(ck.c_str(), H5F_ACC_RDWR, H5P_DEFAULT);
      REQUIRE(f >= 0);
      const hid_t d = H5Dopen2(f, "/w", H5P_DEFAULT);
      std::vector<double> w(16);
      REQUIRE(H5Dread(d, H5T_NATIVE_DOUBLE, H5S_ALL, H5S_ALL, H5P_DEFAULT, w.data()) >= 0);
      w[3] *= 0.5;
      REQUIRE(H5Dwrite(d, H5T_NATIVE_DOUBLE, H5S_ALL, H5S_ALL, H5P_DEFAULT, w.data()) >= 0);
      H5Dclose(d);
      H5Fclose(f);
    }
    const ResumeState rs = load_resume_state(b);  // reads only
    CHECK(rs.state.step == 3);
    CHECK(rs.checkpoint == prev.string());
    CHECK(rs.refused.find("checksum mismatch") != std::string::npos);
    CHECK(rs.log_rows.size() == 3);  // the row of step 4 is redone
    CHECK(fs::exists(ck));
    // Resuming goes on from step 3, sets the damaged file aside, and ends where the uninterrupted run ends.
    CHECK(run_design(runtime(), tiny_run(b, DesignMode::QDOA), true).steps_done == 10);
    CHECK(fs::exists(fs::path(b) / "checkpoint.refused.h5"));
    const DesignState sa = load_checkpoint(a + "/checkpoint.h5", 16, 4), sb = load_checkpoint(ck.string(), 16, 4);
    CHECK(sa.w == sb.w);
    CHECK(sa.offsets == sb.offsets);
    CHECK(sa.adam_w.v == sb.adam_w.v);
    // A kill between keeping the previous checkpoint and writing the new one: no checkpoint.h5.
    fs::remove(ck);
    CHECK(load_resume_state(b).state.step == load_checkpoint(prev.string(), 16, 4).step);
    // Neither loads: the error names checkpoint.h5 (or the folder when it is missing).
    fs::resize_file(prev, 200);
    CHECK_THROWS_AS(load_resume_state(b), InputError);
    fs::copy_file(fs::path(b) / "checkpoint.refused.h5", ck);
    CHECK_THROWS_WITH_AS(load_resume_state(b), doctest::Contains("checkpoint.h5': checksum mismatch"), InputError);
    // A fresh run refuses a folder that holds only a previous checkpoint.
    fs::remove(ck);
    CHECK_THROWS_WITH_AS(run_design(runtime(), tiny_run(b, DesignMode::QDOA), false), doctest::Contains("--resume"), InputError);
    fs::remove_all(dir);
  }

  TEST_CASE("a design run refuses an all-zero training scene, naming it, before writing anything") {
    const auto dir = temp_dir("runs_zero_scene");
    DesignRunOptions o = tiny_run((dir / "run").string(), DesignMode::QDO);
    const std::size_t s = o.cfg.sensor_size_px();
    std::vector<std::string> paths;
    for (int k = 0; k < 3; ++k) {
      paths.push_back((dir / ("zero" + std::to_string(k) + ".h5")).string());
      write_cube(paths.back(), RealStack(o.cfg.bands, 2 * s, 2 * s, 0.0), o.cfg.wavelengths_nm());
    }
    o.data = paths;
    o.data_format = "h5";
    CHECK_THROWS_WITH_AS(run_design(runtime(), o, false), doctest::Contains("an all-zero scene"), InputError);
    CHECK_THROWS_WITH_AS(run_design(runtime(), o, false), doctest::Contains("zero"), InputError);
    CHECK_FALSE(std::filesystem::exists(dir / "run" / "design.h5"));
    std::filesystem::remove_all(dir);
  }

  TEST_CASE("a run folder has one writer: a second is refused naming the holder's pid; a released lock blocks nothing") {
    namespace fs = std::filesystem;
    const auto dir = temp_dir("runs_lock");
    const fs::path run = dir / "run";
    fs::create_directories(run);
    const std::string pid = "pid " + std::to_string(::getpid());
    {
      const RunLock held(run.string());
      CHECK(fs::exists(run / ".lock"));
      // Another lock on the same folder (another open file description: as another process would).
      CHECK_THROWS_WITH_AS(RunLock(run.string()), doctest::Contains(pid.c_str()), InputError);
      // A design into the locked folder, fresh or resumed, is refused before writing anything.
      DesignRunOptions o = tiny_run(run.string(), DesignMode::QDO);
      o.max_steps = 1;
      CHECK_THROWS_WITH_AS(run_design(runtime(), o, false), doctest::Contains(pid.c_str()), InputError);
      CHECK_FALSE(fs::exists(run / "config.json"));
      CHECK_FALSE(fs::exists(run / "checkpoint.h5"));
    }
    // Released (the kernel does the same when the holder dies, even by kill -9): the stale
    // .lock file with the old pid in it blocks neither a run nor its resume.
    DesignRunOptions o = tiny_run(run.string(), DesignMode::QDO);
    o.max_steps = 1;
    CHECK(run_design(runtime(), o, false).steps_done == 1);
    CHECK(fs::exists(run / ".lock"));
    o.max_steps = 2;
    CHECK(run_design(runtime(), o, true).steps_done == 2);
    fs::remove_all(dir);
  }

  TEST_CASE("a second writer names the holder's pid even when it looks before the holder has written it") {
    // Regression (stress "two `qdo sweep` at once ..."): the loser of two writers started at
    // once read the .lock file before the winner had written its pid: "locked by pid unknown",
    // or, over a stale file, the pid of an earlier, dead holder. Simulated here: the lock is
    // held through another open file description, the file empty or holding a dead pid, and
    // the holder's pid is written 30 ms later.
    namespace fs = std::filesystem;
    const auto dir = temp_dir("runs_lock_race");
    const std::string lock = (dir / ".lock").string();
    const pid_t dead = [] {  // a pid that no longer exists: a child that has exited and been reaped
      const pid_t c = ::fork();
      if (c == 0) ::_exit(0);
      ::waitpid(c, nullptr, 0);
      return c;
    }();
    const std::string me = std::to_string(::getpid()) + "\n";
    for (const std::string& before : {std::string(), std::to_string(dead) + "\n"}) {
      CAPTURE(before);
      {
        std::ofstream(lock, std::ios::trunc) << before;
      }
      const int fd = ::open(lock.c_str(), O_RDWR);
      REQUIRE(fd >= 0);
      REQUIRE(::flock(fd, LOCK_EX | LOCK_NB) == 0);
      std::thread holder([&] {
        std::this_thread::sleep_for(std::chrono::milliseconds(30));
        CHECK(::pwrite(fd, me.data(), me.size(), 0) == ssize_t(me.size()));
        CHECK(::ftruncate(fd, off_t(me.size())) == 0);
      });
      std::string err;
      try {
        RunLock second(dir.string());
      } catch (const InputError& e) {
        err = e.what();
      }
      holder.join();
      ::close(fd);
      CHECK(err.find("locked by pid " + std::to_string(::getpid()) + " ") != std::string::npos);
      CHECK(err.find("unknown") == std::string::npos);
    }
    fs::remove_all(dir);
  }

  TEST_CASE("eval: metrics and figures; do and do-refit differ exactly in the decoder") {
    const auto dir = temp_dir("eval");
    const std::string run = (dir / "do").string();
    run_design(runtime(), tiny_run(run, DesignMode::DO), false);
    EvalOptions e;
    e.run = run;
    e.synthetic_scenes = 2;
    e.renders = 1;
    e.out = (dir / "mismatch").string();
    e.decoder = DecoderFit::Mismatch;
    const EvalResult mis = evaluate_run(runtime(), e);
    e.out = (dir / "matched").string();
    e.decoder = DecoderFit::Matched;
    const EvalResult mat = evaluate_run(runtime(), e);
    REQUIRE(mis.rows.size() == 2);
    // The mean row is the mean of the per-scene rows, and a plausible reconstruction PSNR.
    CHECK(mis.mean.psnr == doctest::Approx((mis.rows[0].psnr + mis.rows[1].psnr) / 2).epsilon(1e-9));
    CHECK(mis.mean.psnr > 10);
    CHECK(mis.mean.psnr < 60);
    CHECK(mis.deviation_nm == mat.deviation_nm);  // the same quantized DOE is measured
    CHECK(mis.deviation_nm > 0);
    CHECK(mis.mean.psnr != mat.mean.psnr);       // ... decoded by two different filters
    // For the full-precision design the two decoders coincide: identical results.
    e.full_precision = true;
    e.out = (dir / "full_matched").string();
    const EvalResult fm = evaluate_run(runtime(), e);
    e.decoder = DecoderFit::Mismatch;
    e.out = (dir / "full_mismatch").string();
    const EvalResult fmm = evaluate_run(runtime(), e);
    CHECK(fm.mean.psnr == fmm.mean.psnr);
    CHECK(fm.deviation_nm == 0.0);
    for (const char* f : {"metrics.csv", "metrics.json", "reconstructions.h5", "render_0.png", "spectra_0.png"})
      CHECK(std::filesystem::exists(dir / "mismatch" / f));
    std::filesystem::remove_all(dir);
  }

  TEST_CASE("gradcheck passes through the Wiener objectives in every mode") {
    // wiener-mae and the network runs' check go through a smooth stand-in (wiener-mse), named in
    // the rows: a piecewise-linear loss made the check fail on correct gradients.
    for (const char* objective : {"wiener", "wiener-mse", "wiener-mae"})
      for (DesignMode m : {DesignMode::DO, DesignMode::QDO, DesignMode::QDOA, DesignMode::QDOM}) {
        CAPTURE(objective);
        CAPTURE(to_string(m));
        DesignRunOptions o = tiny_run("(unused)", m);
        o.objective = objective_from_string(objective);
        o.batch = 2;
        const auto rows = gradcheck(runtime(), o, 11);
        CHECK(rows.size() >= 4);
        for (const auto& r : rows) {
          CAPTURE(r.group);
          CAPTURE(r.max_rel_error);
          CHECK(r.ok());
          if (std::string(objective) == "wiener-mae" && r.group.find("end to end") != std::string::npos)
            CHECK(r.group.find("a smooth stand-in for wiener-mae") != std::string::npos);
        }
      }
  }
}
