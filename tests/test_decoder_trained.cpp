// One decoder mechanism for training and evaluation (decoder_registry.hpp): a decoder trained
// with the optics, added by this file alone (a DecoderRegistration whose entry has a `train`
// factory; no production file knows it), is trained by a design run (objective network), kept in
// the run folder and resumed from it, and decodes in `qdo eval` (evaluate_run) with the state the
// run trained; the registry's refusals for such entries name what is wrong.
#include <cmath>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "common.hpp"
#include "joint_common.hpp"
#include "qdo/decode/decoder_registry.hpp"
#include "qdo/design/design_run.hpp"
#include "qdo/evaluate/eval.hpp"
#include "qdo/runtime/error.hpp"

using namespace qdo;
using namespace qdo::test;

namespace {

// The test's per-pixel affine decoder (AffineNet, joint_common.hpp), recording what the registry
// and the run do with it: the states loaded into it and the images it reconstructed.
struct Record {
  std::vector<std::string> loaded;  // the bytes of each load(), in order
  std::size_t images_reconstructed = 0;
};
Record& record() {
  static Record r;
  return r;
}

class RecordedAffine final : public NetworkDecoder {
 public:
  explicit RecordedAffine(const NetworkSettings& s) : net_(s) {}
  std::string spec() const override { return net_.spec(); }
  std::size_t parameter_count() const override { return net_.parameter_count(); }
  NetworkStep train(const std::vector<RealStack>& y, const std::vector<RealStack>& x, double lr) override {
    return net_.train(y, x, lr);
  }
  std::vector<RealStack> reconstruct(const std::vector<RealStack>& y) override {
    record().images_reconstructed += y.size();
    return net_.reconstruct(y);
  }
  std::string save() const override { return net_.save(); }
  void load(const std::string& bytes, const std::string& origin) override {
    record().loaded.push_back(bytes);
    net_.load(bytes, origin);
  }

 private:
  AffineNet net_;
};

// The whole decoder: a name, a summary, trained = true and the train factory. `make` is left to
// the registry (the run's state in inference mode). Registered on first use rather than at static
// initialisation, so that the registry of the other suites in this test program stays as it is.
void register_affine() {
  static const DecoderRegistration registration{
      {"affine", "a test's per-pixel affine map RGB -> bands, trained with the optics", true, nullptr,
       [](const NetworkSettings& s) -> std::unique_ptr<NetworkDecoder> { return std::make_unique<RecordedAffine>(s); }}};
}

DesignRunOptions affine_run(const std::string& out) {
  DesignRunOptions o = net_run(out, DesignMode::QDOA);
  o.decoder = decoder_spec_from_string("affine");
  o.quiet = true;
  return o;
}

}  // namespace

TEST_SUITE("decoder-trained") {
  TEST_CASE("a decoder registered by one file trains with the optics in qdo design and decodes in qdo eval") {
    register_affine();
    const DecoderSpec spec = decoder_spec_from_string("affine");
    CHECK(spec.kind == DecoderSpec::Kind::Named);
    CHECK(spec.network());
    CHECK(decoder_entry("affine").trained);
    CHECK_FALSE(decoder_spec_from_string("cg").network());
    CHECK_FALSE(decoder_spec_from_string("wiener").network());
    CHECK(decoder_spec_from_string("resunet").network());

    const auto dir = temp_dir("decoder_trained");
    const std::string run = (dir / "run").string();
    record() = Record{};
    const DesignRunResult r = run_design(runtime(), affine_run(run), false);
    CHECK(r.steps_done == 6);
    CHECK(std::isfinite(r.final_loss));
    const auto cj = nlohmann::json::parse(slurp(run + "/config.json"));
    CHECK(cj.dump().find("\"affine\"") != std::string::npos);

    // The run's state: the trained decoder's, not a fresh one's.
    const std::unique_ptr<NetworkDecoder> trained = load_run_network(run);
    REQUIRE_FALSE(record().loaded.empty());
    const std::string state = record().loaded.back();
    CHECK(trained->spec() == "affine");
    CHECK(trained->save() == state);
    NetworkSettings fresh_settings;
    fresh_settings.spec = spec;
    fresh_settings.out_channels = 3;
    fresh_settings.seed = 3;  // net_run's seed: the run started from this state
    CHECK(make_trained_decoder(fresh_settings)->save() != state);

    // A run stopped at step 3 and resumed ends in the same state, bit for bit.
    const std::string cut = (dir / "cut").string();
    DesignRunOptions first = affine_run(cut);
    first.max_steps = 3;
    REQUIRE(run_design(runtime(), first, false).steps_done == 3);
    REQUIRE(run_design(runtime(), affine_run(cut), true).steps_done == 6);
    CHECK(load_run_network(cut)->save() == state);

    // qdo eval of the run: its own decoder by default, decoding with the state the run trained.
    EvalOptions e;
    e.run = run;
    e.synthetic_scenes = 2;
    e.out = (dir / "eval").string();
    record() = Record{};
    const EvalResult ev = evaluate_run(runtime(), e);
    REQUIRE(ev.rows.size() == 2);
    REQUIRE(record().loaded.size() == 1);
    CHECK(record().loaded.back() == state);
    CHECK(record().images_reconstructed == 2);
    for (const auto& row : ev.rows) CHECK(std::isfinite(row.psnr));
    const auto mj = nlohmann::json::parse(slurp(e.out + "/metrics.json"));
    CHECK(mj.at("decoder_kind") == "affine");
    CHECK(mj.at("conventions").at("imaging").get<std::string>().find("trained decoder (affine") != std::string::npos);
    std::filesystem::remove_all(dir);
  }

  TEST_CASE("a trained decoder is refused where it cannot work, naming why") {
    register_affine();
    // Not from a PSF: a trained decoder is a run's.
    DecoderInputs in;
    in.spec = decoder_spec_from_string("affine");
    in.psf = RealStack(3, 4, 4, 0.0);
    CHECK_THROWS_WITH_AS(make_decoder(in), doctest::Contains("trained with the optics"), InputError);
    // A design trains it with its own loss, not the Wiener objective.
    DesignRunOptions o = affine_run("(unused)");
    o.objective = Objective::Wiener;
    CHECK_THROWS_WITH_AS(o.validate(), doctest::Contains("objective"), InputError);
    // A decoder without a train factory is not trained: refused by make_trained_decoder, and a
    // design's objective network names the ones that are (this file's among them).
    NetworkSettings s;
    s.spec = decoder_spec_from_string("cg");
    CHECK_THROWS_WITH_AS(make_trained_decoder(s), doctest::Contains("cg"), InputError);
    o.decoder = decoder_spec_from_string("cg");
    o.objective = Objective::Network;
    CHECK_THROWS_WITH_AS(o.validate(), doctest::Contains("affine"), InputError);
    // An entry's trained flag and train factory must agree.
    const DecoderFactory make = [](const DecoderInputs&) -> std::unique_ptr<Decoder> { return nullptr; };
    const NetworkFactory train = [](const NetworkSettings&) -> std::unique_ptr<NetworkDecoder> { return nullptr; };
    CHECK_THROWS_WITH_AS(register_decoder({"half-a", "", true, make, nullptr}), doctest::Contains("half-a"), InputError);
    CHECK_THROWS_WITH_AS(register_decoder({"half-b", "", false, nullptr, train}), doctest::Contains("half-b"), InputError);
    CHECK_FALSE(decoder_registered("half-a"));
    CHECK_FALSE(decoder_registered("half-b"));
  }
}
