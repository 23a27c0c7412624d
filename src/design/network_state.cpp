// The network state files of a network run (design/network_state.hpp): RUN/network/step_*.pt,
// written beside each checkpoint, verified when read, pruned when no checkpoint names them.
#include "design/network_state.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <memory>
#include <sstream>
#include <vector>

#include "qdo/design_run.hpp"
#include "qdo/error.hpp"
#include "qdo/hash.hpp"
#include "qdo/io.hpp"
#include "qdo/run_folder.hpp"

namespace fs = std::filesystem;

namespace qdo {

namespace {

std::string read_file_bytes(const fs::path& p) {
  std::ifstream f(p, std::ios::binary);
  if (!f) throw InputError("file '" + p.string() + "': cannot be read");
  std::ostringstream ss;
  ss << f.rdbuf();
  return ss.str();
}

std::string bytes_checksum(const std::string& bytes) {
  Fnv1a64 f;
  f.add(bytes.data(), bytes.size());
  return f.hex();
}

// The network file a checkpoint names (its /counters attribute), or "" (none, or unreadable).
std::string network_file_of(const fs::path& ckpt) {
  std::error_code ec;
  if (!fs::is_regular_file(ckpt, ec)) return "";
  try {
    const H5Dataset c = h5_read(ckpt.string(), "/counters", 16);
    const auto it = c.str_attrs.find("network_file");
    return it == c.str_attrs.end() ? "" : it->second;
  } catch (const InputError&) {
    return "";
  }
}

}  // namespace

// The network's state at s.step as RUN/network/step_<8 digits>.pt (written, then renamed), named
// with its checksum in s (save_checkpoint then records both).
void save_network_state(const fs::path& dir, const NetworkDecoder& net, DesignState& s) {
  char name[64];
  std::snprintf(name, sizeof name, "network/step_%08ld.pt", s.step);
  make_output_dir((dir / "network").string(), "out");
  const std::string bytes = net.save();
  write_text_atomic((dir / name).string(), bytes);
  s.network_file = name;
  s.network_checksum = bytes_checksum(bytes);
}

// Removes the network states this run wrote (RUN/network/step_*.pt) that no checkpoint of the
// folder names any more (checkpoint.h5, checkpoint.prev.h5, checkpoint.next.h5,
// checkpoint.refused.h5).
void prune_network_states(const fs::path& dir) {
  const fs::path nd = dir / "network";
  std::error_code ec;
  if (!fs::is_directory(nd, ec)) return;
  std::vector<std::string> keep;
  for (const char* c : {"checkpoint.h5", "checkpoint.prev.h5", "checkpoint.next.h5", "checkpoint.refused.h5"})
    keep.push_back(network_file_of(dir / c));
  for (const auto& e : fs::directory_iterator(nd, ec)) {
    const std::string fname = e.path().filename().string();
    if (fname.rfind("step_", 0) != 0 || e.path().extension() != ".pt" || fname.size() != 16) continue;  // not ours
    if (std::find(keep.begin(), keep.end(), "network/" + fname) != keep.end()) continue;
    fs::remove(e.path(), ec);
  }
}

// The network state a checkpoint's state names, its checksum verified.
std::string read_network_state(const fs::path& dir, const DesignState& s, const std::string& ckpt) {
  if (s.network_file.empty())
    throw InputError("file '" + ckpt + "': names no network state, but the run trains a network decoder (a checkpoint of a Wiener run?)");
  const fs::path p = dir / s.network_file;
  if (!fs::is_regular_file(p))
    throw InputError("file '" + p.string() + "': missing (named by " + ckpt + "); the run's network state is gone");
  const std::string bytes = read_file_bytes(p);
  const std::string sum = bytes_checksum(bytes);
  if (sum != s.network_checksum)
    throw InputError("file '" + p.string() + "': checksum mismatch (" + ckpt + " recorded " + s.network_checksum + ", the file hashes to " +
                     sum + "): the network state is corrupt");
  return bytes;
}

NetworkSettings network_settings(const DesignRunOptions& o) {
  NetworkSettings ns;
  ns.spec = o.decoder;
  ns.in_channels = 3;
  ns.out_channels = o.cfg.bands;
  ns.seed = o.design.seed;
  ns.weight_decay_gamma = o.gamma_decoder;
  return ns;
}

double network_lr(const DesignRunOptions& o, long step) {
  return o.lr_decoder * std::pow(o.design.lr_decay_per_epoch, std::floor(double(step) / double(o.design.steps_per_epoch)));
}

std::unique_ptr<NetworkDecoder> load_run_network(const std::string& run) {
  const ResumeState st = load_resume_state(run);
  const DesignRunOptions& o = st.options;
  if (!o.decoder.network())
    reject("run", run, "a run that trained a network decoder (this one's decoder is " + o.decoder.to_string() + ")");
  std::unique_ptr<NetworkDecoder> net = make_network_decoder(network_settings(o));
  const fs::path p = fs::path(run) / st.state.network_file;
  net->load(read_network_state(run, st.state, st.checkpoint), p.string());
  return net;
}

}  // namespace qdo
