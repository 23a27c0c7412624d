// The raw stage (suite `raw`): the sensor as built (include/qdo/physics/raw.hpp) against its CPU reference
// (raw_reference.hpp) and against values worked out by hand: mosaic layout, saturation and floor
// counts, bit depth, black level, gain, noise statistics, configuration errors. Its adjoint
// rows (reference and device) are defined here (QDO_ADJOINT_ROWS raw) and run by the suite `adjoint`.
#include <cmath>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "adjoint_table.hpp"
#include "common.hpp"
#include "qdo/data/config.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/physics/raw.hpp"
#include "qdo/physics/raw_reference.hpp"
#include "qdo/physics/sensor_reference.hpp"

using namespace qdo;
using namespace qdo::test;

namespace {

const Cfa kAllCfa[] = {Cfa::None, Cfa::RGGB, Cfa::GRBG, Cfa::GBRG, Cfa::BGGR};

// A configuration of the raw stage alone: no noise, unit gain, no offset, no quantization.
SystemConfig raw_config(Cfa cfa) {
  SystemConfig c = preset_config("small");
  c.read_noise_sigma = 0;
  c.full_well_photons = 0;
  c.cfa = cfa;
  return c;
}

RealStack stack_of(const std::vector<double>& x, std::size_t p, std::size_t r, std::size_t c) {
  RealStack s(p, r, c);
  REQUIRE(x.size() == s.size());
  s.data = x;
  return s;
}

// Sample mean and unbiased variance.
std::pair<double, double> moments(const std::vector<double>& v) {
  double m = 0, var = 0;
  for (double x : v) m += x;
  m /= double(v.size());
  for (double x : v) var += (x - m) * (x - m);
  return {m, var / double(v.size() - 1)};
}

}  // namespace

QDO_ADJOINT_ROWS(raw, "raw stage") {
  std::vector<Stage> rows;
  const std::size_t h = 5, w = 6;
  for (Cfa cfa : {Cfa::None, Cfa::RGGB, Cfa::GBRG}) {
    // bit_depth 0 (rounding straight-through is not a derivative), read noise only (additive:
    // part of the point, no effect on the Jacobian), a black level and a gain that clip some
    // elements at 0 and at the white level: the mask is exercised, no point lies within a step
    // of a clip edge.
    SystemConfig c = raw_config(cfa);
    c.black_level_dn = 0.05;
    c.gain = 1.2;
    c.read_noise_sigma = 0.02;
    c.noise_seed = 77;
    const std::size_t out = raw_channels(cfa) * h * w;
    Stage st("raw stage, cfa " + to_string(cfa) + ", rgb -> raw (reference)", 3 * h * w, out);
    st.forward = [c](const std::vector<double>& x) { return ref::raw_forward(stack_of(x, 3, h, w), c).raw.data; };
    st.vjp = [c, cfa](const std::vector<double>& x, const std::vector<double>& g) {
      return ref::raw_vjp(stack_of(x, 3, h, w), stack_of(g, raw_channels(cfa), h, w), c).data;
    };
    st.jvp = [c](const std::vector<double>& x, const std::vector<double>& d) {
      return ref::raw_jvp(stack_of(x, 3, h, w), stack_of(d, 3, h, w), c).data;
    };
    st.x0 = uniform_stack(3, h, w, 41, -0.2, 1.1).data;
    st.dot_tol = 1e-14;
    st.fd_tol = 1e-8;
    st.samples = 6;
    rows.push_back(st);
  }
  if (skip_unless(runtime().has_fp64(), "float64 cases: the device has no float64")) {
    SystemConfig c = raw_config(Cfa::RGGB);
    c.black_level_dn = 0.05;
    c.gain = 1.2;
    c.read_noise_sigma = 0.02;
    c.noise_seed = 78;
    auto stage = std::make_shared<RawStage>(runtime(), c, Precision::F64);
    const std::size_t scenes = 2, per_in = 3 * h * w, per_out = h * w;
    auto split = [](const std::vector<double>& v, std::size_t planes, std::size_t n) {
      std::vector<RealStack> s;
      for (std::size_t k = 0; k < n; ++k)
        s.push_back(stack_of({v.begin() + long(k * planes * h * w), v.begin() + long((k + 1) * planes * h * w)}, planes, h, w));
      return s;
    };
    auto join = [](const std::vector<RealStack>& s) {
      std::vector<double> v;
      for (const RealStack& x : s) v.insert(v.end(), x.data.begin(), x.data.end());
      return v;
    };
    Stage st("raw stage, cfa rggb, two scenes (device float64)", scenes * per_in, scenes * per_out);
    st.forward = [=](const std::vector<double>& x) { return join(stage->run(split(x, 3, scenes)).raw); };
    st.vjp = [=](const std::vector<double>& x, const std::vector<double>& g) {
      return join(stage->adjoint(split(x, 3, scenes), split(g, 1, scenes)));
    };
    st.x0 = uniform_stack(1, 1, scenes * per_in, 42, -0.2, 1.1).data;
    st.fd_tol = 1e-8;
    st.samples = 6;
    rows.push_back(st);
  }
  return rows;
}

