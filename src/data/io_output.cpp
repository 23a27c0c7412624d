// Output staging: the command's files are written to temporary names and renamed into place
// together (OutputStage, commit_output), its new folders removed on failure
// (make_output_dir), and write_text_atomic.
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <mutex>

#include "data/io_internal.hpp"
#include "qdo/error.hpp"
#include "qdo/io.hpp"

namespace qdo {
using namespace io_detail;
namespace {
namespace fs = std::filesystem;
}  // namespace

// =========================================================================================
// Output staging
// =========================================================================================

namespace {
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
  g_stage = nullptr;
  if (committed_) return;
  std::error_code ec;
  for (const auto& f : files_) fs::remove(f.first, ec);
  // Folders this command created, deepest first, removed only while empty: never anything
  // else's (a non-empty folder is kept, e.g. a run folder holding a resumable checkpoint).
  for (auto it = dirs_.rbegin(); it != dirs_.rend(); ++it) fs::remove(*it, ec);
}

void OutputStage::commit() {
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
