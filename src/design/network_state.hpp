// The network state files of a network run (private to src/design): RUN/network/step_<8 digits>.pt,
// one per checkpoint, named in the checkpoint with its FNV-1a 64 checksum (DesignState), and the
// network's settings and learning rate from the run's options.
#pragma once
#include <filesystem>
#include <string>

#include "qdo/design/design.hpp"
#include "qdo/design/design_run_options.hpp"
#include "qdo/decode/network_decoder.hpp"

namespace qdo {

// Writes net's state at s.step as RUN/network/step_<8 digits>.pt (atomic) and records its name and
// checksum in s (save_checkpoint then stores both).
void save_network_state(const std::filesystem::path& dir, const NetworkDecoder& net, DesignState& s);
// A network state as a checkpoint records it: its file (relative to the run folder) and checksum.
struct NetworkStateRef {
  std::string file, checksum;
};
// The state the checkpoint at `ckpt` names; empty when none or when the file does not read.
NetworkStateRef network_state_of(const std::filesystem::path& ckpt);
// After a checkpoint rotation: deletes `dropped` (the state the replaced checkpoint.prev.h5 named)
// when no checkpoint of the folder names it any more, it is a regular file (not a link) in a real
// RUN/network folder (not a link) and its bytes still hash to the recorded checksum. Never deletes
// anything else (a user's step_*.pt, a file the run did not record). Returns whether it deleted.
bool drop_network_state(const std::filesystem::path& dir, const NetworkStateRef& dropped);
// The bytes of the network state s names, its checksum verified; InputError naming the file (or
// the checkpoint `ckpt`, when it names none).
std::string read_network_state(const std::filesystem::path& dir, const DesignState& s, const std::string& ckpt);
// The network of the run's options: its spec, 3 input channels, cfg.bands outputs, seed, gamma.
NetworkSettings network_settings(const DesignRunOptions& o);
// The network's learning rate at `step`: lr_decoder times the optics' decay factor (DesignOptions::lr_factor).
double network_lr(const DesignRunOptions& o, long step);

}  // namespace qdo
