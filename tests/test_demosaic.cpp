// The demosaic stage (suite `demosaic`, include/qdo/physics/demosaic.hpp, demosaic_reference.hpp): bilinear
// and Malvar-He-Cutler on the four Bayer layouts, the device against the CPU reference (forward
// and transpose), the adjoint ladder (reference and device rows, run here through the ladder body),
// closed forms (constants everywhere, affine ramps in the interior, an impulse's response by hand),
// MHC against bilinear on real scenes (CAVE rendered to RGB), and the refusals.
#include <cmath>
#include <memory>
#include <string>
#include <vector>

#include "adjoint_ladder.hpp"
#include "common.hpp"
#include "qdo/data/config.hpp"
#include "qdo/data/datasets.hpp"
#include "qdo/physics/demosaic.hpp"
#include "qdo/physics/demosaic_reference.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/physics/raw_reference.hpp"
#include "qdo/physics/sensor_reference.hpp"

using namespace qdo;
using namespace qdo::test;

namespace {

const Cfa kMosaics[] = {Cfa::RGGB, Cfa::GRBG, Cfa::GBRG, Cfa::BGGR};
const DemosaicMethod kMethods[] = {DemosaicMethod::Bilinear, DemosaicMethod::MHC};

// The mosaic of a 3 x H x W image: each pixel keeps the channel its filter passes.
RealStack sample(const RealStack& rgb, Cfa cfa) {
  RealStack raw(1, rgb.rows, rgb.cols);
  for (std::size_t y = 0; y < rgb.rows; ++y)
    for (std::size_t x = 0; x < rgb.cols; ++x) raw(0, y, x) = rgb(std::size_t(cfa_channel(cfa, y, x)), y, x);
  return raw;
}

// Largest |a - b| over pixels at least `margin` from every border, all planes.
double interior_max_abs(const RealStack& a, const RealStack& b, std::size_t margin) {
  REQUIRE(a.planes == b.planes);
  double m = 0;
  for (std::size_t p = 0; p < a.planes; ++p)
    for (std::size_t y = margin; y + margin < a.rows; ++y)
      for (std::size_t x = margin; x + margin < a.cols; ++x) m = std::fmax(m, std::fabs(a(p, y, x) - b(p, y, x)));
  return m;
}

// PSNR (dB) of `got` against `truth` over pixels at least `margin` from the border, peak 1.
double psnr(const RealStack& got, const RealStack& truth, std::size_t margin) {
  double se = 0;
  std::size_t n = 0;
  for (std::size_t p = 0; p < truth.planes; ++p)
    for (std::size_t y = margin; y + margin < truth.rows; ++y)
      for (std::size_t x = margin; x + margin < truth.cols; ++x) {
        const double e = got(p, y, x) - truth(p, y, x);
        se += e * e;
        ++n;
      }
  return 10 * std::log10(double(n) / se);
}

double max_abs_value(const std::vector<double>& v) {
  double m = 0;
  for (double x : v) m = std::fmax(m, std::fabs(x));
  return m;
}

RealStack as_stack(const std::vector<double>& x, std::size_t p, std::size_t r, std::size_t c) {
  RealStack s(p, r, c);
  REQUIRE(x.size() == s.size());
  s.data = x;
  return s;
}

}  // namespace

