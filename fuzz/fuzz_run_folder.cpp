// Fuzz target: the state `qdo design --resume` reads from a run folder (load_resume_state,
// design_run.hpp): config.json, checkpoint.h5 and log.csv, split from one input by
// fuzz::kFileSeparator in that order (fewer parts: the later files are absent). The loader must
// succeed or throw an InputError naming one of the files (or the folder, when config.json or
// checkpoint.h5 is absent). What it accepts must be consistent: options that survive a write /
// read round trip, a state of the sizes the options imply, and only log rows before the step.
#include <cstdlib>
#include <filesystem>

#include "fuzz_util.hpp"
#include "qdo/design/run_folder.hpp"
#include "qdo/design/design_run.hpp"
#include "qdo/physics/doe.hpp"
#include "qdo/design/run.hpp"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  using namespace qdo;
  namespace fs = std::filesystem;
  static const std::string dir = [] {
    const std::string d = fuzz::scratch().path("run");
    fs::create_directories(d);
    return d;
  }();
  const char* names[] = {"config.json", "checkpoint.h5", "log.csv"};
  const std::vector<std::string> parts = fuzz::split_files(data, size);
  for (std::size_t k = 0; k < 3; ++k) {
    std::error_code ec;
    fs::remove(fs::path(dir) / names[k], ec);
    if (k < parts.size())
      fuzz::scratch().write(std::string("run/") + names[k], reinterpret_cast<const std::uint8_t*>(parts[k].data()),
                            parts[k].size());
  }
  try {
    const ResumeState r = load_resume_state(dir);
    const DesignRunOptions& o = r.options;
    const std::string text = design_run_options_to_json(o);
    if (design_run_options_to_json(design_run_options_from_json(text, "round trip")) != text)
      fuzz::fail("accepted run options do not survive a write/read round trip");
    if (r.state.w.size() != parameter_count(o.design.parameterization, o.cfg.n))
      fuzz::fail("accepted a checkpoint whose weights do not fit the stored options");
    const std::size_t levels = o.design.mode == DesignMode::QDOM ? std::size_t(mask_count(o.design.quantizer.levels))
                                                                : std::size_t(o.design.quantizer.levels);
    if (r.state.offsets.size() != levels) fuzz::fail("accepted a checkpoint whose offsets do not fit the stored levels");
    if (r.state.step < 0) fuzz::fail("accepted a negative step");
    if (r.log_rows.size() != r.losses.size()) fuzz::fail("log rows and losses differ in number");
    for (const auto& row : r.log_rows)
      if (std::strtol(row.c_str(), nullptr, 10) >= r.state.step) fuzz::fail("kept a log row at or after the checkpoint's step");
    if (parts.size() < 2) fuzz::fail("accepted a run folder without checkpoint.h5");
  } catch (const InputError& e) {
    const std::string msg = e.what();
    bool named = false;
    for (const char* n : names) named = named || msg.find((fs::path(dir) / n).string()) != std::string::npos;
    if (!named && parts.size() >= 2) fuzz::fail("InputError names none of the run folder's files: " + msg);
    if (!named) fuzz::expect_names(e, dir);
  }
  return 0;
}
