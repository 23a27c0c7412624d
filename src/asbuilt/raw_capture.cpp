// Raw capture checks and outputs (raw_capture.hpp).
#include "qdo/asbuilt/raw_capture.hpp"

#include "qdo/data/io.hpp"
#include "qdo/runtime/error.hpp"

namespace qdo {

void check_raw_capture_config(const SystemConfig& cfg, const std::string& argument) {
  if (cfg.cfa == Cfa::None)
    reject(argument, "a configuration with \"cfa\": \"none\"",
           "a colour filter mosaic (\"cfa\": \"rggb\", \"grbg\", \"gbrg\" or \"bggr\"): a raw frame is one plane");
  if (cfg.bit_depth == 0)
    reject(argument, "a configuration with \"bit_depth\": 0",
           "a bit depth of 8 .. 16 (\"bit_depth\"): raw frames are written as integer code values in 16-bit PNG");
}

Map2D raw_plane_map(const RealStack& raw) {
  if (raw.planes != 1) reject("raw", to_str(raw.planes) + " planes", "one mosaic plane (1 x H x W)");
  Map2D m(raw.rows, raw.cols);
  m.data = raw.data;
  return m;
}

void write_raw_capture_outputs(const std::string& dir, const SystemConfig& cfg, const CaptureFrame& frame, DemosaicMethod demosaic,
                               const std::string& provenance) {
  const RealStack& dn = frame.raw_dn;
  const RawCounts& counts = frame.raw_counts;
  if (dn.data.empty() || counts.total == 0) reject("frame", "a frame without raw output", "a frame of a pipeline with raw output");
  const double sat = double(counts.saturated) / double(counts.total), flo = double(counts.floored) / double(counts.total);
  write_png16_gray(dir + "/raw.png", raw_plane_map(dn));
  h5_write(dir + "/raw.h5",
           {{"/raw", {1, dn.rows, dn.cols}, dn.data,
             {{"black_level_dn", cfg.black_level_dn}, {"white_level_dn", cfg.white_level_dn()}, {"gain", cfg.gain},
              {"bit_depth", double(cfg.bit_depth)}, {"saturated_fraction", sat}, {"floored_fraction", flo}},
             {{"units", "DN"}, {"cfa", to_string(cfg.cfa)}}},
            {"/rgb_demosaiced", {3, dn.rows, dn.cols}, frame.demosaiced.data, {},
             {{"units", "linear, 1 = full well (DN - black) / (gain (white - black))"}, {"method", to_string(demosaic)}}}},
           {{"config", config_to_json_text(cfg)}, {"source", provenance}});
  write_rgb_png(dir + "/raw_demosaiced.png", frame.demosaiced);
}

}  // namespace qdo