TEST_SUITE("demosaic") {
  TEST_CASE("device against the CPU reference on seeded random frames: every layout, both methods, forward and transpose") {
    // Shapes: the smallest allowed (3 x 3, every pixel within the mirror's reach), odd sizes, and a
    // larger frame; two scenes per batch. Tolerance: the sum of |taps| is at most 2.5 (MHC's
    // diagonal filter) over at most 25 taps, each rounded once: 32 eps max|input|.
    struct Shape {
      std::size_t rows, cols;
    };
    const Shape shapes[] = {{3, 3}, {4, 5}, {7, 6}, {19, 24}};
    for (const Shape& sh : shapes)
      for (Cfa cfa : kMosaics)
        for (DemosaicMethod m : kMethods) {
          CAPTURE(sh.rows);
          CAPTURE(sh.cols);
          CAPTURE(to_string(cfa));
          CAPTURE(to_string(m));
          const std::vector<RealStack> raw = {uniform_stack(1, sh.rows, sh.cols, 11, -0.2, 1.2),
                                              uniform_stack(1, sh.rows, sh.cols, 12, 0, 1)};
          const std::vector<RealStack> g = {uniform_stack(3, sh.rows, sh.cols, 13), uniform_stack(3, sh.rows, sh.cols, 14)};
          for (Precision p : device_precisions(runtime())) {
            CAPTURE(to_string(p));
            DemosaicStage stage(runtime(), cfa, m, p);
            const std::vector<RealStack> got = stage.run(raw), got_t = stage.adjoint(g);
            REQUIRE(got.size() == 2);
            REQUIRE(got_t.size() == 2);
            for (std::size_t k = 0; k < 2; ++k) {
              const RealStack want = ref::demosaic(raw[k], cfa, m), want_t = ref::demosaic_vjp(g[k], cfa, m);
              REQUIRE(got[k].planes == 3);
              REQUIRE(got_t[k].planes == 1);
              const Diff<double> d = diff(got[k].data, want.data), dt = diff(got_t[k].data, want_t.data);
              CAPTURE(d.max_abs);
              CAPTURE(dt.max_abs);
              CHECK(d.max_abs <= 32 * eps(p) * max_abs_value(raw[k].data));
              // The transpose sums up to 9 mirror images of 25 taps x 3 channels near a corner.
              CHECK(dt.max_abs <= 64 * eps(p) * 3 * max_abs_value(g[k].data));
            }
          }
        }
  }

  TEST_CASE("adjoint ladder: the transpose is the adjoint (reference rows, and the device in float64)") {
    const std::size_t h = 7, w = 8;
    for (Cfa cfa : {Cfa::RGGB, Cfa::GBRG})
      for (DemosaicMethod m : kMethods) {
        Stage st("demosaic " + to_string(m) + ", cfa " + to_string(cfa) + " (reference)", h * w, 3 * h * w);
        st.forward = [=](const std::vector<double>& x) { return ref::demosaic(as_stack(x, 1, h, w), cfa, m).data; };
        st.jvp = [=](const std::vector<double>&, const std::vector<double>& d) {
          return ref::demosaic(as_stack(d, 1, h, w), cfa, m).data;
        };
        st.vjp = [=](const std::vector<double>&, const std::vector<double>& g) {
          return ref::demosaic_vjp(as_stack(g, 3, h, w), cfa, m).data;
        };
        st.dot_tol = 1e-14;
        st.fd_tol = 1e-9;
        st.samples = 8;
        check_ladder(st, 900 + unsigned(cfa) * 10 + unsigned(m));
      }
    if (skip_unless(runtime().has_fp64(), "float64 device rows: the device has no float64")) {
      for (Cfa cfa : {Cfa::GRBG, Cfa::BGGR})
        for (DemosaicMethod m : kMethods) {
          auto stage = std::make_shared<DemosaicStage>(runtime(), cfa, m, Precision::F64);
          const std::size_t scenes = 2, per = h * w;
          Stage st("demosaic " + to_string(m) + ", cfa " + to_string(cfa) + ", two scenes (device float64)", scenes * per,
                   scenes * 3 * per);
          auto fwd = [=](const std::vector<double>& x) {
            std::vector<RealStack> in;
            for (std::size_t k = 0; k < scenes; ++k)
              in.push_back(as_stack({x.begin() + long(k * per), x.begin() + long((k + 1) * per)}, 1, h, w));
            std::vector<double> out;
            for (const RealStack& s : stage->run(in)) out.insert(out.end(), s.data.begin(), s.data.end());
            return out;
          };
          st.forward = fwd;
          st.jvp = [=](const std::vector<double>&, const std::vector<double>& d) { return fwd(d); };
          st.vjp = [=](const std::vector<double>&, const std::vector<double>& g) {
            std::vector<RealStack> in;
            for (std::size_t k = 0; k < scenes; ++k)
              in.push_back(as_stack({g.begin() + long(k * 3 * per), g.begin() + long((k + 1) * 3 * per)}, 3, h, w));
            std::vector<double> out;
            for (const RealStack& s : stage->adjoint(in)) out.insert(out.end(), s.data.begin(), s.data.end());
            return out;
          };
          st.dot_tol = 1e-14;
          st.fd_tol = 1e-9;
          st.samples = 8;
          check_ladder(st, 950 + unsigned(cfa) * 10 + unsigned(m));
        }
    }
  }

  TEST_CASE("closed forms: a constant everywhere, affine ramps in the interior (bilinear >= 1 px, MHC >= 2 px from the border)") {
    const std::size_t h = 12, w = 15;
    for (Cfa cfa : kMosaics)
      for (DemosaicMethod m : kMethods) {
        CAPTURE(to_string(cfa));
        CAPTURE(to_string(m));
        // A dyadic constant: every tap sum is exact in float32 too.
        const RealStack flat(1, h, w, 0.375);
        CHECK(ref::demosaic(flat, cfa, m).data == RealStack(3, h, w, 0.375).data);
        for (Precision p : device_precisions(runtime())) {
          DemosaicStage stage(runtime(), cfa, m, p);
          CHECK(stage.run({flat})[0].data == RealStack(3, h, w, 0.375).data);
        }
        // Any constant, to rounding.
        const RealStack c3(1, h, w, 0.3);
        CHECK(diff(ref::demosaic(c3, cfa, m).data, RealStack(3, h, w, 0.3).data).max_abs <= 8 * kEps64);
        // Per-channel affine ramps, different in each channel (and so a grey ramp too).
        RealStack ramp(3, h, w);
        for (std::size_t y = 0; y < h; ++y)
          for (std::size_t x = 0; x < w; ++x) {
            ramp(0, y, x) = 0.2 + 0.03 * double(y) - 0.01 * double(x);
            ramp(1, y, x) = 0.5 - 0.02 * double(y) + 0.025 * double(x);
            ramp(2, y, x) = 0.1 + 0.01 * double(y) + 0.04 * double(x);
          }
        const std::size_t margin = m == DemosaicMethod::Bilinear ? 1 : 2;
        const RealStack got = ref::demosaic(sample(ramp, cfa), cfa, m);
        CHECK(interior_max_abs(got, ramp, margin) <= 1e-14);
        // At the border the mirror folds the ramp: not reproduced there (the rule is visible).
        CHECK(interior_max_abs(got, ramp, 0) > 1e-3);
        RealStack grey(3, h, w);
        for (std::size_t c = 0; c < 3; ++c)
          for (std::size_t y = 0; y < h; ++y)
            for (std::size_t x = 0; x < w; ++x) grey(c, y, x) = 0.4 + 0.02 * double(y) + 0.03 * double(x);
        CHECK(interior_max_abs(ref::demosaic(sample(grey, cfa), cfa, m), grey, margin) <= 1e-14);
        for (Precision p : device_precisions(runtime())) {
          DemosaicStage stage(runtime(), cfa, m, p);
          CHECK(interior_max_abs(stage.run({sample(ramp, cfa)})[0], ramp, margin) <= 16 * eps(p));
        }
      }
    // A curved image is not reproduced by either (the ramp check is not vacuous): a quadratic in x.
    RealStack quad(3, h, w);
    for (std::size_t c = 0; c < 3; ++c)
      for (std::size_t y = 0; y < h; ++y)
        for (std::size_t x = 0; x < w; ++x) quad(c, y, x) = 0.01 * double(x * x);
    for (DemosaicMethod m : kMethods) CHECK(interior_max_abs(ref::demosaic(sample(quad, Cfa::RGGB), Cfa::RGGB, m), quad, 2) > 1e-3);
  }

  TEST_CASE("an impulse's response by hand (RGGB): bilinear averages, MHC's published taps") {
    // A unit impulse at the green site (4, 5) of RGGB (row 4 holds R and G: red lies left and right).
    RealStack raw(1, 10, 10);
    raw(0, 4, 5) = 1;
    const RealStack b = ref::demosaic(raw, Cfa::RGGB, DemosaicMethod::Bilinear);
    const RealStack m = ref::demosaic(raw, Cfa::RGGB, DemosaicMethod::MHC);
    // Bilinear: green at the red sites left and right (4, 4), (4, 6) and at the blue sites above
    // and below (3, 5), (5, 5) is a quarter of it; red and blue at the impulse's own site are 0
    // (read from the neighbours); green elsewhere on green sites is the green sample (0).
    CHECK(b(1, 4, 5) == 1);
    CHECK(b(1, 4, 4) == 0.25);
    CHECK(b(1, 4, 6) == 0.25);
    CHECK(b(1, 3, 5) == 0.25);
    CHECK(b(1, 5, 5) == 0.25);
    CHECK(b(0, 4, 5) == 0);
    CHECK(b(2, 4, 5) == 0);
    // Red at the green site (5, 4) of a blue row reads (4, 4) and (6, 4); blue at the red site (4, 4)
    // reads its diagonal neighbours: neither touches the impulse.
    CHECK(b(0, 5, 4) == 0);
    CHECK(b(2, 4, 4) == 0);
    // MHC (taps in eighths, demosaic_reference.hpp): red and blue at the site itself take the centre
    // tap of the green-site filters, 5/8; green at the four neighbouring R/B sites 2/8; blue at the
    // green site (3, 4) of a blue row (blue left and right), a diagonal neighbour: -1/8; red at the
    // green site (6, 5) of a red row, two below: +1/16 (the 1/2 tap); red at the blue site (5, 5),
    // one below: no tap; blue at the red site (4, 4), one left: no tap.
    CHECK(m(1, 4, 5) == 1);
    CHECK(m(0, 4, 5) == 0.625);
    CHECK(m(2, 4, 5) == 0.625);
    CHECK(m(1, 4, 4) == 0.25);
    CHECK(m(1, 3, 5) == 0.25);
    CHECK(m(2, 3, 4) == -0.125);
    CHECK(m(0, 6, 5) == 0.0625);
    CHECK(m(0, 5, 5) == 0);
    CHECK(m(2, 4, 4) == 0);
    CHECK(m(1, 4, 6) == 0.25);
    CHECK(m(1, 4, 7) == 0);  // a green site: its own sample
    // Bilinear's green plane: the impulse plus four quarters.
    double sum_g = 0;
    for (std::size_t i = 0; i < b.plane_size(); ++i) sum_g += b.plane(1)[i];
    CHECK(sum_g == 2);
  }

  TEST_CASE("on real scenes (CAVE rendered to RGB) MHC reconstructs better than bilinear, every layout") {
    if (!skip_unless(have_shared(), "the shared CAVE scenes are not here")) return;
    SystemConfig cfg = preset_config("paper");
    const Eigen::MatrixXd srf = sensor_response(cfg);
    for (const char* name : {"balloons_256.mat", "chart_and_stuffed_toy_256.mat", "cloth_256.mat"}) {
      CAPTURE(name);
      const RealStack cube = load_scene(std::string(shared_dir()) + "/data/hsi/cave/" + name, "auto", cfg.bands);
      const RealStack rgb = ref::sensor_integrate(cube, srf);
      for (Cfa cfa : kMosaics) {
        CAPTURE(to_string(cfa));
        const RealStack raw = sample(rgb, cfa);
        const double pb = psnr(ref::demosaic(raw, cfa, DemosaicMethod::Bilinear), rgb, 2);
        const double pm = psnr(ref::demosaic(raw, cfa, DemosaicMethod::MHC), rgb, 2);
        MESSAGE(std::string(name) << " " << to_string(cfa) << ": bilinear " << pb << " dB, MHC " << pm << " dB");
        CHECK(pb > 20);  // both reconstruct (a wrong layout or filter falls far below)
        CHECK(pm > pb + 2);  // measured +3.9 .. +4.9 dB on the three scenes
      }
    }
  }

  TEST_CASE("mosaic planes, raw_to_linear and the method names") {
    const RealStack raw = uniform_stack(1, 4, 6, 5, 0, 1);
    for (Cfa cfa : kMosaics) {
      const RealStack s = ref::mosaic_planes(raw, cfa);
      REQUIRE(s.planes == 3);
      for (std::size_t y = 0; y < 4; ++y)
        for (std::size_t x = 0; x < 6; ++x)
          for (std::size_t c = 0; c < 3; ++c)
            CHECK(s(c, y, x) == (int(c) == cfa_channel(cfa, y, x) ? raw(0, y, x) : 0.0));
    }
    // The inverse of the raw stage's affine part: raw_forward then raw_to_linear gives back the
    // sampled signal (no noise, no rounding, nothing clipped).
    SystemConfig c = preset_config("small");
    c.cfa = Cfa::RGGB;
    c.bit_depth = 12;
    c.black_level_dn = 200;
    c.gain = 1.5;
    c.read_noise_sigma = 0;
    c.full_well_photons = 0;
    RealStack rgb = uniform_stack(3, 4, 6, 8, 0, 0.6);
    RealStack exact = ref::raw_forward(rgb, c).unquantized;
    const RealStack lin = raw_to_linear(exact, c);
    CHECK(diff(lin.data, sample(rgb, Cfa::RGGB).data).max_abs <= 1e-12);
    CHECK(demosaic_method_from_string("bilinear") == DemosaicMethod::Bilinear);
    CHECK(demosaic_method_from_string("MHC") == DemosaicMethod::MHC);
    CHECK(to_string(DemosaicMethod::MHC) == "mhc");
    CHECK(to_string(demosaic_method_from_string(to_string(DemosaicMethod::Bilinear))) == "bilinear");
  }

  TEST_CASE("refusals name the argument, the value and what is allowed") {
    auto msg = [](auto&& f) {
      try {
        f();
      } catch (const InputError& e) {
        return std::string(e.what());
      }
      return std::string("no error");
    };
    const std::string a = msg([] { demosaic_method_from_string("ahd", "--demosaic"); });
    CHECK(a.find("--demosaic") != std::string::npos);
    CHECK(a.find("ahd") != std::string::npos);
    CHECK(a.find("mhc") != std::string::npos);
    CHECK(msg([] { ref::demosaic(RealStack(1, 5, 5), Cfa::None, DemosaicMethod::MHC); }).find("cfa") != std::string::npos);
    CHECK(msg([] { ref::demosaic(RealStack(1, 2, 5), Cfa::RGGB, DemosaicMethod::MHC); }).find("H, W >= 3") != std::string::npos);
    CHECK(msg([] { ref::demosaic(RealStack(3, 5, 5), Cfa::RGGB, DemosaicMethod::MHC); }).find("3 x 5 x 5") != std::string::npos);
    CHECK(msg([] { ref::demosaic_vjp(RealStack(1, 5, 5), Cfa::RGGB, DemosaicMethod::MHC); }).find("g_rgb") != std::string::npos);
    CHECK(msg([] { DemosaicStage s(runtime(), Cfa::None, DemosaicMethod::Bilinear, Precision::F32); }).find("none") !=
          std::string::npos);
    DemosaicStage s(runtime(), Cfa::RGGB, DemosaicMethod::Bilinear, Precision::F32);
    CHECK(msg([&] { s.run({RealStack(1, 5, 5), RealStack(1, 5, 6)}); }).find("1 x 5 x 6") != std::string::npos);
    CHECK(msg([&] { s.run({RealStack(1, 2, 6)}); }).find("3 x 3") != std::string::npos);
    CHECK(msg([&] { s.run(std::vector<RealStack>{}); }).find("0 scenes") != std::string::npos);
    CHECK(msg([&] { s.adjoint({RealStack(1, 5, 5)}); }).find("g_rgb") != std::string::npos);
  }
}
