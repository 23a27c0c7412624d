// The decoder registry (decoder_registry.hpp): a decoder added by this file alone (a static
// DecoderRegistration; no other file knows it) is named in a spec and reconstructs in `qdo eval`'s
// library call; unknown names are refused naming the known ones; the built-in decoders are the
// Wiener and CG decoders they were before the registry.
#include <cmath>
#include <filesystem>
#include <memory>
#include <string>

#include <nlohmann/json.hpp>

#include "common.hpp"
#include "qdo/decode/decoder_registry.hpp"
#include "qdo/design/design_run.hpp"
#include "qdo/decode/encoders.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/evaluate/eval.hpp"
#include "qdo/data/io.hpp"
#include "qdo/decode/testset.hpp"
#include "qdo/decode/wiener.hpp"

using namespace qdo;
using namespace qdo::test;

namespace {

// The toy: every band of every pixel is the constant `level` (parameter, default 0.25), whatever
// the image; known exactly, so its reconstructions and metrics can be checked.
class ToyDecoder final : public Decoder {
 public:
  ToyDecoder(std::size_t bands, double level) : bands_(bands), level_(level) {}
  RealStack decode(const RealStack& y) const override {
    ++images_decoded();
    return RealStack(bands_, y.rows, y.cols, level_);
  }
  std::size_t bands() const override { return bands_; }
  std::size_t channels() const override { return 3; }
  static int& images_decoded() {
    static int n = 0;
    return n;
  }

 private:
  std::size_t bands_;
  double level_;
};

DecoderInputs& last_inputs() {
  static DecoderInputs in;
  return in;
}

const DecoderRegistration toy_registration{
    {"toy", "a test's constant decoder: toy:level=V", false, [](const DecoderInputs& in) -> std::unique_ptr<Decoder> {
       last_inputs() = in;
       return std::make_unique<ToyDecoder>(in.psf.planes, std::stod(in.spec.param("level", "0.25")));
     },
     nullptr}};

// A Wiener do run of the tiny configuration (4 steps of N = 32, 3 bands).
std::string tiny_wiener_run(const std::filesystem::path& dir) {
  DesignRunOptions o;
  o.cfg = tiny_config(32, 3);
  o.design.mode = DesignMode::DO;
  o.design.quantizer.levels = 4;
  o.design.steps_per_epoch = 2;
  o.design.t0_epochs = 0.5;
  o.design.t1_epochs = 2;
  o.design.seed = 7;
  o.epochs = 2;
  o.synthetic_scenes = 3;
  o.precision = runtime().has_fp64() ? Precision::F64 : Precision::F32;
  o.out = (dir / "run").string();
  o.quiet = true;
  run_design(runtime(), o, false);
  return o.out;
}

}  // namespace

