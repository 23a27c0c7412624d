// qdo fit on the raw frames (suite `fit-raw`, include/qdo/asbuilt/fit_raw.hpp and calibrate.hpp's
// reduce_psf_frames): a known as-built camera (the 4-level lens of the fit tests with its levels
// off by +15, -20, +20 nm, z off by 1.6 % and its sensor grid off by (0.3, -0.2) px) is imaged by
// a simulated monochromator sweep through the sensor as built (capture_psf_sweep: RGGB mosaic,
// black level, noise, rounding), and the raw-frame fit recovers it: without noise to the
// rounding of 16-bit codes; with Poisson-Gaussian noise within 3 of its own sigmas, with a
// reduced chi^2 near 1 (the weights are the noise); with less error than the fit of the stack
// qdo calibrate makes of the same frames. Bad input is refused naming the argument.
#include <doctest/doctest.h>

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "common.hpp"
#include "fit_common.hpp"
#include "qdo/data/config.hpp"
#include "qdo/data/io.hpp"
#include "qdo/asbuilt/fit.hpp"
#include "qdo/asbuilt/fit_raw.hpp"
#include "qdo/design/option_inputs.hpp"
#include "qdo/design/psf_spec.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/asbuilt/psf_sweep_capture.hpp"
#include "qdo/physics/calibrate.hpp"
#include "qdo/runtime/error.hpp"

using namespace qdo;
using namespace qdo::test;
namespace fs = std::filesystem;

namespace {

const std::vector<std::string> kFitted = {"levels", "z", "shift"};

// The fit tests' tiny system (N = 64, S = 32, 8 bands over 450 .. 550 nm) with a raw sensor: RGGB,
// the given bit depth, read noise (full-scale units) and full well (0: no shot noise).
SystemConfig raw_config(std::size_t bit_depth, double read_noise, double full_well, unsigned long long seed) {
  SystemConfig c = fit_config();
  c.cfa = Cfa::RGGB;
  c.bit_depth = bit_depth;
  c.black_level_dn = 64;
  c.read_noise_sigma = read_noise;
  c.full_well_photons = full_well;
  c.noise_seed = seed;
  c.validate();
  return c;
}

// The truth, theta of levels,z,shift = (level1..3, z, sx, sy).
std::vector<double> truth(const SystemConfig& cfg, const Design& d) {
  return {
      d.levels_m[1] + 15e-9, d.levels_m[2] - 20e-9, d.levels_m[3] + 20e-9, cfg.sensor_distance_m * 1.016, 0.3, -0.2};
}

// A sweep of the true camera into DIR/frames and DIR/darks (F = S + 32, the axis at (F/2, F/2)),
// and the options that take the window around that axis (the window the stack path gets too).
struct Sweep {
  fs::path dir;
  CalibrationOptions window;
  std::vector<double> amplitude;  // per band, the sweep's source power (full scale per unit PSF, largest colour)
};

Sweep simulate_sweep(const SystemConfig& cfg, const Design& d, const std::string& tag) {
  Sweep sw;
  sw.dir = temp_dir("fit_raw_" + tag);
  AsBuiltModel m(runtime(), cfg, Precision::F64, d, kFitted);
  PsfInput in;
  in.spec.kind = PsfSpec::Kind::File;
  in.spec.value = "the true camera";
  in.stack = m.evaluate(truth(cfg, d));
  PsfSweepCaptureSpec spec;
  spec.frame_px = cfg.sensor_size_px() + 32;
  spec.darks = 8;
  const PsfSweepCaptureResult r = capture_psf_sweep(runtime(), cfg, Precision::F64, in, spec, sw.dir.string());
  REQUIRE(r.frames_saturated == 0);
  sw.amplitude = r.amplitude;
  sw.window.centre = CentreRule::given;
  sw.window.centre_row = r.geometry.centre_row;
  sw.window.centre_col = r.geometry.centre_col;
  return sw;
}

// A parameter's error in a reader's unit (nm for levels, um for z, px for shifts), for messages.
double shown(const std::string& name, double e) { return name == "z" ? e * 1e6 : name[0] == 'l' ? e * 1e9 : e; }

FitOptions fit_options() {
  FitOptions opt;
  opt.parameters = kFitted;
  opt.max_iterations = 40;
  return opt;
}

// sum_k ((fitted_k - true_k) / sigma_k)^2: a fit's error in the given sigmas (the raw fit's).
double error_in_sigmas(const FitResult& r, const std::vector<double>& t, const FitResult& sigmas) {
  double e = 0;
  for (std::size_t k = 0; k < t.size(); ++k) e += std::pow((r.values[k].value - t[k]) / sigmas.values[k].sigma, 2);
  return e;
}

}  // namespace