TEST_SUITE("raw") {
  TEST_CASE("the mosaic layout by hand: each pixel keeps its filter's channel, on the device and in the reference") {
    // R = 0.1, G = 0.2, B = 0.3 everywhere: the raw value names the channel read.
    RealStack rgb(3, 4, 6);
    for (std::size_t ch = 0; ch < 3; ++ch)
      for (std::size_t i = 0; i < rgb.plane_size(); ++i) rgb.plane(ch)[i] = 0.1 * double(ch + 1);
    struct Case {
      Cfa cfa;
      int cell[2][2];  // channel at (y & 1, x & 1)
    };
    const Case cases[] = {{Cfa::RGGB, {{0, 1}, {1, 2}}},
                          {Cfa::GRBG, {{1, 0}, {2, 1}}},
                          {Cfa::GBRG, {{1, 2}, {0, 1}}},
                          {Cfa::BGGR, {{2, 1}, {1, 0}}}};
    for (const Case& cs : cases) {
      CAPTURE(to_string(cs.cfa));
      const SystemConfig c = raw_config(cs.cfa);
      const ref::RawFrame want = ref::raw_forward(rgb, c);
      REQUIRE(want.raw.planes == 1);
      for (Precision p : device_precisions(runtime())) {
        CAPTURE(to_string(p));
        RawStage stage(runtime(), c, p);
        CHECK(stage.channels() == 1);
        const RealStack got = stage.run({rgb}).raw[0];
        for (std::size_t y = 0; y < 4; ++y)
          for (std::size_t x = 0; x < 6; ++x) {
            const int ch = cs.cell[y & 1][x & 1];
            CHECK(cfa_channel(cs.cfa, y, x) == ch);
            CHECK(want.raw(0, y, x) == 0.1 * double(ch + 1));
            CHECK(got(0, y, x) == doctest::Approx(0.1 * double(ch + 1)).epsilon(4 * eps(p)));
          }
      }
    }
    // RGGB spelled out, channel by channel.
    CHECK(cfa_channel(Cfa::RGGB, 0, 0) == 0);
    CHECK(cfa_channel(Cfa::RGGB, 0, 1) == 1);
    CHECK(cfa_channel(Cfa::RGGB, 1, 0) == 1);
    CHECK(cfa_channel(Cfa::RGGB, 1, 1) == 2);
    CHECK(cfa_channel(Cfa::None, 0, 0) == -1);
    // No mosaic: three planes, the input itself (the default configuration changes nothing).
    const ref::RawFrame none = ref::raw_forward(rgb, raw_config(Cfa::None));
    CHECK(none.raw.planes == 3);
    CHECK(none.raw.data == rgb.data);
    CHECK(preset_config("paper").cfa == Cfa::None);
  }

  TEST_CASE("saturation and floor counts are exact on a constructed frame; the clipped fraction is reported") {
    // 10-bit, black 64 DN, gain 2: code = 64 + 2 v (1023 - 64); v > 0.5 exceeds the white level,
    // v > 1 the full well (either saturates), v < -64 / 1918 is floored at 0.
    SystemConfig c = raw_config(Cfa::None);
    c.bit_depth = 10;
    c.black_level_dn = 64;
    c.gain = 2;
    const std::vector<double> vals = {0.0, 0.25, 0.49, 0.51, 0.75, 1.5, -0.01, -0.04, 0.5, 2.0, -1.0, 0.1};
    // saturated: 0.51, 0.75, 1.5, 2.0 (0.5 lands exactly on the white level: not clipped);
    // floored: -0.04 (64 - 76.72 < 0) and -1.0; -0.01 keeps a positive code (64 - 19.18).
    RealStack rgb(3, 2, 2);
    rgb.data = vals;
    const ref::RawFrame want = ref::raw_forward(rgb, c);
    CHECK(want.counts.saturated == 4);
    CHECK(want.counts.floored == 2);
    CHECK(want.counts.total == 12);
    CHECK(want.counts.clipped_fraction() == doctest::Approx(4.0 / 12.0));
    const std::vector<double> codes = {64, 543.5, 1003.82, 1023, 1023, 1023, 44.82, 0, 1023, 1023, 0, 255.8};
    for (std::size_t i = 0; i < vals.size(); ++i) {
      CAPTURE(i);
      CHECK(want.unquantized.data[i] == doctest::Approx(codes[i]).epsilon(1e-12));
      CHECK(want.raw.data[i] == std::floor(codes[i] + 0.5));
    }
    for (Precision p : device_precisions(runtime())) {
      CAPTURE(to_string(p));
      RawStage stage(runtime(), c, p);
      const RawStage::Frames got = stage.run({rgb, rgb});  // two scenes: the tally is over the batch
      CHECK(got.counts.saturated == 8);
      CHECK(got.counts.floored == 4);
      CHECK(got.counts.total == 24);
      CHECK(got.counts.clipped_fraction() == doctest::Approx(8.0 / 24.0));
      for (const RealStack& s : got.raw) CHECK(s.data == want.raw.data);
    }
  }

  TEST_CASE("bit depth: codes round half up to integer DN, exact at 8, 12 and 16 bits; black level and gain") {
    for (std::size_t bits : {8, 12, 16}) {
      CAPTURE(bits);
      SystemConfig c = raw_config(Cfa::None);
      c.bit_depth = bits;
      const double white = std::ldexp(1.0, int(bits)) - 1;
      CHECK(c.white_level_dn() == white);
      // Codes k + 0.3 -> k and k + 0.7 -> k + 1 over the whole range (0.2 DN from the rounding
      // edge, far above float32's rounding of a code of 65535: 0.01 DN).
      RealStack rgb(3, 1, 16);
      std::vector<double> want;
      for (std::size_t i = 0; i < rgb.size(); ++i) {
        const double k = std::floor(double(i) * (white - 1) / double(rgb.size() - 1));
        const double frac = i % 2 ? 0.7 : 0.3;
        rgb.data[i] = (k + frac) / white;
        want.push_back(k + (i % 2 ? 1 : 0));
      }
      CHECK(ref::raw_forward(rgb, c).raw.data == want);
      for (Precision p : device_precisions(runtime())) {
        CAPTURE(to_string(p));
        RawStage stage(runtime(), c, p);
        CHECK(stage.run({rgb}).raw[0].data == want);
      }
    }
    // Black level 64 of 10 bits: dark reads 64, full well 1023, half way 543.5 -> 544 (half up);
    // a negative signal stays above 0 while the offset lasts. Gain 0.5: the full well reaches
    // only half the span.
    SystemConfig c = raw_config(Cfa::None);
    c.bit_depth = 10;
    c.black_level_dn = 64;
    RealStack rgb(3, 1, 2);
    rgb.data = {0.0, 1.0, 0.5, -0.05, 0.25, 1.0};
    const std::vector<double> want = {64, 1023, 544, 16, 304, 1023};  // -0.05: 64 - 47.95 = 16.05
    CHECK(ref::raw_forward(rgb, c).raw.data == want);
    c.gain = 0.5;
    const std::vector<double> half = {64, 544, 304, 40, 184, 544};  // 64 + 0.5 v 959
    CHECK(ref::raw_forward(rgb, c).raw.data == half);
    for (Precision p : device_precisions(runtime())) {
      CAPTURE(to_string(p));
      RawStage stage(runtime(), c, p);
      CHECK(stage.run({rgb}).raw[0].data == half);
    }
  }

  TEST_CASE("device against the CPU reference on seeded random frames, every mosaic, float32 and float64") {
    const std::size_t h = 16, w = 24, scenes = 2;
    std::vector<RealStack> rgb;
    for (unsigned k = 0; k < scenes; ++k) rgb.push_back(uniform_stack(3, h, w, 60 + k, -0.05, 1.1));
    for (Cfa cfa : kAllCfa) {
      CAPTURE(to_string(cfa));
      // (a) No noise, no quantization: a float32 code differs by its rounding only. Elements
      // within that rounding of a clip edge could be tallied differently: counted from the reference.
      SystemConfig c = raw_config(cfa);
      c.black_level_dn = 0.02;
      c.gain = 1.1;
      // (b) Shot and read noise (same counters), 12 bits, black 256 DN.
      SystemConfig n = c;
      n.bit_depth = 12;
      n.black_level_dn = 256;
      n.read_noise_sigma = 0.01;
      n.full_well_photons = 200;  // means from 0 to 200 photons: both Poisson branches
      n.noise_seed = 0xfeedbeef12ull;
      for (Precision p : device_precisions(runtime())) {
        CAPTURE(to_string(p));
        {
          RawStage stage(runtime(), c, p);
          const RawStage::Frames got = stage.run(rgb);
          const double tol = 8 * eps(p) * c.white_level_dn();
          std::size_t sat = 0, flo = 0, edge = 0;
          for (std::size_t k = 0; k < scenes; ++k) {
            const ref::RawFrame want = ref::raw_forward(rgb[k], c, k);
            sat += want.counts.saturated;
            flo += want.counts.floored;
            const Diff<double> d = diff(got.raw[k].data, want.raw.data);
            CAPTURE(d.max_abs);
            CHECK(d.max_abs <= tol);
            for (std::size_t ch = 0; ch < 3; ++ch)
              for (std::size_t i = 0; i < rgb[k].plane_size(); ++i) {
                const double v = rgb[k].plane(ch)[i], code = c.black_level_dn + c.gain * v * (1 - c.black_level_dn);
                if (std::fabs(v - 1) < 1e-5 || std::fabs(code - 1) < 1e-5 || std::fabs(code) < 1e-5) ++edge;
              }
          }
          CAPTURE(edge);
          CHECK(sat > 0);
          CHECK(flo > 0);
          CHECK(got.counts.saturated + edge >= sat);
          CHECK(got.counts.saturated <= sat + edge);
          CHECK(got.counts.floored + edge >= flo);
          CHECK(got.counts.floored <= flo + edge);
          CHECK(got.counts.total == scenes * raw_channels(cfa) * h * w);
        }
        {
          // Same counters give the same draws. In float32 a Poisson count may land one step off
          // when its uniform sits within rounding of a CDF step, and a code within rounding of a
          // half DN may round the other way: allow 1 % of elements off by more than the rounding.
          RawStage stage(runtime(), n, p);
          const RawStage::Frames got = stage.run(rgb);
          std::size_t off = 0, sat = 0, total = 0;
          for (std::size_t k = 0; k < scenes; ++k) {
            const ref::RawFrame want = ref::raw_forward(rgb[k], n, k);
            sat += want.counts.saturated;
            total += want.raw.size();
            for (std::size_t i = 0; i < want.raw.size(); ++i)
              if (std::fabs(got.raw[k].data[i] - want.raw.data[i]) > 0.5) ++off;  // codes are integers
          }
          CAPTURE(off);
          CAPTURE(sat);
          if (p == Precision::F64) {
            CHECK(off == 0);
            CHECK(got.counts.saturated == sat);
          } else {
            CHECK(double(off) <= 0.01 * double(total));
            CHECK(double(got.counts.saturated) <= double(sat + off));
            CHECK(double(got.counts.saturated) + double(off) >= double(sat));
          }
        }
      }
    }
  }

  TEST_CASE("the device adjoint matches the reference's: mosaic scatter, gain and the clip mask with noise") {
    const std::size_t h = 8, w = 10, scenes = 2;
    std::vector<RealStack> rgb;
    for (unsigned k = 0; k < scenes; ++k) rgb.push_back(uniform_stack(3, h, w, 70 + k, -0.1, 1.1));
    for (Cfa cfa : kAllCfa) {
      CAPTURE(to_string(cfa));
      SystemConfig c = raw_config(cfa);
      c.bit_depth = 12;  // straight-through: the scale is gain (white - black)
      c.black_level_dn = 100;
      c.gain = 1.2;
      c.read_noise_sigma = 0.01;
      c.noise_seed = 5;
      std::vector<RealStack> g;
      for (unsigned k = 0; k < scenes; ++k) g.push_back(uniform_stack(raw_channels(cfa), h, w, 80 + k));
      for (Precision p : device_precisions(runtime())) {
        CAPTURE(to_string(p));
        RawStage stage(runtime(), c, p);
        const std::vector<RealStack> got = stage.adjoint(rgb, g);
        for (std::size_t k = 0; k < scenes; ++k) {
          const RealStack want = ref::raw_vjp(rgb[k], g[k], c, k);
          std::size_t zeros = 0;
          for (double v : want.data) zeros += v == 0 ? 1 : 0;
          CHECK(zeros > (cfa == Cfa::None ? 0 : 2 * h * w));  // dropped channels and clipped elements
          // Elements whose mask differs (float32 noise within rounding of a clip edge) are none here.
          CHECK(diff(got[k].data, want.data).max_abs <= 8 * eps(p) * c.gain * c.white_level_dn());
        }
      }
    }
  }

  TEST_CASE("noise: shot and read noise statistics within bounds from the sample count, reproducible by seed") {
    // Constant signal 0.1, no mosaic, no quantization, black level 0.5 (white 1): raw = 0.5 +
    // 0.5 (Poisson(lambda) / fw + sigma g), far from both clips (fw = 10 lambda).
    const std::size_t h = 64, w = 64;
    const RealStack rgb(3, h, w, 0.1);
    for (double lambda : {3.0, 30.0, 300.0}) {
      for (double sigma : {0.0, 0.002}) {
        CAPTURE(lambda);
        CAPTURE(sigma);
        SystemConfig c = raw_config(Cfa::None);
        c.full_well_photons = 10 * lambda;
        c.read_noise_sigma = sigma;
        c.noise_seed = 11;
        c.black_level_dn = 0.5;
        const double fw = c.full_well_photons;
        const double mean = 0.5 + 0.5 * 0.1, var = 0.25 * (lambda / (fw * fw) + sigma * sigma);
        // Excess kurtosis of the sum: Poisson's 1 / lambda, scaled by its share of the variance².
        const double shot = 0.25 * lambda / (fw * fw);
        const double kurt = shot * shot / (var * var) / lambda;
        std::vector<std::vector<double>> samples = {ref::raw_forward(rgb, c).raw.data};
        for (Precision p : device_precisions(runtime())) {
          RawStage stage(runtime(), c, p);
          samples.push_back(stage.run({rgb}).raw[0].data);
        }
        for (const auto& s : samples) {
          const double n = double(s.size());
          const auto [m, v] = moments(s);
          CAPTURE(m);
          CAPTURE(v);
          // 5 standard errors: of the mean sqrt(var / n), of the variance var sqrt(2 / (n - 1) + kurt / n).
          CHECK(std::fabs(m - mean) <= 5 * std::sqrt(var / n));
          CHECK(std::fabs(v - var) <= 5 * var * std::sqrt(2 / (n - 1) + kurt / n));
        }
        CHECK(ref::raw_forward(rgb, c).counts.saturated == 0);
        CHECK(ref::raw_forward(rgb, c).counts.floored == 0);
      }
    }
    SystemConfig c = raw_config(Cfa::RGGB);
    c.read_noise_sigma = 0.01;
    c.full_well_photons = 100;
    c.noise_seed = 3;
    const RealStack a = ref::raw_forward(rgb, c).raw;
    CHECK(ref::raw_forward(rgb, c).raw.data == a.data);
    // A scene further in the batch draws other numbers.
    CHECK(ref::raw_forward(rgb, c, 1).raw.data != a.data);
    c.noise_seed = 4;
    CHECK(ref::raw_forward(rgb, c).raw.data != a.data);
    // The raw stream is not the sensor stage's: the same seed gives other read noise.
    SystemConfig r = raw_config(Cfa::None);
    r.read_noise_sigma = 0.01;
    r.noise_seed = 3;
    RealStack sensor = rgb;
    ref::add_noise(sensor, 0.01, 0, 3);
    CHECK(ref::raw_forward(rgb, r).raw.data != sensor.data);
  }

  TEST_CASE("bad raw-stage configuration values are refused, naming the key, the value and what is allowed") {
    auto refused = [](const std::string& json, const std::string& key, const std::string& value) {
      CAPTURE(json);
      CHECK_THROWS_WITH_AS(config_from_json_text(json), doctest::Contains(("'" + key + "' = " + value).c_str()), InputError);
    };
    refused(R"({"cfa": "rgbg"})", "cfa", "\"rgbg\"");
    refused(R"({"cfa": "RGGB"})", "cfa", "\"RGGB\"");
    refused(R"({"bit_depth": 7})", "bit_depth", "7");
    refused(R"({"bit_depth": 17})", "bit_depth", "17");
    refused(R"({"gain": 0})", "gain", "0");
    refused(R"({"gain": -1})", "gain", "-1");
    refused(R"({"black_level_dn": -1})", "black_level_dn", "-1");
    refused(R"({"black_level_dn": 1})", "black_level_dn", "1");  // bit_depth 0: white level 1
    refused(R"({"bit_depth": 8, "black_level_dn": 255})", "black_level_dn", "255");
    CHECK_THROWS_WITH_AS(config_from_json_text(R"({"cfa": "x"})"), doctest::Contains("\"bggr\""), InputError);
    CHECK_THROWS_WITH_AS(config_from_json_text(R"({"bit_depth": 7})"), doctest::Contains("8 to 16"), InputError);
    CHECK_THROWS_WITH_AS(config_from_json_text(R"({"bit_depth": 8, "black_level_dn": 300})"), doctest::Contains("255"),
                         InputError);
    // Good values round-trip through JSON; the defaults are today's sensor (no mosaic).
    const SystemConfig d = preset_config("small");
    CHECK(d.cfa == Cfa::None);
    CHECK(d.black_level_dn == 0);
    CHECK(d.gain == 1);
    CHECK(d.bit_depth == 0);
    for (Cfa cfa : kAllCfa) {
      SystemConfig c = d;
      c.cfa = cfa;
      c.bit_depth = 14;
      c.black_level_dn = 512;
      c.gain = 2.5;
      const SystemConfig back = config_from_json_text(config_to_json_text(c));
      CHECK(back.cfa == cfa);
      CHECK(back.bit_depth == 14);
      CHECK(back.black_level_dn == 512);
      CHECK(back.gain == 2.5);
    }
    // Reference-side shape errors name the argument.
    CHECK_THROWS_WITH_AS(ref::raw_forward(RealStack(2, 2, 2), d), doctest::Contains("'rgb'"), InputError);
    CHECK_THROWS_WITH_AS(ref::raw_vjp(RealStack(3, 2, 2), RealStack(3, 2, 2), raw_config(Cfa::RGGB)),
                         doctest::Contains("'g_raw'"), InputError);
  }
}
