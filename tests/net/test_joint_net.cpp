// The LibTorch network behind the core's NetworkDecoder (src/net/network_decoder.cpp): its state
// round trip is exact (weights, batch-norm statistics, Adam moments: the continuation after a
// load equals the uninterrupted one, bytes included), other architectures and foreign bytes are
// refused naming both, and a whole network design run resumes bit-identically with the Res-UNet.
#include <cstring>
#include <fstream>
#include <sstream>

#include "torch_common.hpp"  // LibTorch, then doctest's CHECK macros and the common helpers
#include "qdo/design/design_run.hpp"
#include "qdo/evaluate/eval.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"
#include "qdo/net/net.hpp"
#include "qdo/decode/network_decoder.hpp"
#include "qdo/design/run.hpp"

using namespace qdo;
using namespace qdo::test;

namespace {

NetworkSettings settings(const std::string& spec, std::size_t bands = 3) {
  NetworkSettings s;
  s.spec = decoder_spec_from_string(spec);
  s.out_channels = bands;
  s.seed = 4;
  return s;
}

std::vector<RealStack> cubes(std::size_t planes, std::size_t n, unsigned seed, std::size_t count = 2) {
  std::vector<RealStack> v;
  for (std::size_t k = 0; k < count; ++k) v.push_back(random_cube(planes, n, n, seed + unsigned(k)));
  return v;
}

// Registers the LibTorch network for the guard's lifetime, then puts back what was there.
struct TorchFactory {
  NetworkFactory previous = registered_network_factory();
  TorchFactory() { register_torch_network(); }
  ~TorchFactory() { register_network_factory(previous); }
};

}  // namespace

