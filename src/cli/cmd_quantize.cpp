// qdo quantize: a design's heights quantized post hoc to --levels uniform levels (doe.hpp) -> a
// design .h5 file (--out).
#include <cstdio>
#include <filesystem>
#include <string>

#include "cli.hpp"
#include "options.hpp"
#include "qdo/physics/doe.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"

namespace fs = std::filesystem;

namespace qdo::cli {

static int cmd_quantize(const Args& a) {
  const SystemConfig cfg = load_config(a);
  if (!a.has("levels")) reject("--levels", "(missing)", "the number of levels L >= 2");
  const std::string out = a.get("out");
  if (out.empty()) reject("--out", "(missing)", "an output .h5 file");
  const Map2D full = load_design(cfg, a.get("design"));
  const QuantSpec qs = load_quantizer(a);
  const Map2D hq = quantize_heights(full, cfg.h_max_m(), qs.q);
  Design d;
  d.height_m = hq;
  d.pitch_m = cfg.pitch_m;
  d.levels_m = qs.q.level_heights_m(cfg.h_max_m());
  if (fs::path(out).has_parent_path()) make_output_dir(fs::path(out).parent_path().string(), "--out");
  write_design(out, d, {{"source", a.get("design")}, {"mode", "DO (post-hoc uniform quantization)"},
                        {"levels", std::to_string(qs.q.levels)}, {"placement", to_string(qs.q.placement)}});
  std::printf("quantized to %d levels (%s): mean |H_q - H_f| = %.3f nm; levels (nm):", qs.q.levels,
              to_string(qs.q.placement).c_str(), quantization_deviation_m(hq, full) * 1e9);
  for (double l : d.levels_m) std::printf(" %.1f", l * 1e9);
  std::printf("\nwrote %s\n", out.c_str());
  return 0;
}

namespace {
// qdo quantize: its entry in the command table (help order 70).
const RegisterCommand registered_quantize(70, [] {
  using namespace opts;
  CommandSpec c{"quantize", "quantize a design to L levels (post-hoc, uniform) into a design .h5 file", "", "",
                   {preset(), config(), design_spec(), opt("levels", "number of height levels L, an integer in [2, 65536] (required)"),
                    placement(), opt("out", "output design .h5 file")},
                   cmd_quantize};
  return c;
});
}  // namespace

}  // namespace qdo::cli
