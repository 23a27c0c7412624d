// Raw captures as the sensor as built writes them, as library calls: the configuration check every
// raw output needs, and the files of `qdo simulate --raw` (the raw and demosaic stages of a
// CapturePipeline frame, capture_pipeline.hpp).
#pragma once
#include <string>

#include "qdo/data/config.hpp"
#include "qdo/physics/capture_pipeline.hpp"
#include "qdo/physics/demosaic_reference.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo {

// A raw frame is one mosaic plane of integer code values: cfg.cfa a mosaic (not "none") and
// cfg.bit_depth in 8 .. 16. An InputError naming `argument` (the option that asked for raw output)
// otherwise.
void check_raw_capture_config(const SystemConfig& cfg, const std::string& argument);

// A raw plane (1 x H x W code values in DN, row-major) as an H x W map (the 16-bit PNG writer's).
Map2D raw_plane_map(const RealStack& raw);

// DIR/raw.png (frame.raw_dn, 1 x H x W DN, as a 16-bit PNG), raw.h5 (/raw 1 x H x W DN with the
// sensor's black level, white level, gain, bit depth and the saturated and floored fractions;
// /rgb_demosaiced 3 x H x W linear, 1 = full well) and raw_demosaiced.png. frame: a run of a
// pipeline with raw output; demosaic: the method that made frame.demosaiced; provenance: raw.h5's
// "source" attribute. The folder exists.
void write_raw_capture_outputs(const std::string& dir, const SystemConfig& cfg, const CaptureFrame& frame, DemosaicMethod demosaic,
                               const std::string& provenance);

}  // namespace qdo