TEST_SUITE("fit-raw") {
  TEST_CASE(
      "noise-free raw frames: the raw-frame fit recovers levels, z and the registration; the stack path is off by its "
      "calibration") {
    const SystemConfig cfg = raw_config(16, 0, 0, 1);
    const Design d = quantized_lens(cfg);
    const auto t = truth(cfg, d);
    const Sweep sw = simulate_sweep(cfg, d, "clean");
    const RawPsfWindows w =
        reduce_psf_frames(cfg, (sw.dir / "frames").string(), (sw.dir / "darks").string(), sw.window);
    // The window and what is usable: every pixel (no hot pixel, every colour responds).
    CHECK(w.s == cfg.sensor_size_px());
    CHECK(w.usable == cfg.bands * w.s * w.s);
    const RawFitResult raw = fit_as_built_raw(runtime(), cfg, Precision::F64, d, w, fit_options());
    const FitResult& r = raw.fit;
    REQUIRE(r.values.size() == t.size());
    CHECK(r.converged);
    // What is left is the codes' rounding (+-0.5 DN of a 39000 DN peak): the fit stops when a
    // step moves no parameter by more than FitOptions::step_sigmas = 1e-3 of its sigma (or the
    // loss falls by less than tolerance = 1e-7 of itself), so its distance to the minimum is far
    // below one sigma, and the minimum is within the rounding's sigmas of the truth: |error| <
    // 3 sigma, each sigma bounded (levels 0.05 nm, z 2e-6 z, registration 1e-4 px; measured 0.026 ..
    // 0.032 nm, 1.0e-6 z, 2e-6 and 5e-6 px), and the reduced chi^2 at most 1: the rounding of the
    // frames' codes against its variance 1/12 DN^2, the darks' being exact here.
    for (std::size_t k = 0; k < t.size(); ++k) {
      const FitValue& v = r.values[k];
      CAPTURE(v.name);
      INFO("fitted " << v.value << " +- " << v.sigma << ", true " << t[k] << ", design " << v.design << "; error "
                     << shown(v.name, v.value - t[k]));
      CHECK(std::fabs(v.value - t[k]) < 3 * v.sigma + 1e-3 * v.sigma);
      if (v.name == "z")
        CHECK(v.sigma < 2e-6 * t[k]);
      else if (v.name == "sx" || v.name == "sy")
        CHECK(v.sigma < 1e-4);
      else
        CHECK(v.sigma < 0.05e-9);
    }
    MESSAGE("noise-free: reduced chi^2 " << r.residual_sigma * r.residual_sigma << ", " << r.iterations
                                         << " iterations");
    CHECK(r.residual_sigma * r.residual_sigma < 1.0);
    // The source powers: the sweep's amplitudes, to the rounding.
    REQUIRE(r.source_power.size() == cfg.bands);
    for (std::size_t b = 0; b < cfg.bands; ++b)
      CHECK(r.source_power[b] == doctest::Approx(sw.amplitude[b]).epsilon(1e-4));
    // The stack qdo calibrate makes of the same frames (the same window, the darks' background
    // alone) carries the calibration's own error into the stack path's fit: its levels come back
    // 0.17 .. 0.30 nm off, 5 .. 11 of the raw fit's sigmas (sums of squared errors in those sigmas:
    // raw 3.4, stack 358).
    CalibrationOptions copt = sw.window;
    copt.ring_background = false;
    const CalibrationResult cal = calibrate_psf(cfg, (sw.dir / "frames").string(), (sw.dir / "darks").string(), copt);
    const FitResult st = fit_as_built(runtime(), cfg, Precision::F64, d, cal.psf, fit_options());
    const double e_raw = error_in_sigmas(r, t, r), e_stack = error_in_sigmas(st, t, r);
    for (std::size_t k = 0; k < t.size(); ++k)
      MESSAGE(r.values[k].name << ": raw error " << shown(r.values[k].name, r.values[k].value - t[k])
                               << ", stack error " << shown(r.values[k].name, st.values[k].value - t[k])
                               << " (raw sigma " << shown(r.values[k].name, r.values[k].sigma) << ")");
    MESSAGE("noise-free: sum of squared errors in the raw fit's sigmas: raw " << e_raw << ", stack " << e_stack);
    CHECK(10 * e_raw < e_stack);
    fs::remove_all(sw.dir);
  }

  TEST_CASE(
      "Poisson-Gaussian noise: errors within 3 of the fit's own sigmas, reduced chi^2 near 1, not worse than the stack "
      "path") {
    // 12 bits, read noise 1 DN (5 electrons), 20000 electrons at full scale, the peak at 0.6 of it
    // (a peak SNR about 110), one exposure per band, 8 darks.
    const SystemConfig cfg = raw_config(12, 0.00025, 20000, 5);
    const Design d = quantized_lens(cfg);
    const auto t = truth(cfg, d);
    const Sweep sw = simulate_sweep(cfg, d, "noisy");
    const RawPsfWindows w =
        reduce_psf_frames(cfg, (sw.dir / "frames").string(), (sw.dir / "darks").string(), sw.window);
    const RawFitResult raw = fit_as_built_raw(runtime(), cfg, Precision::F64, d, w, fit_options());
    const FitResult& r = raw.fit;
    REQUIRE(r.values.size() == t.size());
    // The weights are the noise: the reduced chi^2 (residual_sigma^2: chi^2 over the usable pixels
    // less the bands' source powers and the parameters) within 10 % of 1. Its own spread over
    // 8000 residuals is 1.6 %; the variances' shot term comes from each pixel's neighbours, which
    // a lens PSF's steep core makes approximate (noise seeds 5 .. 8 gave 0.986 .. 1.006; with the
    // read noise from calibrate's MAD of the lit frames' integer codes it was 0.88).
    const double chi2 = r.residual_sigma * r.residual_sigma;
    MESSAGE("reduced chi^2 " << chi2 << " over " << raw.usable_pixels << " pixels");
    // Two weighting passes (the default): the neighbours' shot noise, then the fitted model's; the
    // last pass's reduced chi^2 is the one sigma is scaled by.
    REQUIRE(r.chi2_reduced_passes.size() == 2);
    MESSAGE("reduced chi^2 per pass: " << r.chi2_reduced_passes[0] << ", " << r.chi2_reduced_passes[1]);
    CHECK(r.chi2_reduced_passes[1] == doctest::Approx(chi2).epsilon(1e-12));
    // Inside the model, with the noise the weights assume, the fit says its sigma reads as an error.
    INFO(r.sigma_unreliable_because);
    CHECK(r.sigma_reliable);
    CHECK(chi2 > 0.9);
    CHECK(chi2 < 1.1);
    // Each error within 3 sigma (the curvature sigma, scaled by the reduced chi^2): a Gaussian
    // error leaves that bound 0.3 % of the time; and the perturbation resolved (the design
    // outside 4 sigma).
    for (std::size_t k = 0; k < t.size(); ++k) {
      const FitValue& v = r.values[k];
      CAPTURE(v.name);
      INFO("fitted " << v.value << " +- " << v.sigma << " (jackknife " << v.sigma_jackknife << "), true " << t[k]
                     << ", design " << v.design << "; error " << (v.value - t[k]) / v.sigma << " sigma");
      CHECK(std::fabs(v.value - t[k]) < 3 * v.sigma);
      CHECK(std::fabs(v.design - t[k]) > 4 * v.sigma);
    }
    // The stack path on the same frames and window: its error measured in the raw fit's sigmas.
    // Noise seed 5: raw 5.0 (6 parameters: 6 expected), the stack 70 (its levels 4 .. 20 nm off,
    // z 1.3 um: the calibration's error at this noise, carried into the fit). With the joint
    // estimate's spread in absolute units, which shrank the lens's peak, and a 5 x 5 signal mask,
    // seeds 5 .. 8 gave the stack 27000 .. 85000 (levels 60 .. 590 nm off, z 36 .. 79 um).
    CalibrationOptions copt = sw.window;
    copt.ring_background = false;
    const CalibrationResult cal = calibrate_psf(cfg, (sw.dir / "frames").string(), (sw.dir / "darks").string(), copt);
    const FitResult st = fit_as_built(runtime(), cfg, Precision::F64, d, cal.psf, fit_options());
    const double e_raw = error_in_sigmas(r, t, r), e_stack = error_in_sigmas(st, t, r);
    for (std::size_t k = 0; k < t.size(); ++k)
      MESSAGE(r.values[k].name << ": raw error " << shown(r.values[k].name, r.values[k].value - t[k]) << " +- "
                               << shown(r.values[k].name, r.values[k].sigma) << ", stack error "
                               << shown(r.values[k].name, st.values[k].value - t[k]) << " +- "
                               << shown(r.values[k].name, st.values[k].sigma));
    MESSAGE("noisy: sum of squared errors in the raw fit's sigmas: raw " << e_raw << ", stack " << e_stack);
    CHECK(10 * e_raw < e_stack);
    fs::remove_all(sw.dir);
  }

  TEST_CASE("re-weighting: the variance is read plus shot noise of a signal; with the true signal the weights are the noise") {
    const SystemConfig cfg = raw_config(12, 0.00025, 20000, 6);
    const Design d = quantized_lens(cfg);
    const Sweep sw = simulate_sweep(cfg, d, "reweight");
    const RawPsfWindows w =
        reduce_psf_frames(cfg, (sw.dir / "frames").string(), (sw.dir / "darks").string(), sw.window);
    // The expected signal of the true camera: a_b G PSF_b (full-scale units).
    AsBuiltModel m(runtime(), cfg, Precision::F64, d, kFitted);
    const RealStack psf = m.evaluate(truth(cfg, d));
    RealStack expected(psf.planes, psf.rows, psf.cols, 0.0);
    const std::size_t plane = psf.plane_size();
    for (std::size_t i = 0; i < psf.data.size(); ++i) expected.data[i] = sw.amplitude[i / plane] * w.gain.data[i] * psf.data[i];
    const RawPsfWindows t = reweight_raw_windows(w, expected);
    // The split: variance = read + shot per signal x signal, pixel for pixel; unusable pixels keep 0.
    double chi2_true = 0, chi2_neighbours = 0;
    std::size_t n = 0;
    for (std::size_t i = 0; i < w.variance.data.size(); ++i) {
      if (!(w.gain.data[i] > 0)) {
        CHECK(t.variance.data[i] == 0);
        continue;
      }
      CHECK(t.variance.data[i] == doctest::Approx(w.read_variance.data[i] + w.shot_per_signal.data[i] * std::max(expected.data[i], 0.0)));
      CHECK(w.shot_per_signal.data[i] > 0);
      const double e = w.signal.data[i] - expected.data[i];
      chi2_true += e * e / t.variance.data[i];
      chi2_neighbours += e * e / w.variance.data[i];
      ++n;
    }
    // The residuals of the true signal over the variances of the true signal: chi^2 per pixel 1
    // within 7 % (its spread over 8192 pixels is 1.6 %; the darks' read variance is an estimate).
    chi2_true /= double(n);
    chi2_neighbours /= double(n);
    MESSAGE("chi^2 per pixel of the true signal: with its own variances " << chi2_true << ", with the neighbours' "
                                                                          << chi2_neighbours);
    CHECK(chi2_true > 0.93);
    CHECK(chi2_true < 1.07);
    // A camera outside the model: its sensor grid is off by (0.3, -0.2) px, and the fit holds the
    // registration at 0. The misfit is far above the noise, and the fit says its sigma does not
    // bound the error.
    FitOptions held = fit_options();
    held.parameters = {"levels", "z"};
    held.lateral_starts = 1;
    const RawFitResult off = fit_as_built_raw(runtime(), cfg, Precision::F64, d, w, held);
    MESSAGE("registration held at 0: reduced chi^2 " << off.fit.residual_sigma * off.fit.residual_sigma << "; "
                                                     << off.fit.sigma_unreliable_because);
    CHECK(off.fit.residual_sigma * off.fit.residual_sigma > kReducedChi2Reliable);
    CHECK_FALSE(off.fit.sigma_reliable);
    CHECK(off.fit.sigma_unreliable_because.find("reduced chi^2") != std::string::npos);
    // The windows must match: a stack of another shape is refused.
    CHECK_THROWS_AS(reweight_raw_windows(w, RealStack(1, 2, 2, 0.0)), InputError);
    CHECK_THROWS_AS(fit_as_built_raw(runtime(), cfg, Precision::F64, d, w, fit_options(), 6), InputError);
    fs::remove_all(sw.dir);
  }

  TEST_CASE(
      "refusals name the argument: a missing band, a frame of another size, windows of another configuration; qdo "
      "fit's options") {
    const SystemConfig cfg = raw_config(12, 0.0005, 0, 3);
    const Design d = quantized_lens(cfg);
    const Sweep sw = simulate_sweep(cfg, d, "refuse");
    const std::string darks = (sw.dir / "darks").string();
    const auto refusal = [&](const std::string& frames) {
      try {
        reduce_psf_frames(cfg, frames, darks, sw.window);
      } catch (const InputError& e) {
        return std::string(e.what());
      }
      return std::string("(accepted)");
    };
    // A band without a frame (band 2, as capture_psf_sweep names it).
    const double nm2 = cfg.wavelengths_nm()[2];
    char gone[64];
    std::snprintf(gone, sizeof gone, "psf_%gnm.png", nm2);
    const fs::path missing = sw.dir / "missing";
    fs::create_directories(missing);
    for (const auto& e : fs::directory_iterator(sw.dir / "frames"))
      if (e.path().filename() != gone) fs::copy_file(e.path(), missing / e.path().filename());
    const std::string m = refusal(missing.string());
    CAPTURE(m);
    CHECK(m.find("--frames") != std::string::npos);
    CHECK(m.find(to_str(nm2) + " nm") != std::string::npos);
    // A frame of another size than the others.
    const fs::path sized = sw.dir / "sized";
    fs::create_directories(sized);
    for (const auto& e : fs::directory_iterator(sw.dir / "frames"))
      fs::copy_file(e.path(), sized / e.path().filename());
    write_png16_gray((sized / "psf_550nm.png").string(), Map2D(40, 40, 100.0));
    const std::string s = refusal(sized.string());
    CAPTURE(s);
    CHECK(s.find("psf_550nm.png") != std::string::npos);
    CHECK(s.find("differs") != std::string::npos);
    // Windows made for another configuration.
    const RawPsfWindows w = reduce_psf_frames(cfg, (sw.dir / "frames").string(), darks, sw.window);
    SystemConfig other = cfg;
    other.bands = 5;
    other.wavelength_step_nm = 25;
    try {
      fit_as_built_raw(runtime(), other, Precision::F64, d, w, fit_options());
      FAIL("accepted 8-band windows for a 5-band configuration");
    } catch (const InputError& e) {
      CHECK(std::string(e.what()).find("8 x 32 x 32") != std::string::npos);
    }
    // qdo fit: the stack or the frames, not both; frames need darks; darks and whites need frames.
    std::ofstream(sw.dir / "cfg.json") << config_to_json_text(cfg) << "\n";
    write_design((sw.dir / "design.h5").string(), d);
    write_psf((sw.dir / "psf_given.h5").string(), RealStack(cfg.bands, 32, 32, 1.0 / 1024), cfg.wavelengths_nm(),
              cfg.sensor_pitch_m);
    const std::string base =
        "fit --config " + (sw.dir / "cfg.json").string() + " --design " + (sw.dir / "design.h5").string();
    const std::string frames = " --frames " + (sw.dir / "frames").string();
    const auto refused = [&](const std::string& extra, const std::vector<std::string>& named) {
      const Run run = qdo_run(base + " " + extra + " --out " + (sw.dir / "out").string());
      CAPTURE(extra);
      CAPTURE(run.out);
      CHECK(run.code == 2);
      for (const auto& n : named) CHECK(run.out.find(n) != std::string::npos);
      CHECK(!fs::exists(sw.dir / "out"));
    };
    refused("--psf " + (sw.dir / "psf_given.h5").string() + frames + " --darks " + darks,
            {"--psf", "--frames", "not both"});
    refused(frames, {"--darks", "(missing)"});
    refused("--psf " + (sw.dir / "psf_given.h5").string() + " --darks " + darks, {"--darks", "only with --frames"});
    refused("--psf " + (sw.dir / "psf_given.h5").string() + " --white " + darks, {"--white", "only with --frames"});
    refused("", {"--psf", "--frames"});
    refused(" --frames " + missing.string() + " --darks " + darks, {"--frames", to_str(nm2) + " nm"});
    refused(frames + " --darks " + darks + " --centre 1,2,3", {"--centre", "ROW,COL"});
    // calibrate's frame reduction options: checked, only with --frames, and they reach the reduction
    // (a least SNR no band of these frames reaches refuses them, naming the option).
    refused(frames + " --darks " + darks + " --hot-sigma 0.5", {"--hot-sigma", "0.5"});
    refused(frames + " --darks " + darks + " --min-response 0", {"--min-response"});
    refused("--psf " + (sw.dir / "psf_given.h5").string() + " --min-snr 5", {"--min-snr", "only with --frames"});
    refused(frames + " --darks " + darks + " --min-snr 1e9", {"--min-snr", "psf_"});
    fs::remove_all(sw.dir);
  }

  TEST_CASE("qdo fit --frames end to end: the as-built values from the raw frames, fit.json with the source powers") {
    const SystemConfig cfg = raw_config(16, 0, 0, 1);
    const Design d = quantized_lens(cfg);
    const auto t = truth(cfg, d);
    // The camera with a window that samples the transfer function, as qdo fit models it by default.
    SystemConfig cam = cfg;
    cam.padding_px = sampled_padding_px(cfg, kModelPaddingZMargin * cfg.sensor_distance_m).padding_px;
    const Sweep sw = simulate_sweep(cam, d, "cli");
    std::ofstream(sw.dir / "cfg.json") << config_to_json_text(cfg) << "\n";
    write_design((sw.dir / "design.h5").string(), d);
    const Run run =
        qdo_run("fit --config " + (sw.dir / "cfg.json").string() + " --design " + (sw.dir / "design.h5").string() +
                " --frames " + (sw.dir / "frames").string() + " --darks " + (sw.dir / "darks").string() + " --centre " +
                to_str(sw.window.centre_row) + "," + to_str(sw.window.centre_col) + " --fit levels,z,shift --out " +
                (sw.dir / "out").string());
    INFO(run.out);
    REQUIRE(run.code == 0);
    CHECK(run.out.find("raw frames") != std::string::npos);
    for (const char* f : {"fit.h5", "fit.json", "design.h5", "config.json", "fit.png", "residual.png"})
      CHECK(fs::exists(sw.dir / "out" / f));
    const auto j = nlohmann::json::parse(slurp(sw.dir / "out" / "fit.json"));
    CHECK(j["data"] == "raw frames");
    CHECK(j["model_padding_px"] == cam.padding_px);
    // The window's centre and the rule that chose it, in fit.json and in the fit's psf.h5.
    const std::string centre = to_str(sw.window.centre_row) + "," + to_str(sw.window.centre_col);
    CHECK(j["window_centre_row_col"] == centre);
    CHECK(j["window_centre_rule"] == "given");
    const auto pa = h5_read_root_attrs((sw.dir / "out" / "psf.h5").string());
    CHECK(pa.at("centre_row_col") == centre);
    CHECK(pa.at("centre_rule") == "given");
    REQUIRE(j["source_power"].size() == cfg.bands);
    CHECK(j["source_power"][3].get<double>() == doctest::Approx(sw.amplitude[3]).epsilon(1e-3));
    REQUIRE(j["parameters"].size() == t.size());
    CHECK(std::fabs(j["parameters"][0]["value"].get<double>() - t[0]) < 0.1e-9);
    CHECK(std::fabs(j["parameters"][3]["value"].get<double>() - t[3]) < 1e-5 * t[3]);
    fs::remove_all(sw.dir);
  }
}
