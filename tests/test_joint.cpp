// Joint training of the optics with a network decoder, the core half (qdo/design/joint.hpp): the patch
// camera, the training batches, the step a JointTrainer takes (their adjoints are rows of the
// adjoint table, QDO_ADJOINT_ROWS joint, defined here), and network runs of qdo design / eval
// (checkpointed network state, bit-identical resume, refusals, do-finetune). The network here is
// a stand-in written in plain C++ (a per-pixel affine map RGB -> bands trained by Adam on the
// MSE), so these run without LibTorch; the Res-UNet itself is tested in tests/net/.
#include <cmath>
#include <cstring>
#include <fstream>
#include <map>
#include <memory>
#include <random>
#include <set>
#include <sstream>

#include <nlohmann/json.hpp>

#include "adjoint_table.hpp"
#include "common.hpp"
#include "joint_common.hpp"
#include "qdo/design/design_run.hpp"
#include "qdo/evaluate/eval.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"
#include "qdo/design/joint.hpp"
#include "qdo/decode/network_decoder.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/design/run.hpp"
#include "qdo/design/run_folder.hpp"
#include "qdo/evaluate/sweep.hpp"

using namespace qdo;
using namespace qdo::test;

namespace {

// A JointTrainer on the tiny configuration (B = 3, S = 16) with the affine stand-in network, in
// float64: step(k, 0, psf, g) leaves the network as it was, so its loss is a function of the PSF.
struct JointStep {
  SystemConfig c = tiny_config(32, 3);
  std::size_t s = c.sensor_size_px();
  AffineNet net{settings()};
  JointData d = load_joint_data(c, {}, "auto", 3, 9);
  JointTrainer trainer{runtime(), c, Precision::F64, net, d, 2, 1e-3, 9};
  static NetworkSettings settings() {
    NetworkSettings ns;
    ns.spec = decoder_spec_from_string("resunet:depth=2,root=4");
    ns.out_channels = 3;
    ns.seed = 1;
    return ns;
  }
};

}  // namespace

// Joint training's rows of the adjoint table (suite `adjoint`, tests/adjoint_table.hpp), on the
// device in float64: the patch camera (PSF -> the images of three patches, linear) against its
// adjoint on the circular (S = 16) and the periodic-extension (S = 22) grids, and the joint step's
// loss against its PSF gradient.
QDO_ADJOINT_ROWS(joint, "joint training") {
  REQUIRE(runtime().has_fp64());  // gradient checks run in double (PoCL has fp64)
  std::vector<Stage> rows;
  for (std::size_t n : {32, 44}) {
    const SystemConfig c = tiny_config(n, 3);
    const std::size_t s = c.sensor_size_px(), k = 3;
    const auto cam = std::make_shared<testset::PatchCamera>(runtime(), c, Precision::F64);
    auto patches = std::make_shared<std::vector<testset::Patch>>();
    for (unsigned i = 0; i < k; ++i) patches->push_back({"p", random_cube(3, s, s, 10 + i)});
    Stage st("patch camera PSF -> " + std::to_string(k) + " patch images, S = " + std::to_string(s), 3 * s * s, k * 3 * s * s);
    st.forward = [cam, patches, s](const std::vector<double>& x) {
      RealStack psf(3, s, s);
      psf.data = x;
      std::vector<double> out;
      for (const RealStack& y : cam->measure(psf, *patches)) {
        REQUIRE(y.size() == 3 * s * s);
        out.insert(out.end(), y.data.begin(), y.data.end());
      }
      return out;
    };
    // The adjoint belongs to the last measure() call (its patches' spectra): measure, then vjp.
    st.vjp = [cam, patches, s, k](const std::vector<double>& x, const std::vector<double>& g) {
      RealStack psf(3, s, s);
      psf.data = x;
      cam->measure(psf, *patches);
      std::vector<RealStack> gs(k, RealStack(3, s, s));
      for (std::size_t i = 0; i < k; ++i) std::copy_n(g.begin() + long(i * 3 * s * s), 3 * s * s, gs[i].data.begin());
      return cam->vjp(gs).data;
    };
    st.jvp = [f = st.forward](const std::vector<double>&, const std::vector<double>& d) { return f(d); };
    // In double through FFTs of S x S: within 1e-12 of the sums' scale.
    st.dot_tol = 1e-12;
    st.lo = 0;
    rows.push_back(st);
  }
  {
    const auto js = std::make_shared<JointStep>();
    Stage st("joint step loss -> PSF (lr 0, affine network)", 3 * js->s * js->s, 1);
    st.forward = [js](const std::vector<double>& x) {
      RealStack psf(3, js->s, js->s), unused;
      psf.data = x;
      return std::vector<double>{js->trainer.step(5, 0.0, psf, unused)};
    };
    st.vjp = [js](const std::vector<double>& x, const std::vector<double>& g) {
      RealStack psf(3, js->s, js->s), grad;
      psf.data = x;
      js->trainer.step(5, 0.0, psf, grad);
      std::vector<double> v = grad.data;
      for (double& e : v) e *= g[0];
      return v;
    };
    st.x0 = random_cube(3, js->s, js->s, 40).data;
    st.g0 = {1.0};
    // A smooth loss in double: step 1e-5 (truncation ~1e-10, rounding ~1e-11 of the loss), along a
    // direction within 1e-7 of the derivative, on an entry within 1e-6 of the gradient's rms.
    st.fd_step = 1e-5;
    st.fd_tol = 0;
    st.dir_rel = 1e-7;
    st.probe_rms = 1e-6;
    rows.push_back(st);
  }
  return rows;
}

