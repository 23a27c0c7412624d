// The built camera's model window (suite model-padding): sampled_padding_px (optics.hpp) against
// the closed form of each propagator's sampling limit, and minimal; the Simulator's own sampling
// report at that padding; --model-padding (option_inputs.hpp apply_model_padding) in qdo fit's
// request and in qdo fabricate: auto raises the presets' window and never lowers one, config keeps
// it, an integer sets it, and bad values are refused naming the option.
#include <cmath>
#include <string>

#include "common.hpp"
#include "fit_common.hpp"
#include "qdo/design/option_inputs.hpp"
#include "qdo/fab/fab.hpp"
#include "qdo/fab/fab_text.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/physics/simulator.hpp"
#include "qdo/runtime/error.hpp"

using namespace qdo;
using namespace qdo::test;

namespace {

std::size_t window_px(SystemConfig c, std::size_t padding_px) {
  c.padding_px = padding_px;
  return PropagationGeometry::from_config(c).m;
}

// The closed forms, written from the limits' definitions: Fresnel, the chirp's phase step between
// bins reaches pi at |f| = M pitch / (2 lambda z), so Nyquist 1 / (2 pitch) needs M pitch^2 >= lambda z;
// the angular spectrum's band limit 1 / (lambda sqrt((2 z / W)^2 + 1)) >= 1 / (2 pitch) needs
// W >= 2 z / sqrt((2 pitch / lambda)^2 - 1), W = M pitch.
TextOptions given(const std::string& name, const std::string& value) {
  TextOptions t;
  t.opt[name] = value;
  return t;
}

bool sampled_closed_form(const SystemConfig& c, std::size_t m, double z_m) {
  for (double w_nm : c.wavelengths_nm()) {
    const double lambda = w_nm * 1e-9, p = c.pitch_m, window = double(m) * p;
    if (c.propagator == Propagator::Fresnel) {
      if (double(m) * p * p < lambda * z_m) return false;
    } else if (window < 2 * z_m / std::sqrt(std::pow(2 * p / lambda, 2) - 1)) {
      return false;
    }
  }
  return true;
}

}  // namespace

