// Output staging: the command's files are written to temporary names and renamed into place
// together (OutputStage, commit_output), its new folders removed on failure
// (make_output_dir), the rule of every command's output folder (claim_output_dir), and
// write_text_atomic; abandon_outputs_on_termination_signals (the signals that abandon the stage).
#include <pthread.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <csignal>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "data/io_internal.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"

namespace qdo {
using namespace io_detail;
namespace {
namespace fs = std::filesystem;
}  // namespace

// =========================================================================================
// Output staging
// =========================================================================================

namespace {
// Set by abandon_output_stage: from then on no thread starts or finishes an output write
// (wait_if_abandoned), so that nothing is created after the discard and before the signal ends
// the process.
std::atomic<bool> g_abandoned{false};
OutputStage* g_stage = nullptr;  // the active stage (CLI: one per command)
// Guards the active stage's lists: a command may write outputs from two threads (figures beside
// HDF5 files), and every writer ends in commit_output.
std::mutex g_stage_mutex;
}  // namespace

OutputStage::OutputStage(bool defer_files) : defer_files_(defer_files) {
  if (g_stage) throw Error("OutputStage: a stage is already active (one per command)");
  g_stage = this;
}

OutputStage::~OutputStage() {
  const std::lock_guard<std::mutex> lock(g_stage_mutex);
  g_stage = nullptr;
  if (committed_) return;
  discard();
}

void wait_if_abandoned() {
  while (g_abandoned.load()) std::this_thread::sleep_for(std::chrono::seconds(1));  // until the signal ends the process
}

// SIGINT (Ctrl-C), SIGTERM (kill, Slurm's time limit) and SIGHUP are blocked in every thread and
// taken by one thread of their own, which discards the command's unfinished outputs as a failure
// does (abandon_output_stage: the staged files, this process's temporary files, a folder the
// command created and left empty) and then dies of the same signal (exit status 128 + signal for
// the shell). A resumable run keeps its folder: checkpoints and logs make it non-empty.
void abandon_outputs_on_termination_signals() {
  sigset_t set;
  sigemptyset(&set);
  for (int sig : {SIGINT, SIGTERM, SIGHUP}) sigaddset(&set, sig);
  if (pthread_sigmask(SIG_BLOCK, &set, nullptr) != 0) return;  // the default handling then
  std::thread([set] {
    int sig = 0;
    if (sigwait(&set, &sig) != 0) return;
    abandon_output_stage();
    std::signal(sig, SIG_DFL);
    sigset_t one;
    sigemptyset(&one);
    sigaddset(&one, sig);
    pthread_sigmask(SIG_UNBLOCK, &one, nullptr);
    std::raise(sig);
  }).detach();
}


void abandon_output_stage() {
  g_abandoned.store(true);
  const std::lock_guard<std::mutex> lock(g_stage_mutex);
  if (!g_stage || g_stage->committed_) return;
  g_stage->discard();
  g_stage->committed_ = true;  // nothing is renamed into place after this
  g_stage->files_.clear();
}

// Called with g_stage_mutex held.
void OutputStage::discard() {
  std::error_code ec;
  for (const auto& f : files_) fs::remove(f.first, ec);
  // This process's temporary files ("<name>.tmp-<pid>": a write it had not finished) in the
  // folders it claimed or created; another process's are never touched.
  const std::string mine = ".tmp-" + std::to_string(static_cast<long>(::getpid()));
  std::vector<fs::path> folders(dirs_.begin(), dirs_.end());
  for (const std::string& m : markers_) folders.push_back(fs::path(m).parent_path());
  for (const fs::path& d : folders)
    for (const auto& e : fs::directory_iterator(d, ec)) {
      const std::string name = e.path().filename().string();
      if (name.size() > mine.size() && name.compare(name.size() - mine.size(), mine.size(), mine) == 0) fs::remove(e.path(), ec);
    }
  // A marker this command wrote into a folder that holds nothing else goes too: the folder is
  // then as it was (empty, or removed below when the command created it).
  for (const std::string& m : markers_) {
    const fs::path dir = fs::path(m).parent_path();
    std::size_t entries = 0;
    for (const auto& e : fs::directory_iterator(dir, ec)) entries += e.path().filename() != kOutputMarker;
    if (!ec && entries == 0) fs::remove(m, ec);
  }
  // Folders this command created, deepest first, removed only while empty: never anything
  // else's (a non-empty folder is kept, e.g. a run folder holding a resumable checkpoint).
  for (auto it = dirs_.rbegin(); it != dirs_.rend(); ++it) fs::remove(*it, ec);
}

void OutputStage::commit() {
  wait_if_abandoned();  // a signal's discard has run or is running: nothing is renamed into place
  // Under the stage's lock: the signal thread's abandon_output_stage never runs beside it.
  const std::lock_guard<std::mutex> lock(g_stage_mutex);
  if (committed_) return;
  // What can be known to fail is checked before the first rename, so that a set is renamed
  // whole or not at all: a final name taken by a folder, a temporary file that vanished.
  for (const auto& f : files_) {
    std::error_code ec;
    if (fs::is_directory(f.second, ec)) fail(f.second, "", "is a folder; the command's outputs were not written");
    if (!fs::is_regular_file(f.first, ec))
      fail(f.second, "", "its temporary file '" + f.first + "' disappeared; the command's outputs were not written");
  }
  for (const auto& f : files_) {
    std::error_code ec;
    fs::rename(f.first, f.second, ec);
    if (ec) fail(f.second, "", "cannot rename the temporary file '" + f.first + "' into place: " + ec.message());
  }
  files_.clear();
  committed_ = true;
}

void commit_output(const std::string& tmp, const std::string& path) {
  wait_if_abandoned();
  const std::lock_guard<std::mutex> lock(g_stage_mutex);
  if (g_stage && g_stage->defer_files_) {
    for (auto& f : g_stage->files_)
      if (f.second == path) {  // written again: the newer temporary file replaces the older
        if (f.first != tmp) {
          std::error_code ec;
          fs::remove(f.first, ec);
        }
        f.first = tmp;
        return;
      }
    g_stage->files_.emplace_back(tmp, path);
    return;
  }
  if (std::rename(tmp.c_str(), path.c_str()) != 0)
    fail(path, "", std::string("cannot rename temp file into place: ") + std::strerror(errno));
}

std::string readable_output(const std::string& path) {
  const std::lock_guard<std::mutex> lock(g_stage_mutex);
  if (g_stage)
    for (const auto& f : g_stage->files_)
      if (f.second == path) return f.first;
  return path;
}

void make_output_dir(const std::string& dir, const std::string& argument) {
  if (dir.empty()) reject(argument, "\"\"", "a folder name");
  std::error_code ec;
  if (fs::is_directory(dir, ec)) return;
  // The ancestors that do not exist yet, outermost first: the stage removes them on failure.
  std::vector<fs::path> missing;
  for (fs::path p = fs::path(dir).lexically_normal(); !p.empty() && !fs::exists(p, ec); p = p.parent_path()) {
    missing.push_back(p);
    if (p == p.parent_path()) break;
  }
  fs::create_directories(dir, ec);
  if (ec || !fs::is_directory(dir))
    reject(argument, dir, "a folder that can be created (" + (ec ? ec.message() : std::string("exists as a file")) + ")");
  const std::lock_guard<std::mutex> lock(g_stage_mutex);
  if (g_stage)
    for (auto it = missing.rbegin(); it != missing.rend(); ++it) g_stage->dirs_.push_back(it->string());
}

void claim_output_dir(const std::string& dir, const std::string& argument, const std::string& command, bool into_existing) {
  if (dir.empty()) reject(argument, "\"\"", "a folder name");
  if (command.empty()) throw Error("claim_output_dir: no command name");
  std::error_code ec;
  const fs::path marker = fs::path(dir) / kOutputMarker;
  if (fs::exists(dir, ec) && !fs::is_directory(dir, ec)) reject(argument, dir, "a folder (this is a file)");
  std::vector<std::string> entries;
  std::string maker;  // the command the folder's marker names, if any
  if (fs::is_directory(dir, ec)) {
    for (const auto& e : fs::directory_iterator(dir, ec)) {
      const std::string name = e.path().filename().string();
      if (name == ".lock") continue;  // a run folder's lock file (RunLock): qdo's, checked by the run itself
      // qdo's temporary files ("<name>.tmp-<pid>", AtomicFile): a write in progress (another qdo
      // claiming the folder at this moment) or one a kill interrupted. Not a user's.
      const std::size_t t = name.rfind(".tmp-");
      if (t != std::string::npos && t + 5 < name.size() &&
          name.find_first_not_of("0123456789", t + 5) == std::string::npos)
        continue;
      if (name == kOutputMarker) {
        std::ifstream f(marker, std::ios::binary);
        std::string text(4096, '\0');
        f.read(&text[0], std::streamsize(text.size()));
        text.resize(std::size_t(f.gcount()));
        const std::string key = "\"command\": \"";
        const std::size_t at = text.find(key), end = at == std::string::npos ? at : text.find('"', at + key.size());
        std::error_code file_ec;  // kept apart from the listing's error
        if (fs::is_regular_file(e.path(), file_ec) && end != std::string::npos) maker = text.substr(at + key.size(), end - at - key.size());
        if (maker.empty()) entries.push_back(name + " (unreadable)");
      } else {
        entries.push_back(name);
      }
    }
    if (ec) reject(argument, dir, "a folder that can be listed (" + ec.message() + ")");
    std::sort(entries.begin(), entries.end());
  }
  const bool ours = maker == command;
  if (!ours && !into_existing && (!entries.empty() || !maker.empty())) {
    std::string list;
    const std::size_t shown = std::min<std::size_t>(entries.size(), 5);
    for (std::size_t i = 0; i < shown; ++i) list += (i ? ", " : "") + entries[i];
    if (entries.size() > shown) list += ", ... (" + std::to_string(entries.size()) + " entries)";
    const std::string what = !maker.empty() ? "a folder `qdo " + maker + "` made" + (list.empty() ? "" : " (holding " + list + ")")
                                            : "a folder qdo did not make, holding " + list;
    reject(argument, dir,
           "a new or empty folder, or one an earlier `qdo " + command + "` made; this is " + what +
               ". Choose another folder, or pass --into-existing to write into it anyway (files of the names qdo " + command +
               " writes are then replaced)");
  }
  make_output_dir(dir, argument);
  if (ours) return;
  write_text_atomic(marker.string(), "{\"made_by\": \"qdo\", \"command\": \"" + command + "\"}\n");
  const std::lock_guard<std::mutex> lock(g_stage_mutex);
  if (g_stage) g_stage->markers_.push_back(marker.string());
}

void write_text_atomic(const std::string& path, const std::string& text) {
  AtomicFile out(path);
  {
    std::ofstream f(out.tmp(), std::ios::binary | std::ios::trunc);
    if (!f) fail(path, "", std::string("cannot create file: ") + std::strerror(errno));
    f.write(text.data(), static_cast<std::streamsize>(text.size()));
    f.close();
    if (!f) fail(path, "", "write failed");
  }
  out.commit();
}

}  // namespace qdo
