// qdo quantize as a library call (quantize_design.hpp).
#include "qdo/design/quantize_design.hpp"

#include <filesystem>

#include "qdo/data/io.hpp"
#include "qdo/design/option_inputs.hpp"
#include "qdo/design/run_folder.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/runtime/strprintf.hpp"

namespace fs = std::filesystem;

namespace qdo {

std::string quantize_design_file(const TextOptions& a) {
  const SystemConfig cfg = config_from_options(a);
  if (!a.has("levels")) reject("--levels", "(missing)", "the number of levels L >= 2");
  const std::string out = a.get("out");
  if (out.empty()) reject("--out", "(missing)", "an output .h5 file");
  const Map2D full = design_heights_from_spec(cfg, a.get("design"), "--design");
  const QuantizerOption qs = quantizer_from_options(a);
  const Map2D hq = quantize_heights(full, cfg.h_max_m(), qs.q);
  Design d;
  d.height_m = hq;
  d.pitch_m = cfg.pitch_m;
  d.levels_m = qs.q.level_heights_m(cfg.h_max_m());
  if (fs::path(out).has_parent_path()) make_output_dir(fs::path(out).parent_path().string(), "--out");
  write_design(out, d,
               {{"source", a.get("design")},
                {"mode", "DO (post-hoc uniform quantization)"},
                {"levels", std::to_string(qs.q.levels)},
                {"placement", to_string(qs.q.placement)}});
  std::string s = strprintf("quantized to %d levels (%s): mean |H_q - H_f| = %.3f nm; levels (nm):", qs.q.levels,
                            to_string(qs.q.placement).c_str(), quantization_deviation_m(hq, full) * 1e9);
  for (double l : d.levels_m) s += strprintf(" %.1f", l * 1e9);
  return s + "\nwrote " + out + "\n";
}

}  // namespace qdo
