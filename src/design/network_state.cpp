// The network state files of a network run (design/network_state.hpp): RUN/network/step_*.pt,
// written beside each checkpoint, verified when read, deleted when the checkpoint that named them
// is rotated out (and only then).
#include "design/network_state.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <memory>
#include <sstream>
#include <vector>

#include "qdo/decode/decoder_registry.hpp"
#include "qdo/design/design_run.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/runtime/hash.hpp"
#include "qdo/data/io.hpp"
#include "qdo/design/run_folder.hpp"

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

NetworkStateRef network_state_of(const fs::path& ckpt) {
  std::error_code ec;
  if (!fs::is_regular_file(ckpt, ec)) return {};
  try {
    const H5Dataset c = h5_read(ckpt.string(), "/counters", 16);
    const auto f = c.str_attrs.find("network_file"), k = c.str_attrs.find("network_checksum");
    if (f == c.str_attrs.end() || k == c.str_attrs.end()) return {};
    return {f->second, k->second};
  } catch (const InputError&) {
    return {};
  }
}

// Deletes only what this run recorded as its own: the state a checkpoint named (with its
// checksum) that the rotation just dropped. Kept when any checkpoint of the folder still names it,
// when it is not a regular file (a link, a folder), when RUN/network is not a real folder (a
// link: the files behind it are someone else's to manage), or when its bytes no longer hash to
// the recorded checksum (the file was replaced since).
bool drop_network_state(const fs::path& dir, const NetworkStateRef& dropped) {
  if (dropped.file.empty()) return false;
  const fs::path p = dir / dropped.file;
  if (p.parent_path() != dir / "network" || p.filename().string().rfind("step_", 0) != 0 || p.extension() != ".pt") return false;
  for (const char* c : {"checkpoint.h5", "checkpoint.prev.h5", "checkpoint.next.h5", "checkpoint.refused.h5"})
    if (network_file_of(dir / c) == dropped.file) return false;
  std::error_code ec;
  const fs::file_status folder = fs::symlink_status(dir / "network", ec);
  if (ec || !fs::is_directory(folder)) return false;
  const fs::file_status file = fs::symlink_status(p, ec);
  if (ec || !fs::is_regular_file(file)) return false;
  try {
    if (bytes_checksum(read_file_bytes(p)) != dropped.checksum) return false;
  } catch (const InputError&) {
    return false;
  }
  return fs::remove(p, ec);
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
  ns.style = o.network_style;
  ns.in_channels = 3;
  ns.out_channels = o.cfg.bands;
  ns.seed = o.design.seed;
  ns.weight_decay_gamma = o.gamma_decoder;
  return ns;
}

double network_lr(const DesignRunOptions& o, long step) {
  return o.lr_decoder * o.design.lr_factor(step);
}

std::unique_ptr<NetworkDecoder> load_run_network(const std::string& run) {
  const ResumeState st = load_resume_state(run);
  const DesignRunOptions& o = st.options;
  if (!o.decoder.network())
    reject("run", run, "a run that trained a network decoder (this one's decoder is " + o.decoder.to_string() + ")");
  std::unique_ptr<NetworkDecoder> net = make_trained_decoder(network_settings(o));
  const fs::path p = fs::path(run) / st.state.network_file;
  net->load(read_network_state(run, st.state, st.checkpoint), p.string());
  return net;
}

}  // namespace qdo
