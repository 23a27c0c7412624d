#include "qdo/design/run.hpp"

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <map>
#include <utility>

#include <fcntl.h>
#include <signal.h>
#include <sys/file.h>
#include <unistd.h>

#include "qdo/runtime/error.hpp"
#include "qdo/runtime/hash.hpp"
#include "qdo/data/io.hpp"

namespace qdo {

namespace {

// The datasets a checkpoint holds, in the order the checksum covers them.
const char* const kCheckpointSets[] = {"/w", "/offsets", "/adam_w_m", "/adam_w_v", "/adam_a_m", "/adam_a_v", "/counters"};

// FNV-1a (64 bit) over each dataset's name, value count and float64 bit patterns (little-endian),
// as "fnv1a64:<16 hex digits>". HDF5 stores float64 exactly, so an intact file reproduces it.
// Network runs: the network file's name and checksum (attributes of /counters) are covered too.
std::string checkpoint_checksum(const std::vector<std::pair<std::string, const std::vector<double>*>>& sets,
                                const std::string& network_file = "", const std::string& network_checksum = "") {
  Fnv1a64 f;
  if (!network_file.empty()) {
    f.add(network_file);
    f.add(network_checksum);
  }
  for (const auto& [name, data] : sets) {
    f.add(name);  // name and a '\0'
    f.add_u64(data->size());
    for (double v : *data) {
      std::uint64_t bits = 0;
      std::memcpy(&bits, &v, sizeof bits);
      f.add_u64(bits);
    }
  }
  return f.hex();
}

}  // namespace
RunLock::RunLock(const std::string& dir, const std::string& what) : path_((std::filesystem::path(dir) / ".lock").string()) {
  fd_ = ::open(path_.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
  if (fd_ < 0)
    reject(what, dir, "a run folder this process can write (cannot open '" + path_ + "': " + std::strerror(errno) + ")");
  if (::flock(fd_, LOCK_EX | LOCK_NB) != 0) {
    const int err = errno;
    // The holder writes its pid right after taking the lock, so a second writer that looks in
    // that instant finds the file empty (a fresh folder) or holding an earlier holder's pid (a
    // dead one: the lock is free when its holder is gone). Both were seen by the stress suite
    // ("locked by pid unknown" with two sweeps started at once). Look again, for up to 0.2 s,
    // until the first line names a live process.
    std::string holder;
    for (int tries = 0; tries < 100; ++tries) {
      char buf[64] = {};
      const ssize_t n = ::pread(fd_, buf, sizeof buf - 1, 0);
      holder = n > 0 ? std::string(buf, std::size_t(n)) : std::string();
      holder = holder.substr(0, holder.find('\n'));
      while (!holder.empty() && holder.back() == ' ') holder.pop_back();
      char* end = nullptr;
      const long pid = holder.empty() ? 0 : std::strtol(holder.c_str(), &end, 10);
      const bool live = pid > 0 && end && *end == '\0' && (::kill(pid_t(pid), 0) == 0 || errno == EPERM);
      if (live || err != EWOULDBLOCK) break;
      ::usleep(2000);
    }
    ::close(fd_);
    fd_ = -1;
    if (err == EWOULDBLOCK)
      throw RunBusyError("argument '" + what + "' = " + dir + ": a run folder no other process is writing (it is locked by pid " +
                         (holder.empty() ? std::string("unknown") : holder) + " through '" + path_ +
                         "'; wait for it to finish, or stop it, or choose another folder)");
    reject(what, dir, "a run folder that can be locked (flock on '" + path_ + "': " + std::strerror(err) + ")");
  }
  // The pid over what an earlier holder left, then cut to its length: the file never reads
  // empty in between (a reader takes the first line).
  const std::string pid = std::to_string(::getpid()) + "\n";
  if (::pwrite(fd_, pid.data(), pid.size(), 0) != ssize_t(pid.size()) || ::ftruncate(fd_, off_t(pid.size())) != 0) {
    const int err = errno;
    ::close(fd_);
    fd_ = -1;
    reject(what, dir, "a run folder this process can write (writing '" + path_ + "': " + std::strerror(err) + ")");
  }
}

RunLock::~RunLock() {
  if (fd_ >= 0) ::close(fd_);  // releases the flock
}

void save_checkpoint(const std::string& path, const DesignState& s) {
  auto vec = [](const std::string& name, const std::vector<double>& v) {
    return H5Dataset{name, {v.size()}, v.empty() ? std::vector<double>{} : v, {}, {}};
  };
  std::vector<H5Dataset> ds = {vec("/w", s.w), vec("/offsets", s.offsets), vec("/adam_w_m", s.adam_w.m),
                               vec("/adam_w_v", s.adam_w.v), vec("/adam_a_m", s.adam_a.m), vec("/adam_a_v", s.adam_a.v)};
  ds.push_back({"/counters", {3}, {double(s.step), double(s.adam_w.t), double(s.adam_a.t)}, {}, {{"names", "step, adam_w.t, adam_a.t"}}});
  std::vector<std::pair<std::string, const std::vector<double>*>> sets;
  for (const H5Dataset& d : ds) sets.emplace_back(d.name, &d.data);
  if (!s.network_file.empty()) {
    ds.back().str_attrs["network_file"] = s.network_file;
    ds.back().str_attrs["network_checksum"] = s.network_checksum;
  }
  ds.back().str_attrs["checksum"] = checkpoint_checksum(sets, s.network_file, s.network_checksum);
  // The rotation never leaves `path` missing or partial, whenever a kill -9 lands: the new
  // checkpoint is first written complete beside it (checkpoint.next.h5, itself written to a
  // temporary name and renamed); the current one then becomes checkpoint.prev.h5 through a hard
  // link (a copy where the file system refuses links) renamed over the old previous one; only
  // then does one rename put the new one in place. A kill leaves at worst checkpoint.next.h5 (a
  // complete checkpoint that nothing reads; the next save replaces it) and a ".tmp-" file.
  namespace fs = std::filesystem;
  const std::string next = checkpoint_next_path(path);
  h5_write(next, ds, {{"format", "qdo checkpoint 2"}});
  std::error_code ec;
  if (fs::is_regular_file(path, ec)) {
    wait_if_abandoned();
    const std::string prev = checkpoint_prev_path(path), prev_tmp = prev + ".tmp-" + std::to_string(long(::getpid()));
    fs::remove(prev_tmp, ec);
    fs::create_hard_link(path, prev_tmp, ec);
    if (ec) {
      ec.clear();
      fs::copy_file(path, prev_tmp, fs::copy_options::overwrite_existing, ec);
    }
    if (!ec) fs::rename(prev_tmp, prev, ec);
    if (ec) {
      std::error_code ignored;
      fs::remove(prev_tmp, ignored);
      throw InputError("file '" + path + "': cannot keep it as the previous checkpoint " + prev + ": " + ec.message());
    }
  }
  wait_if_abandoned();
  fs::rename(next, path, ec);
  if (ec) throw InputError("file '" + next + "': cannot move it onto " + path + ": " + ec.message());
}

std::string checkpoint_next_path(const std::string& path) {
  const std::filesystem::path p(path);
  return (p.parent_path() / (p.stem().string() + ".next" + p.extension().string())).string();
}

std::string checkpoint_prev_path(const std::string& path) {
  const std::filesystem::path p(path);
  return (p.parent_path() / (p.stem().string() + ".prev" + p.extension().string())).string();
}

DesignState load_checkpoint(const std::string& path, std::size_t expected_w, std::size_t expected_levels, bool mask_depths,
                            bool pin_top) {
  // Every dataset is read first, then the checksum (on /counters, written since format 2) is
  // checked before any value is trusted: a flipped byte in a dataset would otherwise resume a
  // different optimisation silently. Checkpoints without the attribute (older qdo) are read as before.
  // One open file for every dataset: opened by name once per dataset, a read racing the run's
  // next save mixed two checkpoints and failed its checksum (the stress suite under load).
  std::map<std::string, H5Dataset> sets;
  {
    const std::vector<std::string> names(std::begin(kCheckpointSets), std::end(kCheckpointSets));
    std::vector<H5Dataset> read = h5_read_many(path, names, 1u << 28);
    for (std::size_t i = 0; i < names.size(); ++i) sets[names[i]] = std::move(read[i]);
  }
  const auto& cattrs = sets["/counters"].str_attrs;
  const auto stored = cattrs.find("checksum");
  const auto nf = cattrs.find("network_file"), nc = cattrs.find("network_checksum");
  const std::string network_file = nf != cattrs.end() ? nf->second : "", network_checksum = nc != cattrs.end() ? nc->second : "";
  if (network_file.empty() != network_checksum.empty())
    throw InputError("file '" + path + "': names a network file without its checksum, or a checksum without the file");
  if (!network_file.empty() &&
      (network_file.find("..") != std::string::npos || network_file.front() == '/' || network_file.rfind("network/", 0) != 0))
    throw InputError("file '" + path + "': network_file '" + network_file + "' is not a file under the run's network/ folder");
  if (stored != cattrs.end()) {
    std::vector<std::pair<std::string, const std::vector<double>*>> covered;
    for (const char* name : kCheckpointSets) covered.emplace_back(name, &sets[name].data);
    const std::string actual = checkpoint_checksum(covered, network_file, network_checksum);
    if (stored->second != actual)
      throw InputError("file '" + path + "': checksum mismatch (stored " + stored->second + ", the datasets hash to " + actual +
                       "): the checkpoint is corrupt; resume from a copy or start the run anew");
  }
  auto read = [&](const std::string& name, std::size_t expected, bool allow_empty) {
    const H5Dataset& d = sets.at(name);
    const std::size_t n = d.data.size();
    if (!(n == expected || (allow_empty && n == 0)))
      throw InputError("file '" + path + "': dataset '" + name + "' has " + to_str(n) + " values, expected " + to_str(expected) +
                       " (is this checkpoint from another configuration?)");
    for (double v : d.data)
      if (!std::isfinite(v)) throw InputError("file '" + path + "': dataset '" + name + "' holds non-finite values");
    return d.data;
  };
  DesignState s;
  s.w = read("/w", expected_w, false);
  s.offsets = read("/offsets", expected_levels, false);
  s.adam_w.m = read("/adam_w_m", expected_w, true);
  s.adam_w.v = read("/adam_w_v", expected_w, true);
  s.adam_a.m = read("/adam_a_m", expected_levels, true);
  s.adam_a.v = read("/adam_a_v", expected_levels, true);
  const auto c = read("/counters", 3, false);
  // Counts up to 2^53 (exact in a double; converting larger values to long is undefined).
  for (double v : c)
    if (v < 0 || v != std::floor(v) || v > 9007199254740992.0)
      throw InputError("file '" + path + "': dataset '/counters' holds " + to_str(v) + ", not a count (0 .. 2^53)");
  // Adam's second moments are averages of squares; a negative one would turn the weights into
  // NaN on the first step after resuming.
  for (const char* name : {"/adam_w_v", "/adam_a_v"})
    for (double v : name == std::string("/adam_w_v") ? s.adam_w.v : s.adam_a.v)
      if (v < 0) throw InputError("file '" + path + "': dataset '" + name + "' holds " + to_str(v) + " < 0 (second moments are >= 0)");
  // Adaptive offsets: a_0 = 0, |a_l| within the clip limit (0.2 when L = 2, else 1), as the
  // optimiser keeps them (Quantizer::validate).
  const double lim = expected_levels == 2 ? 0.2 : 1.0;
  if (mask_depths) {  // qdo+m: depths in [0, 1] whose sum (the deepest etch) stays within h_max
    double sum = 0;
    for (std::size_t j = 0; j < s.offsets.size(); ++j) {
      if (!(s.offsets[j] >= 0 && s.offsets[j] <= 1))
        throw InputError("file '" + path + "': dataset '/offsets' holds mask depth " + to_str(s.offsets[j]) + " (mask " + to_str(j) +
                         ") outside [0, 1]");
      sum += s.offsets[j];
    }
    if (sum > 1 + 1e-12)
      throw InputError("file '" + path + "': dataset '/offsets' holds mask depths summing to " + to_str(sum) + " > 1 (h_max)");
  }
  const std::size_t pinned = pin_top && !s.offsets.empty() ? s.offsets.size() - 1 : 0;
  for (std::size_t l = 0; l < s.offsets.size() && !mask_depths; ++l)
    if ((l == pinned && s.offsets[l] != 0) || std::fabs(s.offsets[l]) > lim)
      throw InputError("file '" + path + "': dataset '/offsets' holds " + to_str(s.offsets[l]) + " at level " + to_str(l) +
                       (l == pinned ? " (level " + to_str(l) + " is the pinned one, fixed at 0)"
                                    : " outside [-" + to_str(lim) + ", " + to_str(lim) + "]"));
  s.network_file = network_file;
  s.network_checksum = network_checksum;
  s.step = long(c[0]);
  s.adam_w.t = long(c[1]);
  s.adam_a.t = long(c[2]);
  for (double w : s.w)
    if (w < -1 || w > 1) throw InputError("file '" + path + "': dataset '/w' holds " + to_str(w) + " outside [-1, 1]");
  return s;
}

}  // namespace qdo