TEST_SUITE("net") {
  TEST_CASE("the network state round trip is exact: a loaded network continues as the original, bytes included") {
    const TorchFactory torch_net;
    const auto y = cubes(3, 16, 1), x = cubes(3, 16, 5);
    auto a = make_network_decoder(settings("resunet:depth=2,root=4"));
    a->train(y, x, 1e-2);
    a->train(y, x, 1e-2);
    const std::string saved = a->save();
    auto b = make_network_decoder(settings("resunet:depth=2,root=4"));
    b->load(saved, "mem");
    CHECK(b->save() == saved);
    const NetworkStep sa = a->train(y, x, 1e-2), sb = b->train(y, x, 1e-2);
    CHECK(sa.loss == sb.loss);
    CHECK(sa.grad_images.front().data == sb.grad_images.front().data);
    CHECK(a->save() == b->save());
    CHECK(a->reconstruct(y).front().data == b->reconstruct(y).front().data);
    // Training moves the network (the step is not a no-op) and the loss includes γ||ω||².
    CHECK(a->save() != saved);
    CHECK(sa.loss > sa.mae);
  }

  TEST_CASE("QDO_TORCH_DEVICE chooses the network's device; cuda without CUDA is refused by name") {
    const TorchFactory torch_net;
    ::setenv("QDO_TORCH_DEVICE", "cpu", 1);
    CHECK(make_network_decoder(settings("resunet:depth=2,root=4"))->parameter_count() > 0);
    ::setenv("QDO_TORCH_DEVICE", "tpu", 1);
    CHECK_THROWS_WITH_AS(make_network_decoder(settings("resunet:depth=2,root=4")), doctest::Contains("QDO_TORCH_DEVICE"), InputError);
    if (!torch::cuda::is_available()) {
      ::setenv("QDO_TORCH_DEVICE", "cuda", 1);
      CHECK_THROWS_WITH_AS(make_network_decoder(settings("resunet:depth=2,root=4")), doctest::Contains("Torch_DIR"), InputError);
    }
    ::unsetenv("QDO_TORCH_DEVICE");
  }

  TEST_CASE("a network state of another architecture, band count or format is refused, naming both") {
    const TorchFactory torch_net;
    auto small = make_network_decoder(settings("resunet:depth=2,root=4"));
    auto other = make_network_decoder(settings("resunet:depth=3,root=4"));
    std::string msg;
    try {
      other->load(small->save(), "ckpt.pt");
    } catch (const InputError& e) {
      msg = e.what();
    }
    CHECK(msg.find("ckpt.pt") != std::string::npos);
    CHECK(msg.find("resunet:depth=2,root=4") != std::string::npos);
    CHECK(msg.find("resunet:depth=3,root=4") != std::string::npos);
    auto bands = make_network_decoder(settings("resunet:depth=2,root=4", 5));
    CHECK_THROWS_WITH_AS(bands->load(small->save(), "b.pt"), doctest::Contains("output bands"), InputError);
    CHECK_THROWS_WITH_AS(small->load("not a torch archive", "junk.pt"), doctest::Contains("junk.pt"), InputError);
  }

  TEST_CASE("a Res-UNet design run resumes bit-identically after a stop; eval reconstructs with its network") {
    const TorchFactory torch_net;
    const auto dir = temp_dir("net_resume");
    auto run = [&](const std::string& out) {
      DesignRunOptions o;
      o.cfg = tiny_config(32, 3);  // S = 16
      o.design.mode = DesignMode::QDOA;
      o.design.quantizer.levels = 4;
      o.design.steps_per_epoch = 2;
      o.design.t0_epochs = 0;
      o.design.t1_epochs = 2;
      o.design.seed = 2;
      o.epochs = 2;
      o.synthetic_scenes = 3;
      o.checkpoint_every = 1;
      o.batch = 2;
      o.decoder = decoder_spec_from_string("resunet:depth=2,root=4");
      o.objective = Objective::Network;
      o.precision = Precision::F32;
      o.out = out;
      o.quiet = true;
      return o;
    };
    const std::string a = (dir / "a").string(), b = (dir / "b").string();
    run_design(runtime(), run(a), false);
    DesignRunOptions first = run(b);
    first.max_steps = 1;
    run_design(runtime(), first, false);
    run_design(runtime(), run(b), true);
    const DesignState sa = load_checkpoint(a + "/checkpoint.h5", 16, 4), sb = load_checkpoint(b + "/checkpoint.h5", 16, 4);
    CHECK(sa.w == sb.w);
    CHECK(sa.offsets == sb.offsets);
    REQUIRE(!sa.network_file.empty());
    CHECK(slurp(a + "/" + sa.network_file) == slurp(b + "/" + sb.network_file));
    EvalOptions e;
    e.run = a;
    e.synthetic_scenes = 2;
    e.renders = 1;
    e.out = (dir / "eval").string();
    const EvalResult r = evaluate_run(runtime(), e);
    CHECK(std::isfinite(r.mean.psnr));
    CHECK(r.mean.psnr > 0);
    std::filesystem::remove_all(dir);
  }

  TEST_CASE("the qdo tool trains, resumes, fine-tunes and evaluates a network run from the command line") {
    const auto dir = temp_dir("net_cli");
    const std::string cfg = (dir / "tiny.json").string();
    write_text_atomic(cfg, config_to_json_text(tiny_config(32, 3)));
    const std::string d = (dir / "do").string(), common = " --config " + cfg + " --epochs 2 --steps-per-epoch 2 --synthetic-scenes 2 --batch 2";
    const Run r1 = qdo_run("design --mode do --decoder resunet:depth=2,root=4" + common + " --max-steps 1 --out " + d);
    CAPTURE(r1.out);
    REQUIRE(r1.code == 0);
    const Run r2 = qdo_run("design --resume --out " + d);
    CAPTURE(r2.out);
    REQUIRE(r2.code == 0);
    CHECK(r2.out.find("design: 4 steps") != std::string::npos);
    // A given option that differs from the stored one is refused on resume, the decoder included.
    const Run r3 = qdo_run("design --resume --decoder resunet:depth=3,root=4 --out " + d);
    CHECK(r3.code == 2);
    CHECK(r3.out.find("--decoder") != std::string::npos);
    const Run ft = qdo_run("design --mode do-finetune --from " + d + " --levels 2 --finetune-steps 2 --out " + (dir / "ft").string());
    CAPTURE(ft.out);
    CHECK(ft.code == 0);
    const Run bad = qdo_run("design --mode do-finetune --from " + d + " --lr 0.5 --out " + (dir / "ft2").string());
    CHECK(bad.code == 2);
    CHECK(bad.out.find("--lr") != std::string::npos);
    const Run ev = qdo_run("eval " + d + " --decoder mismatch --synthetic-scenes 2 --renders 1 --out " + (dir / "ev").string());
    CAPTURE(ev.out);
    CHECK(ev.code == 0);
    CHECK(ev.out.find("mean") != std::string::npos);
    const Run ev2 = qdo_run("eval " + d + " --synthetic-scenes 2 --out " + (dir / "ev2").string());
    CHECK(ev2.code == 2);
    CHECK(ev2.out.find("mismatch") != std::string::npos);
    std::filesystem::remove_all(dir);
  }

  // The tool links no LibTorch: its plugin (libqdo-net.so, src/cli/net_plugin.cpp) is loaded when a
  // network is first asked for, so other commands start without LibTorch's ~0.5 s of
  // initialisers. LD_DEBUG=files makes the dynamic loader name every object it opens.
  TEST_CASE("the qdo tool loads LibTorch only when a network is asked for; a missing plugin is an error naming it") {
    const Run version = qdo_run("--version", "LD_DEBUG=files");
    CAPTURE(version.out);
    REQUIRE(version.code == 0);
    CHECK(version.out.find("file=") != std::string::npos);  // the loader did report its files
    CHECK(version.out.find("libtorch") == std::string::npos);
    CHECK(version.out.find("libqdo-net") == std::string::npos);

    const auto dir = temp_dir("net_plugin");
    const std::string cfg = (dir / "tiny.json").string();
    write_text_atomic(cfg, config_to_json_text(tiny_config(32, 3)));
    const std::string args = "design --mode do --decoder resunet:depth=2,root=4 --config " + cfg +
                             " --epochs 1 --steps-per-epoch 1 --synthetic-scenes 2 --batch 2 --max-steps 1 --out ";
    const Run net = qdo_run(args + (dir / "run").string(), "LD_DEBUG=files");
    CAPTURE(net.out);
    CHECK(net.code == 0);
    CHECK(net.out.find("libqdo-net") != std::string::npos);
    CHECK(net.out.find("libtorch") != std::string::npos);

    const Run missing = qdo_run(args + (dir / "run2").string(), "QDO_NET_PLUGIN=/nonexistent/libqdo-net.so");
    CAPTURE(missing.out);
    CHECK(missing.code == 2);
    CHECK(missing.out.find("LibTorch plugin did not load") != std::string::npos);
    CHECK(missing.out.find("/nonexistent/libqdo-net.so") != std::string::npos);
    CHECK_FALSE(std::filesystem::exists(dir / "run2" / "config.json"));  // refused before any work
    std::filesystem::remove_all(dir);
  }
}
