// The core half of network_decoder.hpp: the factory slot qdo_net (src/net) fills with
// register_network_factory(), the loader the qdo tool registers so that LibTorch is loaded only
// when a network is asked for, and the network behind the Decoder interface.
#include "qdo/decode/network_decoder.hpp"

#include <algorithm>
#include <cstdlib>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "qdo/runtime/error.hpp"

namespace qdo {

namespace {
std::mutex& factory_mutex() {
  static std::mutex m;
  return m;
}
NetworkFactory& factory_slot() {
  static NetworkFactory f;
  return f;
}
}  // namespace

void register_network_factory(NetworkFactory factory) {
  const std::lock_guard<std::mutex> lock(factory_mutex());
  factory_slot() = std::move(factory);
}

namespace {
[[noreturn]] void no_data_parallel(const NetworkDecoder& n) {
  reject("decoder", n.spec(), "a network with data-parallel training (resunet): this one trains only in one process");
}
}  // namespace

void NetworkDecoder::set_rank_sum(RankSum) { no_data_parallel(*this); }
NetworkStep NetworkDecoder::backward(const std::vector<RealStack>&, const std::vector<RealStack>&, double, bool) {
  no_data_parallel(*this);
}
void NetworkDecoder::read_gradients(double*) const { no_data_parallel(*this); }
void NetworkDecoder::apply_gradients(const double*, double) { no_data_parallel(*this); }

NetworkFactory registered_network_factory() {
  const std::lock_guard<std::mutex> lock(factory_mutex());
  return factory_slot();
}

namespace {
struct LoaderState {
  NetworkLoader loader;
  bool tried = false;
  std::string error;
};
LoaderState& loader_state() {
  static LoaderState s;
  return s;
}
std::mutex& loader_mutex() {  // held while the loader runs (it takes factory_mutex to register)
  static std::mutex m;
  return m;
}
// The registered factory, after running the loader once if there is none yet.
NetworkFactory factory_after_loading() {
  {
    const std::lock_guard<std::mutex> lock(factory_mutex());
    if (factory_slot()) return factory_slot();
  }
  {
    const std::lock_guard<std::mutex> lock(loader_mutex());
    LoaderState& st = loader_state();
    if (st.loader && !st.tried) {
      st.tried = true;
      try {
        st.error = st.loader();
      } catch (const InputError&) {
        // The plugin loaded and refused the user's settings (e.g. QDO_TORCH_THREADS=0): that is
        // the message, not "the plugin did not load". Asked again, it is checked again.
        st.tried = false;
        throw;
      } catch (const std::exception& e) {
        st.error = e.what();
      }
    }
  }
  const std::lock_guard<std::mutex> lock(factory_mutex());
  return factory_slot();
}
}  // namespace

void register_network_loader(NetworkLoader loader) {
  const std::lock_guard<std::mutex> lock(loader_mutex());
  loader_state() = LoaderState{std::move(loader), false, ""};
}

bool network_decoder_available() { return bool(factory_after_loading()); }

int network_threads() {
  if (const char* t = std::getenv("QDO_TORCH_THREADS")) {
    char* end = nullptr;
    const long v = std::strtol(t, &end, 10);
    if (end == t || *end || v < 1 || v > 1024) reject("QDO_TORCH_THREADS", t, "an integer from 1 to 1024");
    return int(v);
  }
  return int(std::max(1u, std::thread::hardware_concurrency()));
}

std::string network_decoder_unavailable_reason() {
  if (factory_after_loading()) return "";
  const std::lock_guard<std::mutex> lock(loader_mutex());
  if (!loader_state().error.empty()) return "the LibTorch plugin did not load: " + loader_state().error;
  return "this qdo was built without LibTorch (-DQDO_TORCH=OFF, or the Python extension); the network decoder needs the qdo "
         "tool built with LibTorch (scripts/install-deps.sh installs libtorch-dev)";
}

std::unique_ptr<NetworkDecoder> make_network_decoder(const NetworkSettings& s) {
  const NetworkFactory f = factory_after_loading();
  if (!f) reject("decoder", s.spec.to_string(), "wiener: " + network_decoder_unavailable_reason());
  return f(s);
}

NetworkImageDecoder::NetworkImageDecoder(std::unique_ptr<NetworkDecoder> net, std::size_t bands, std::size_t batch,
                                         std::string description)
    : owned_(std::move(net)), net_(owned_.get()), bands_(bands), batch_(batch), description_(std::move(description)) {
  if (!net_) throw Error("internal: NetworkImageDecoder without a network");
  if (batch_ < 1) reject("batch", batch_, ">= 1");
}

NetworkImageDecoder::NetworkImageDecoder(NetworkDecoder& net, std::size_t bands, std::size_t batch, std::string description)
    : net_(&net), bands_(bands), batch_(batch), description_(std::move(description)) {
  if (batch_ < 1) reject("batch", batch_, ">= 1");
}

RealStack NetworkImageDecoder::decode(const RealStack& y) const { return std::move(net_->reconstruct({y}).at(0)); }

std::vector<RealStack> NetworkImageDecoder::decode_batch(const std::vector<RealStack>& ys) const { return net_->reconstruct(ys); }

}  // namespace qdo