TEST_SUITE("model-padding") {
  TEST_CASE("sampled_padding_px is the smallest padding the closed form allows, for both propagators") {
    for (const Propagator prop : {Propagator::Fresnel, Propagator::AngularSpectrum}) {
      for (const std::string preset : {"small", "paper"}) {
        SystemConfig c = preset_config(preset);
        c.propagator = prop;
        for (const double zf : {1.0, 1.05, 1.3}) {
          const double z = zf * c.sensor_distance_m;
          CAPTURE(preset);
          CAPTURE(zf);
          CAPTURE(int(prop));
          const SampledPadding s = sampled_padding_px(c, z);
          REQUIRE(s.sampled);
          CHECK(sampled_closed_form(c, window_px(c, s.padding_px), z));
          if (s.padding_px > 0) CHECK_FALSE(sampled_closed_form(c, window_px(c, s.padding_px - 1), z));
        }
        // The presets keep the paper's window, which does not sample the long wavelengths at z.
        CHECK_FALSE(sampled_closed_form(c, window_px(c, c.padding_px), c.sensor_distance_m));
      }
    }
    // The small preset at 5 % beyond its z: M >= 700 nm * 13.125 mm / (4 um)^2 = 574.2, so
    // M = 576 = 2^6 * 9; padding 153 is the first to reach it (N + 2 p = 562 -> 567, whose M - N is
    // odd -> 576), the window of padding 160 exactly.
    SystemConfig small = preset_config("small");
    const std::size_t p_small = sampled_padding_px(small, 1.05 * small.sensor_distance_m).padding_px;
    CHECK(p_small == 153);
    CHECK(window_px(small, p_small) == 576);
    CHECK(window_px(small, p_small) == window_px(small, 160));
    // Nothing up to 4 n samples a distance 100 x as long: the limit, and said so.
    const SampledPadding far = sampled_padding_px(small, 100 * small.sensor_distance_m);
    CHECK_FALSE(far.sampled);
    CHECK(far.padding_px == 4 * small.n);
  }

  TEST_CASE("at that padding the Simulator's own report finds every band sampled, at the configuration's it does not") {
    SystemConfig c = tiny_config(64, 8);
    c.wavelength_start_nm = 400;
    c.wavelength_step_nm = 300.0 / 7;  // 400 .. 700 nm
    const Map2D h = random_heights(c.n, c.h_max_m(), 5);
    {
      Simulator sim(runtime(), c, Precision::F32);
      sim.set_heights(h);
      sim.compute_psf();
      CHECK(sim.sampling().bands.back().undersampled);
    }
    c.padding_px = sampled_padding_px(c, c.sensor_distance_m).padding_px;
    Simulator sim(runtime(), c, Precision::F32);
    sim.set_heights(h);
    sim.compute_psf();
    for (const BandSampling& b : sim.sampling().bands) {
      CAPTURE(b.wavelength_nm);
      CHECK_FALSE(b.undersampled);
      CHECK(b.f_limit_per_m >= b.f_nyquist_per_m);
    }
  }

  TEST_CASE("--model-padding: auto raises and never lowers, config keeps, an integer sets, the rest is refused") {
    const SystemConfig small = preset_config("small");
    const double z = small.sensor_distance_m;
    const std::size_t need = sampled_padding_px(small, kModelPaddingZMargin * z).padding_px;
    REQUIRE(need > small.padding_px);
    {
      SystemConfig c = small;
      const std::string note = apply_model_padding(c, TextOptions{}, z);
      CHECK(c.padding_px == need);
      CHECK(note.find("raised from 64 to 153") != std::string::npos);
    }
    {
      SystemConfig c = small;
      c.padding_px = need + 40;  // a user's wider window stays
      CHECK(apply_model_padding(c, given("model-padding", "auto"), z).empty());
      CHECK(c.padding_px == need + 40);
    }
    {
      SystemConfig c = small;
      CHECK(apply_model_padding(c, given("model-padding", "config"), z).empty());
      CHECK(c.padding_px == small.padding_px);
    }
    {
      SystemConfig c = small;
      CHECK_FALSE(apply_model_padding(c, given("model-padding", "200"), z).empty());
      CHECK(c.padding_px == 200);
    }
    for (const std::string bad : {"1025", "-1", "wide", ""}) {
      SystemConfig c = small;
      CAPTURE(bad);
      CHECK_THROWS_WITH_AS(apply_model_padding(c, given("model-padding", bad), z),
                           doctest::Contains("--model-padding"), InputError);
      CHECK(c.padding_px == small.padding_px);
    }
  }

  TEST_CASE("qdo fabricate's as-built configuration gets the model window; the relief and the rest do not change") {
    const SystemConfig c = fit_config();
    const Design d = quantized_lens(c);
    fab::AsBuiltOptions o;
    o.seed = 3;
    const fab::AsBuiltCamera plain = fab::fabricate(d, c, o);
    CHECK(plain.cfg.padding_px == c.padding_px);
    fab::as_built_padding_from_options(o, c, TextOptions{});
    REQUIRE(o.padding_px.has_value());
    CHECK(*o.padding_px == sampled_padding_px(c, kModelPaddingZMargin * c.sensor_distance_m).padding_px);
    const fab::AsBuiltCamera padded = fab::fabricate(d, c, o);
    CHECK(padded.cfg.padding_px == *o.padding_px);
    CHECK(padded.design.height_m.data == plain.design.height_m.data);
    CHECK(padded.cfg.sensor_distance_m == plain.cfg.sensor_distance_m);
    fab::AsBuiltOptions kept;
    fab::as_built_padding_from_options(kept, c, given("model-padding", "config"));
    CHECK_FALSE(kept.padding_px.has_value());
  }
}