TEST_SUITE("decoders") {
  TEST_CASE("a decoder registered by one file is named in a spec and reconstructs in qdo eval (evaluate_run)") {
    REQUIRE(decoder_registered("toy"));
    const auto names = decoder_names();
    REQUIRE(names.size() >= 4);
    CHECK(names[0] == "wiener");  // the built-in ones first
    CHECK(names.back() == "toy");
    const DecoderSpec spec = decoder_spec_from_string("toy:level=0.375");
    CHECK(spec.kind == DecoderSpec::Kind::Named);
    CHECK(spec.kind_name() == "toy");
    CHECK(spec.param("level") == "0.375");
    CHECK(decoder_spec_from_string(spec.to_string()) == spec);
    CHECK(decoder_spec_from_string("toy").to_string() == "toy");

    const auto dir = temp_dir("decoders_toy");
    const std::string run = tiny_wiener_run(dir);
    EvalOptions e;
    e.run = run;
    e.synthetic_scenes = 2;
    e.renders = 2;  // every patch (one per synthetic S x S scene) into reconstructions.h5
    e.decoder_kind = spec;
    e.out = (dir / "toy").string();
    ToyDecoder::images_decoded() = 0;
    const EvalResult r = evaluate_run(runtime(), e);
    REQUIRE(r.rows.size() == 2);
    CHECK(ToyDecoder::images_decoded() == 2);
    // What the factory was given: the evaluated design's PSF stack and the run's prior and sigma.
    const std::size_t s = tiny_config(32, 3).sensor_size_px();
    CHECK(last_inputs().psf.planes == 3);
    CHECK(last_inputs().psf.rows == s);
    CHECK(last_inputs().prior.rows == s);
    CHECK(last_inputs().noise_sigma == 1e-3);
    CHECK(last_inputs().spec == spec);
    // The reconstructions are the toy's, and the metrics are those of the toy's cubes.
    const std::string h5 = e.out + "/reconstructions.h5";
    for (std::size_t k = 0; k < 2; ++k) {
      CAPTURE(k);
      const H5Dataset rec = h5_read(h5, "/recon_" + std::to_string(k)),
                      truth = h5_read(h5, "/truth_" + std::to_string(k));
      for (double v : rec.data) REQUIRE(v == 0.375);
      RealStack x(truth.shape[0], truth.shape[1], truth.shape[2]);
      x.data = truth.data;
      const testset::Scores want = testset::score(RealStack(x.planes, x.rows, x.cols, 0.375), x);
      CHECK(r.rows[k].psnr == want.psnr);
      CHECK(r.rows[k].ssim == want.ssim);
      CHECK(r.rows[k].rmse == want.rmse);
      CHECK(r.rows[k].sam_rad == want.sam_rad);
    }
    const auto mj = nlohmann::json::parse(slurp(e.out + "/metrics.json"));
    CHECK(mj.at("decoder_kind") == "toy:level=0.375");
    CHECK(mj.at("decoder") == "matched");
    CHECK(mj.at("conventions").at("imaging").get<std::string>().find("decoder toy:level=0.375") != std::string::npos);
    std::filesystem::remove_all(dir);
  }

  TEST_CASE("unknown or malformed decoder names are refused, naming the known ones") {
    const std::string msg = input_error_of([] { decoder_spec_from_string("nosuch"); });
    CHECK(msg.find("--decoder") != std::string::npos);
    for (const std::string& n : decoder_names()) {
      CAPTURE(n);
      CHECK(msg.find(n) != std::string::npos);
    }
    CHECK_THROWS_WITH_AS(decoder_spec_from_string("Toy"), doctest::Contains("toy"), InputError);
    CHECK_THROWS_WITH_AS(decoder_spec_from_string("toy:"), doctest::Contains("nothing after"), InputError);
    CHECK_THROWS_WITH_AS(decoder_spec_from_string("toy:level"), doctest::Contains("key=value"), InputError);
    CHECK_THROWS_WITH_AS(decoder_spec_from_string("toy:level=1,level=2"), doctest::Contains("given once"), InputError);
    CHECK_THROWS_WITH_AS(decoder_spec_from_string("wiener:x=1"), doctest::Contains("--decoder"), InputError);
    // A spec made by hand with an unregistered name: the registry refuses it, naming the known ones.
    DecoderSpec ghost;
    ghost.kind = DecoderSpec::Kind::Named;
    ghost.name = "ghost";
    DecoderInputs in;
    in.spec = ghost;
    const std::string m2 = input_error_of([&] { make_decoder(in); });
    CHECK(m2.find("ghost") != std::string::npos);
    CHECK(m2.find("wiener") != std::string::npos);
    CHECK(m2.find("toy") != std::string::npos);
    // Registering: a taken name, a malformed name, no factory.
    const DecoderFactory f = [](const DecoderInputs&) -> std::unique_ptr<Decoder> { return nullptr; };
    CHECK_THROWS_WITH_AS(register_decoder({"toy", "", false, f, nullptr}), doctest::Contains("toy"), InputError);
    CHECK_THROWS_WITH_AS(register_decoder({"Bad Name", "", false, f, nullptr}), doctest::Contains("Bad Name"), InputError);
    CHECK_THROWS_WITH_AS(register_decoder({"nofactory", "", false, nullptr, nullptr}), doctest::Contains("nofactory"),
                         InputError);
    // A design run trains wiener or a network; another registered decoder is refused by name.
    DesignRunOptions o;
    o.cfg = tiny_config(32, 3);
    o.out = "(unused)";
    o.decoder = decoder_spec_from_string("cg");
    CHECK_THROWS_WITH_AS(o.validate(), doctest::Contains("decoder"), InputError);
  }

  TEST_CASE("the built-in wiener and cg decoders are the Wiener and CG decoders of the PSF camera") {
    const std::size_t s = 16;
    std::vector<RealStack> scenes;
    for (unsigned k = 0; k < 4; ++k) scenes.push_back(random_cube(3, s, s, 11 + k));
    DecoderInputs in;
    in.prior = wiener::estimate_prior(scenes, 8);
    in.psf = random_cube(3, 5, 5, 3);
    in.srf = Eigen::MatrixXd::Constant(3, 3, 1.0 / 3.0);
    in.srf(0, 0) = 0.6;
    in.srf(2, 2) = 0.5;
    in.noise_sigma = 1e-2;
    const ComplexStack otf = wiener::psf_to_otf(in.psf, s, s);
    const WienerDecoder w(otf, in.srf, in.prior, in.noise_sigma);
    const RealStack y = wiener::simulate_measurement(scenes[0], otf, in.srf);
    in.spec = decoder_spec_from_string("wiener");
    const auto dw = make_decoder(in);
    CHECK(dw->decode(y).data == w.decode(y).data);
    CHECK(dw->description() == "Wiener decoder");
    in.spec = decoder_spec_from_string("cg:tolerance=1e-13,max_iterations=20000");
    const auto dc = make_decoder(in);
    const CgDecoder cg(std::make_shared<DoeEncoder>(otf, in.srf), in.prior, in.noise_sigma, CgOptions{1e-13, 20000});
    CHECK(dc->decode(y).data == cg.decode(y).data);
    // ... and CG, converged, to the Wiener solution (encoders.hpp).
    const RealStack a = dc->decode(y), b = w.decode(y);
    double num = 0, den = 0;
    for (std::size_t i = 0; i < a.size(); ++i) {
      num += (a.data[i] - b.data[i]) * (a.data[i] - b.data[i]);
      den += b.data[i] * b.data[i];
    }
    CHECK(std::sqrt(num / den) < 1e-6);
    in.spec = decoder_spec_from_string("cg:tolerance=2");
    CHECK_THROWS_WITH_AS(make_decoder(in), doctest::Contains("tolerance"), InputError);
    in.spec = decoder_spec_from_string("cg:iterations=3");
    CHECK_THROWS_WITH_AS(make_decoder(in), doctest::Contains("iterations"), InputError);
    // The network is a run's: outside a run folder it is refused.
    in.spec = decoder_spec_from_string("resunet");
    CHECK_THROWS_WITH_AS(make_decoder(in), doctest::Contains("resunet"), InputError);
  }

  TEST_CASE(
      "qdo eval --decoder-kind: the run's own decoder by default, wiener the same numbers, cg close, unknown names "
      "refused") {
    const auto dir = temp_dir("decoders_eval");
    const std::string run = tiny_wiener_run(dir);
    const std::string common = " --synthetic-scenes 2 --renders 0 --precision " +
                               std::string(runtime().has_fp64() ? "f64" : "f32") + " --out ";
    const Run def = qdo_run("eval " + run + common + (dir / "def").string());
    CAPTURE(def.out);
    REQUIRE(def.code == 0);
    const Run wie = qdo_run("eval " + run + " --decoder-kind wiener" + common + (dir / "wiener").string());
    REQUIRE(wie.code == 0);
    const Run cg = qdo_run("eval " + run + " --decoder-kind cg" + common + (dir / "cg").string());
    CAPTURE(cg.out);
    REQUIRE(cg.code == 0);
    const auto jd = nlohmann::json::parse(slurp(dir / "def" / "metrics.json"));
    const auto jw = nlohmann::json::parse(slurp(dir / "wiener" / "metrics.json"));
    const auto jc = nlohmann::json::parse(slurp(dir / "cg" / "metrics.json"));
    CHECK(jd.at("decoder_kind") == "wiener");
    // The same decoder in two processes: equal up to the rounding of the FFT plans each process
    // chose (FFTW_MEASURE picks by timing; under load a plan may differ: ~1e-12 relative seen).
    for (const auto& [k, v] : jw.at("mean").items()) {
      CAPTURE(k);
      CHECK(jd.at("mean").at(k).get<double>() == doctest::Approx(v.get<double>()).epsilon(1e-9));
    }
    CHECK(jc.at("decoder_kind") == "cg");
    // CG at its default tolerance (1e-6) on this camera: near the Wiener decoder, not equal to it.
    CHECK(std::fabs(jc.at("mean").at("psnr_db").get<double>() - jd.at("mean").at("psnr_db").get<double>()) < 1.0);
    CHECK(jc.at("mean") != jd.at("mean"));
    const Run bad = qdo_run("eval " + run + " --decoder-kind nosuch" + common + (dir / "bad").string());
    CAPTURE(bad.out);
    CHECK(bad.code == 2);
    CHECK(bad.out.find("--decoder") != std::string::npos);
    CHECK(bad.out.find("cg") != std::string::npos);
    CHECK_FALSE(std::filesystem::exists(dir / "bad"));
    // The network is the run's own: a Wiener run has none.
    const Run net = qdo_run("eval " + run + " --decoder-kind resunet" + common + (dir / "net").string());
    CAPTURE(net.out);
    CHECK(net.code == 2);
    std::filesystem::remove_all(dir);
  }
}
