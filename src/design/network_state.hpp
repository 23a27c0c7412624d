// The network state files of a network run (private to src/design): RUN/network/step_<8 digits>.pt,
// one per checkpoint, named in the checkpoint with its FNV-1a 64 checksum (DesignState), and the
// network's settings and learning rate from the run's options.
#pragma once
#include <filesystem>
#include <string>

#include "qdo/design.hpp"
#include "qdo/design_run_options.hpp"
#include "qdo/network_decoder.hpp"

namespace qdo {

// Writes net's state at s.step as RUN/network/step_<8 digits>.pt (atomic) and records its name and
// checksum in s (save_checkpoint then stores both).
void save_network_state(const std::filesystem::path& dir, const NetworkDecoder& net, DesignState& s);
// Removes the network states this run wrote that no checkpoint of the folder names any more
// (checkpoint.h5, checkpoint.prev.h5, checkpoint.refused.h5).
void prune_network_states(const std::filesystem::path& dir);
// The bytes of the network state s names, its checksum verified; InputError naming the file (or
// the checkpoint `ckpt`, when it names none).
std::string read_network_state(const std::filesystem::path& dir, const DesignState& s, const std::string& ckpt);
// The network of the run's options: its spec, 3 input channels, cfg.bands outputs, seed, gamma.
NetworkSettings network_settings(const DesignRunOptions& o);
// The network's learning rate at `step`: lr_decoder decayed per epoch by lr_decay_per_epoch.
double network_lr(const DesignRunOptions& o, long step);

}  // namespace qdo