TEST_SUITE("joint") {
  TEST_CASE("the patch camera: periodic extension when S is not 7-smooth; one gradient per patch or refused") {
    // Its adjoint, <A psf, g> = <psf, A^T g>, is a row of the adjoint table (QDO_ADJOINT_ROWS joint).
    Runtime& rt = runtime();
    if (!skip_unless(rt.has_fp64(), "float64 device")) return;
    for (std::size_t n : {32, 44}) {  // S = 16 (7-smooth: circular camera), S = 22 = 2 x 11 (periodic extension)
      const SystemConfig c = tiny_config(n, 3);
      const std::size_t s = c.sensor_size_px();
      CAPTURE(s);
      testset::PatchCamera cam(rt, c, Precision::F64);
      CHECK(cam.periodic_extension() == (n == 44));
      std::vector<testset::Patch> patches;
      for (unsigned k = 0; k < 3; ++k) patches.push_back({"p", random_cube(3, s, s, 10 + k)});
      const std::vector<RealStack> y = cam.measure(random_cube(3, s, s, 20), patches);
      REQUIRE(y.size() == 3);
      // The adjoint belongs to one device call: a count that does not match is refused.
      CHECK_THROWS_WITH_AS(cam.vjp({y[0]}), doctest::Contains("one per patch"), InputError);
    }
  }

  TEST_CASE("training batches: S x S windows of the training scenes, flipped or rotated, the same for the same (seed, step)") {
    const SystemConfig c = tiny_config(32, 2);
    const std::size_t s = c.sensor_size_px();
    JointData d;
    RealStack scene(2, 40, 50);
    for (std::size_t b = 0; b < 2; ++b)
      for (std::size_t y = 0; y < 40; ++y)
        for (std::size_t x = 0; x < 50; ++x) scene(b, y, x) = double(b * 100000 + y * 100 + x);
    d.train.push_back(scene);
    const auto a = joint_batch(d, s, 16, 7, 3), b = joint_batch(d, s, 16, 7, 3), c2 = joint_batch(d, s, 16, 7, 4);
    REQUIRE(a.size() == 16);
    bool differs = false;
    for (std::size_t k = 0; k < 16; ++k) {
      CHECK(a[k].data == b[k].data);
      differs = differs || a[k].data != c2[k].data;
      // Band 0 holds 100 y + x: a window [y0, y0+S) x [x0, x0+S) under one of the 8 symmetries
      // has its smallest value at a corner, 100 y0 + x0, and every value of the window once.
      const RealStack& p = a[k];
      const auto mn = *std::min_element(p.data.begin(), p.data.begin() + long(s * s));
      const std::size_t y0 = std::size_t(mn) / 100, x0 = std::size_t(mn) % 100;
      std::multiset<double> want, got(p.data.begin(), p.data.begin() + long(s * s));
      for (std::size_t y = 0; y < s; ++y)
        for (std::size_t x = 0; x < s; ++x) want.insert(double((y0 + y) * 100 + x0 + x));
      CHECK(got == want);
      for (std::size_t i = 0; i < s * s; ++i) CHECK(p.data[s * s + i] == p.data[i] + 100000);  // bands move together
    }
    CHECK(differs);
    // Which symmetry a crop has: the steps from its first pixel to the next along x and along y
    // (+-1: a row of the scene, +-100: a column, i.e. transposed). All 8 appear in 64 draws.
    std::set<std::pair<long, long>> symmetries;
    for (long step = 3; step < 7; ++step)
      for (const RealStack& p : joint_batch(d, s, 16, 7, step))
        symmetries.insert({long(p(0, 0, 1) - p(0, 0, 0)), long(p(0, 1, 0) - p(0, 0, 0))});
    CHECK(symmetries == std::set<std::pair<long, long>>{{1, 100}, {-1, 100}, {1, -100}, {-1, -100},
                                                        {100, 1}, {-100, 1}, {100, -1}, {-100, -1}});
  }

  TEST_CASE("the release's fixed patches: the whole scene resized, then a 3 x 3 grid of crops, in order, unshuffled") {
    const std::size_t s = 16;
    JointData d;
    for (auto [h, w] : {std::pair<std::size_t, std::size_t>{40, 50}, {30, 30}}) {
      RealStack scene(2, h, w);
      for (std::size_t b = 0; b < 2; ++b)
        for (std::size_t y = 0; y < h; ++y)
          for (std::size_t x = 0; x < w; ++x) scene(b, y, x) = double(b * 100000 + y * 100 + x);
      d.train.push_back(scene);
    }
    const std::vector<FixedPatch> list = fixed_patches(d, s);
    REQUIRE(list.size() == 20);
    // Scene 0 (40 x 50): rows range(0, 40, 14) = 0, 14, 28 -> 24 inside; columns range(0, 50, 17) = 0, 17, 34.
    // Scene 1 (30 x 30): range(0, 30, 10) = 0, 10, 20 -> 14.
    const std::vector<std::size_t> r0 = {0, 14, 24}, c0 = {0, 17, 34}, r1 = {0, 10, 14};
    for (std::size_t sc = 0; sc < 2; ++sc) {
      const FixedPatch& whole = list[sc * 10];
      CHECK(whole.scene == sc);
      CHECK(whole.resized);
      for (std::size_t i = 0; i < 9; ++i) {
        const FixedPatch& p = list[sc * 10 + 1 + i];
        CHECK(p.scene == sc);
        CHECK_FALSE(p.resized);
        CHECK(p.y0 == (sc == 0 ? r0 : r1)[i / 3]);
        CHECK(p.x0 == (sc == 0 ? c0 : r1)[i % 3]);
      }
    }
    // The release's ICVL numbers: 1392 x 1300 scenes, 512 patches -> rows 0, 464, 880, columns 0, 434, 788.
    JointData icvl;
    icvl.train.push_back(RealStack(1, 1392, 1300));
    const std::vector<FixedPatch> li = fixed_patches(icvl, 512);
    REQUIRE(li.size() == 10);
    CHECK(li[9].y0 == 880);
    CHECK(li[9].x0 == 788);
    CHECK(li[5].y0 == 464);
    CHECK(li[5].x0 == 434);
    // A crop is the scene's window, unflipped.
    const RealStack crop = fixed_patch(d, list[6], s);  // scene 0, row 14, column 34
    for (std::size_t y = 0; y < s; ++y)
      for (std::size_t x = 0; x < s; ++x) CHECK(crop(1, y, x) == 100000 + double((14 + y) * 100 + 34 + x));
    // The resize of a linear image is linear at the half-pixel-centre sample points:
    // value 100 ((i + 0.5) H / S - 0.5) + ((j + 0.5) W / S - 0.5), inside the scene here.
    const RealStack small = fixed_patch(d, list[0], s);
    for (std::size_t y = 0; y < s; ++y)
      for (std::size_t x = 0; x < s; ++x) {
        const double sy = (double(y) + 0.5) * 40.0 / 16.0 - 0.5, sx = (double(x) + 0.5) * 50.0 / 16.0 - 0.5;
        CHECK(small(0, y, x) == doctest::Approx(100 * sy + sx).epsilon(1e-12));
      }
    // Batches: `batch` consecutive patches from step x batch, wrapping at the end of the list.
    const auto b4 = fixed_batch(d, list, s, 4, 4), b5 = fixed_batch(d, list, s, 4, 5);
    for (std::size_t k = 0; k < 4; ++k) {
      CHECK(b4[k].data == fixed_patch(d, list[16 + k], s).data);
      CHECK(b5[k].data == fixed_patch(d, list[k], s).data);
    }
  }

  TEST_CASE("the release's sensor noise on the bands: srf n per sensor pixel, sigma pitch / sensor pitch per band") {
    const SystemConfig c = tiny_config(32, 3);
    const Eigen::MatrixXd srf = sensor_response(c);
    const double sb = 0.01;
    RealStack rgb(3, 128, 128), again(3, 128, 128), other(3, 128, 128);
    add_band_noise(rgb, srf, sb, 5, 0);
    add_band_noise(again, srf, sb, 5, 0);
    add_band_noise(other, srf, sb, 5, 1);
    CHECK(rgb.data == again.data);
    CHECK(rgb.data != other.data);
    // The sample covariance of the RGB noise over n pixels against sb^2 srf srf^T; each entry's
    // standard error is at most sb^2 sqrt(2 / n) x its scale, so 6 of them bound it.
    const std::size_t n = rgb.plane_size();
    const Eigen::MatrixXd want = sb * sb * srf * srf.transpose();
    for (std::size_t i = 0; i < 3; ++i)
      for (std::size_t j = 0; j < 3; ++j) {
        double acc = 0;
        for (std::size_t p = 0; p < n; ++p) acc += rgb.plane(i)[p] * rgb.plane(j)[p];
        const double scale = std::sqrt(want(Eigen::Index(i), Eigen::Index(i)) * want(Eigen::Index(j), Eigen::Index(j)));
        CHECK(std::fabs(acc / double(n) - want(Eigen::Index(i), Eigen::Index(j))) < 6 * std::sqrt(2.0 / double(n)) * scale);
      }
    // REFERENCE §3: sigma = 1e-3 on the bands is about 1.5e-4 on RGB at the release's sampling
    // (8 um pixels over 4 um samples, the small preset's too).
    const SystemConfig small = preset_config("small");
    const Eigen::MatrixXd rs = sensor_response(small);
    const double per_band = band_noise_sigma(small, 1e-3);
    CHECK(per_band == doctest::Approx(5e-4));
    for (Eigen::Index ch = 0; ch < 3; ++ch) {
      const double rgb_sigma = per_band * rs.row(ch).norm();
      CHECK(rgb_sigma > 0.8e-4);
      CHECK(rgb_sigma < 2.5e-4);
    }
  }

  TEST_CASE("the joint step: lr 0 keeps the loss a function of the PSF, with a non-zero PSF gradient") {
    // The gradient against finite differences is a row of the adjoint table (QDO_ADJOINT_ROWS joint).
    Runtime& rt = runtime();
    if (!skip_unless(rt.has_fp64(), "float64 device")) return;
    JointStep js;
    const RealStack psf = random_cube(3, js.s, js.s, 40);
    RealStack g, unused;
    const double l0 = js.trainer.step(5, 0.0, psf, g);
    double gg = 0;
    for (double v : g.data) gg += v * v;
    CHECK(gg > 0);
    CHECK(g.size() == psf.size());
    CHECK(js.trainer.step(5, 0.0, psf, unused) == l0);
    // The validation PSNR is a property of the state and the PSF: asking twice gives one value.
    CHECK(js.trainer.validation_psnr_db(psf) == js.trainer.validation_psnr_db(psf));
  }

  TEST_CASE("a network run resumes bit-identically: optics, network state and log") {
    const AffineFactory fake;
    const auto dir = temp_dir("joint_resume");
    const std::string a = (dir / "a").string(), b = (dir / "b").string();
    CHECK(run_design(runtime(), net_run(a, DesignMode::QDOA), false).steps_done == 6);
    DesignRunOptions first = net_run(b, DesignMode::QDOA);
    first.max_steps = 3;  // "killed" after step 3 (checkpoint at 2, then the final one at 3)
    CHECK(run_design(runtime(), first, false).steps_done == 3);
    CHECK(run_design(runtime(), net_run(b, DesignMode::QDOA), true).steps_done == 6);
    const DesignState sa = load_checkpoint(a + "/checkpoint.h5", 16, 4), sb = load_checkpoint(b + "/checkpoint.h5", 16, 4);
    CHECK(sa.w == sb.w);
    CHECK(sa.offsets == sb.offsets);
    CHECK(sa.network_file == "network/step_00000006.pt");
    CHECK(sa.network_file == sb.network_file);
    CHECK(sa.network_checksum == sb.network_checksum);
    CHECK(slurp(a + "/" + sa.network_file) == slurp(b + "/" + sb.network_file));
    // Every log column but the step time, row by row.
    auto rows = [](const std::string& p) {
      std::vector<std::string> out;
      std::ifstream f(p);
      for (std::string l; std::getline(f, l);) {
        std::vector<std::string> cols;
        std::stringstream ss(l);
        for (std::string x; std::getline(ss, x, ',');) cols.push_back(x);
        if (cols.size() > 5) cols.erase(cols.begin() + 5);  // step_s
        std::string j;
        for (const auto& x : cols) j += x + ",";
        out.push_back(j);
      }
      return out;
    };
    const auto ra = rows(a + "/log.csv"), rb = rows(b + "/log.csv");
    REQUIRE(ra.size() == 7);
    for (std::size_t r = 0; r < ra.size(); ++r) {
      CAPTURE(r);
      CHECK(ra[r] == rb.at(r));
    }
    CHECK(ra[0].find("train_psnr_db,val_psnr_db") != std::string::npos);
    // Validation PSNR at the end of each epoch (steps 2, 4, 6), empty otherwise.
    auto val = [&](std::size_t r) { std::vector<std::string> c; std::stringstream ss(ra[r]); for (std::string x; std::getline(ss, x, ',');) c.push_back(x); return c.at(8); };
    CHECK(val(1).empty());
    CHECK(!val(2).empty());
    CHECK(!val(6).empty());
    // Only the states the checkpoints name are kept; the scene split and the PSNR curves are written.
    std::set<std::string> kept;
    for (const auto& e : std::filesystem::directory_iterator(std::filesystem::path(b) / "network")) kept.insert(e.path().filename().string());
    CHECK(kept == std::set<std::string>{"step_00000004.pt", "step_00000006.pt"});
    for (const char* f : {"split.json", "psnr.png", "loss.png", "design.h5", "prior.h5"}) CHECK(std::filesystem::exists(std::filesystem::path(b) / f));
    const auto split = nlohmann::json::parse(slurp(b + "/split.json"));
    CHECK(split.at("train").size() == 3);
    CHECK(split.at("validation").size() == 2);
    // The network learns: the data term (column mae) falls from the first step to the last.
    auto mae = [&](std::size_t r) { std::vector<std::string> c; std::stringstream ss(ra[r]); for (std::string x; std::getline(ss, x, ',');) c.push_back(x); return std::stod(c.at(6)); };
    CHECK(mae(6) < mae(1));
    std::filesystem::remove_all(dir);
  }

  TEST_CASE("a network run's state is checked before resuming: missing, corrupt, another architecture") {
    const AffineFactory fake;
    const auto dir = temp_dir("joint_refuse");
    const std::string a = (dir / "a").string();
    DesignRunOptions o = net_run(a, DesignMode::QDO);
    o.max_steps = 2;
    run_design(runtime(), o, false);
    const DesignState st = load_checkpoint(a + "/checkpoint.h5", 16, 4);
    const std::string net = a + "/" + st.network_file, bytes = slurp(net);
    // Corrupt: one byte changed.
    std::string bad = bytes;
    bad[bad.size() / 2] = char(bad[bad.size() / 2] ^ 1);
    write_text_atomic(net, bad);
    CHECK_THROWS_WITH_AS(run_design(runtime(), net_run(a, DesignMode::QDO), true), doctest::Contains("checksum mismatch"), InputError);
    // Missing.
    std::filesystem::remove(net);
    CHECK_THROWS_WITH_AS(run_design(runtime(), net_run(a, DesignMode::QDO), true), doctest::Contains("missing"), InputError);
    // Another architecture: the run's config.json asks for another spec than the state holds.
    write_text_atomic(net, bytes);
    std::string cfg = slurp(a + "/config.json");
    const auto at = cfg.find("resunet:depth=2,root=4");
    REQUIRE(at != std::string::npos);
    cfg.replace(at, std::strlen("resunet:depth=2,root=4"), "resunet:depth=3,root=4");
    write_text_atomic(a + "/config.json", cfg);
    const std::string msg = input_error_of([&] { run_design(runtime(), net_run(a, DesignMode::QDO), true); });
    CHECK(msg.find("resunet:depth=2,root=4") != std::string::npos);
    CHECK(msg.find("resunet:depth=3,root=4") != std::string::npos);
    std::filesystem::remove_all(dir);
  }

  TEST_CASE("network runs: refusals before any work, eval's matched/mismatch rule, do-finetune keeps the optics frozen") {
    const AffineFactory fake;
    const auto dir = temp_dir("joint_eval");
    // Options refused by name.
    DesignRunOptions o = net_run((dir / "x").string(), DesignMode::DO);
    o.objective = Objective::Wiener;
    const std::string msg = input_error_of([&] { o.validate(); });
    CHECK(msg.find("objective") != std::string::npos);
    CHECK(msg.find("network") != std::string::npos);
    o = net_run((dir / "x").string(), DesignMode::DO);
    o.decoder = decoder_spec_from_string("resunet:depth=6,root=4");  // 2^5 = 32 does not divide S = 16
    CHECK_THROWS_WITH_AS(o.validate(), doctest::Contains("S = 16"), InputError);
    o = net_run((dir / "x").string(), DesignMode::DO);
    o.decoder = DecoderSpec{};
    CHECK_THROWS_WITH_AS(o.validate(), doctest::Contains("decoder"), InputError);
    o = net_run((dir / "x").string(), DesignMode::QDOA);
    o.finetune_from = "somewhere";
    CHECK_THROWS_WITH_AS(o.validate(), doctest::Contains("do-finetune"), InputError);
    CHECK(!std::filesystem::exists(dir / "x"));
    // Without a registered network (a qdo built without LibTorch) the run is refused, naming LibTorch.
    {
      const NetworkFactory keep = registered_network_factory();
      register_network_factory(nullptr);
      CHECK_THROWS_WITH_AS(run_design(runtime(), net_run((dir / "y").string(), DesignMode::DO), false),
                           doctest::Contains("LibTorch"), InputError);
      register_network_factory(keep);
    }
    // A network do run: matched is refused at its levels (the network was trained for H_f),
    // mismatch is the paper's DO, matched at full precision is the network's own design.
    const std::string d = (dir / "do").string();
    run_design(runtime(), net_run(d, DesignMode::DO), false);
    EvalOptions e;
    e.run = d;
    e.synthetic_scenes = 2;
    e.renders = 1;
    e.out = (dir / "eval").string();
    CHECK_THROWS_WITH_AS(evaluate_run(runtime(), e), doctest::Contains("mismatch"), InputError);
    e.decoder = DecoderFit::Mismatch;
    const EvalResult mis = evaluate_run(runtime(), e);
    CHECK(std::isfinite(mis.mean.psnr));
    const auto mj = nlohmann::json::parse(slurp(e.out + "/metrics.json"));
    CHECK(mj.at("decoder_kind") == "resunet:depth=2,root=4");
    e.decoder = DecoderFit::Matched;
    e.full_precision = true;
    CHECK(std::isfinite(evaluate_run(runtime(), e).mean.psnr));
    // do-finetune: the do run's optics at 2 levels, frozen; its network trained on.
    DesignRunOptions f = net_run((dir / "ft").string(), DesignMode::DO);
    f.finetune_from = d;
    f.design.quantizer.levels = 2;
    f.epochs = 1;
    f.design.steps_per_epoch = 3;
    f.design.t0_epochs = 0;
    f.design.t1_epochs = 1;
    run_design(runtime(), f, false);
    const DesignState src = load_checkpoint(d + "/checkpoint.h5", 16, 4), ft = load_checkpoint(f.out + "/checkpoint.h5", 16, 2);
    CHECK(ft.w == src.w);
    CHECK(ft.step == 3);
    CHECK(slurp(f.out + "/" + ft.network_file) != slurp(d + "/" + src.network_file));
    const Design fd = read_design(f.out + "/design.h5");
    CHECK(std::set<double>(fd.height_m.data.begin(), fd.height_m.data.end()).size() <= 2);
    // Its network is matched to its quantized DOE: eval's default decoder is accepted.
    EvalOptions ef = e;
    ef.run = f.out;
    ef.full_precision = false;
    ef.out = (dir / "eval_ft").string();
    CHECK(std::isfinite(evaluate_run(runtime(), ef).mean.psnr));
    // A finetune source that is not a network do run is refused, naming it.
    DesignRunOptions g = f;
    g.out = (dir / "ft2").string();
    g.finetune_from = f.out + "_none";
    CHECK_THROWS_AS(run_design(runtime(), g, false), InputError);
    std::filesystem::remove_all(dir);
  }

  TEST_CASE("synthetic:N adds synthetic training scenes to a network run's real ones; refused for Wiener runs") {
    const SystemConfig c = tiny_config(32, 3);
    const JointData only = load_joint_data(c, {"synthetic:3"}, "auto", 12, 1);
    CHECK(only.train.size() == 3);
    CHECK_THROWS_WITH_AS(load_joint_data(c, {"synthetic:x"}, "auto", 12, 1), doctest::Contains("synthetic:N"), InputError);
    DesignRunOptions o = net_run("/tmp/unused", DesignMode::QDOA);
    o.data = {"synthetic:4"};
    CHECK_NOTHROW(o.validate());
    o.decoder = DecoderSpec{};
    o.objective = Objective::Wiener;
    CHECK_THROWS_WITH_AS(o.validate(), doctest::Contains("synthetic:4"), InputError);
    if (!skip_unless(have_shared(), "../shared/data/hsi (the CAVE scenes)")) return;
    const std::string cave = std::string(shared_dir()) + "/data/hsi/cave";
    SystemConfig c31 = tiny_config(32, 31);  // CAVE's bands: 400 to 700 nm in 10 nm steps
    c31.wavelength_start_nm = 400;
    c31.wavelength_step_nm = 10;
    c31.validate();
    const JointData real = load_joint_data(c31, {cave}, "auto", 12, 1), mixed = load_joint_data(c31, {cave, "synthetic:2"}, "auto", 12, 1);
    CHECK(mixed.train.size() == real.train.size() + 2);
    CHECK(mixed.val_names == real.val_names);  // only the real scenes are split
    CHECK(std::count(mixed.train_names.begin(), mixed.train_names.end(), "synthetic:1") == 1);
  }

  TEST_CASE("a run's config.json keeps the decoder; run folders from before it read as Wiener runs") {
    DesignRunOptions o = net_run("/tmp/unused", DesignMode::QDOA);
    o.lr_decoder = 0.002;
    o.gamma_decoder = 3e-4;
    const DesignRunOptions back = design_run_options_from_json(design_run_options_to_json(o), "mem");
    CHECK(back.decoder == o.decoder);
    CHECK(back.lr_decoder == 0.002);
    CHECK(back.gamma_decoder == 3e-4);
    CHECK(back.objective == Objective::Network);
    auto j = nlohmann::json::parse(design_run_options_to_json(o));
    for (const char* k : {"decoder", "lr_decoder", "gamma_decoder", "finetune_from"}) j["design"].erase(k);
    j["design"]["objective"] = "wiener";
    const DesignRunOptions old = design_run_options_from_json(j.dump(), "old");
    CHECK(old.decoder.kind == DecoderSpec::Kind::Wiener);
    CHECK(old.finetune_from.empty());
  }

  TEST_CASE("qdo sweep's decoder axis: Wiener and network runs side by side, do-finetune for both, do-refit for Wiener only") {
    const AffineFactory fake;
    const auto dir = temp_dir("joint_sweep");
    GridOptions g;
    g.base = net_run("(per run)", DesignMode::DO);
    g.base.decoder = DecoderSpec{};
    g.base.objective = Objective::Wiener;
    g.levels = {2};
    g.modes = {"do", "do-refit", "do-finetune", "qdo"};
    g.decoders = {DecoderSpec{}, decoder_spec_from_string("resunet:depth=2,root=4")};
    g.finetune_steps = 2;
    g.eval_synthetic_scenes = 2;
    g.out = dir.string();
    const auto cells = run_grid(runtime(), g);
    std::map<std::string, GridCell> by;
    for (const auto& c : cells) by[c.name] = c;
    // Wiener: full + 4 modes; network: full + 3 (no do-refit).
    CHECK(cells.size() == 9);
    for (const char* n : {"full", "do_L2", "do-refit_L2", "do-finetune_L2", "qdo_L2", "full_resunet-depth2-root4", "do_L2_resunet-depth2-root4",
                          "do-finetune_L2_resunet-depth2-root4", "qdo_L2_resunet-depth2-root4"})
      CHECK(by.count(n) == 1);
    CHECK(by.count("do-refit_L2_resunet-depth2-root4") == 0);
    CHECK(by["qdo_L2_resunet-depth2-root4"].mode == "qdo@resunet:depth=2,root=4");
    CHECK(by["qdo_L2_resunet-depth2-root4"].decoder.to_string() == "resunet:depth=2,root=4");
    // With the Wiener decoder do-finetune is the closed-form refit: the do-refit cell's numbers.
    CHECK(by["do-finetune_L2"].mean.psnr == by["do-refit_L2"].mean.psnr);
    // The network's do-finetune is a run of its own, from the do run, optics frozen.
    const DesignRunOptions ft = read_run_config((dir / "runs" / "do-finetune_L2_resunet-depth2-root4").string());
    CHECK(ft.finetune_from == (dir / "runs" / "do_resunet-depth2-root4").string());
    CHECK(ft.decoder.to_string() == "resunet:depth=2,root=4");
    CHECK(read_run_config((dir / "runs" / "qdo_L2").string()).decoder.to_string() == "wiener");
    // A rerun reuses every run and cell.
    const auto again = run_grid(runtime(), g);
    REQUIRE(again.size() == cells.size());
    for (std::size_t i = 0; i < cells.size(); ++i) CHECK(again[i].mean.psnr == cells[i].mean.psnr);
    std::ifstream t1(dir / "table1.md");
    const std::string text((std::istreambuf_iterator<char>(t1)), std::istreambuf_iterator<char>());
    CHECK(text.find("| 2 | qdo@resunet:depth=2,root=4 |") != std::string::npos);
    // The CSV tables quote the labels with commas: qdo's own reader takes them back, one row per cell.
    const CsvTable t1csv = read_csv((dir / "table1.csv").string());
    REQUIRE(t1csv.raw[1].size() == cells.size());
    CHECK(std::count(t1csv.raw[1].begin(), t1csv.raw[1].end(), "qdo@resunet:depth=2,root=4") == 1);
    const CsvTable t2csv = read_csv((dir / "table2.csv").string());
    CHECK(std::count(t2csv.raw[1].begin(), t2csv.raw[1].end(), "do@resunet:depth=2,root=4") == 1);
    std::filesystem::remove_all(dir);
  }
}
