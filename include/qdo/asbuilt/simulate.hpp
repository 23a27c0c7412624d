// qdo simulate as a library call: the RGB sensor image of a scene through a PSF source (a design
// simulated on the device, or a PSF stack file), through the capture pipeline
// (capture_pipeline.hpp: the camera operator, noise, the full-scale clip; with raw, the raw and
// demosaic stages, raw_capture.hpp); a spatially varying image (a depth map or a field grid,
// varying_capture.hpp); or a simulated monochromator sweep of a point source and dark frames for
// qdo calibrate (psf_sweep_capture.hpp).
//
// Two steps. plan_simulate reads the options as a user typed them (TextOptions, by name without
// "--": preset, config, design, psf, levels, placement, scene, key, resample-bands, formation,
// raw, demosaic, capture, frame-size, peak, darks, centre, depth, depth-scale, depth-layers,
// psf-placement, field-grid, field-edge-deg, field-rank, precision, save, compress) and checks
// every one on the host, the scene and the PSF file read, before any device work or output:
// refusals are InputErrors naming the option as typed ("--centre"), the value and what is allowed.
// run_simulate then computes on the device and writes the outputs into a folder the caller claimed.
#pragma once
#include <functional>
#include <string>
#include <vector>

#include "qdo/asbuilt/psf_sweep_capture.hpp"
#include "qdo/asbuilt/varying_capture.hpp"
#include "qdo/data/config.hpp"
#include "qdo/design/psf_spec.hpp"
#include "qdo/physics/capture_pipeline.hpp"
#include "qdo/runtime/parse.hpp"
#include "qdo/runtime/runtime.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo {

enum class SimulateKind { Scene, PsfSweep, Varying };

// What a simulation computes, every input read and checked on the host.
struct SimulatePlan {
  SimulateKind kind = SimulateKind::Scene;
  SystemConfig cfg;
  Precision precision = Precision::F32;
  std::string design;              // --design as given (psf.h5's provenance)
  bool save_native = false;        // --save native: /psf_native in psf.h5
  bool compress = false;           // --compress
  PsfInput psf;                    // Scene and PsfSweep: the PSF source's input
  RealStack scene;                 // Scene and Varying: bands x H x W, row-major
  PipelineOptions capture;         // Scene: the formation, raw and demosaic stages
  PsfSweepCaptureSpec sweep;       // PsfSweep: the frames, peak, darks and centre
  VaryingPlan varying;             // Varying: the components, their weights
  Map2D heights;                   // Varying: the design, N x N metres, row-major
  std::string varying_option;      // Varying: "--depth" or "--field-grid"
  std::vector<std::string> notes;  // remarks for the user before any work (e.g. the release's aperture edge)
};

// The plan from the options (see the file comment); nothing on the device, nothing written.
SimulatePlan plan_simulate(const TextOptions& a);

// The simulation into `dir` (claimed by the caller): Scene: sensor.h5, sensor.png, scene.png,
// psf.h5, psf.png, design.png (a simulated design), and with raw raw.png, raw.h5,
// raw_demosaiced.png; PsfSweep: frames/psf_<nm>nm.png, darks/dark_<k>.png, frames.png, psf.h5,
// sweep.h5; Varying: write_varying_outputs' files. say (when set) gets progress lines. Returns
// the report: device, formation, PSF, sizes, seconds, sampling, clipping, the files written.
std::string run_simulate(Runtime& rt, const SimulatePlan& plan, const std::string& dir,
                         const std::function<void(const std::string&)>& say = {});

// The varying part of plan_simulate (simulate_varying.cpp): true when the options ask for a varying
// image (depth or field-grid); check_no_orphan_varying_options refuses the varying options
// (depth-layers, depth-scale, psf-placement, field-edge-deg, field-rank) without them;
// plan_varying_simulation fills plan.varying, plan.heights, plan.scene and plan.varying_option.
bool varying_requested(const TextOptions& a);
void check_no_orphan_varying_options(const TextOptions& a);
void plan_varying_simulation(const TextOptions& a, SimulatePlan& plan);
// The report of a varying simulation run into `dir` (run_simulate's Varying part).
std::string run_varying_simulation(Runtime& rt, const SimulatePlan& plan, const std::string& dir,
                                   const std::function<void(const std::string&)>& say);

// ---- qdo image: one scene through Camera's skipping rules ----
struct ImagePlan {
  SystemConfig cfg;
  Precision precision = Precision::F32;
  SkipOptions skip;  // tolerance, tiles, tile-px, exact (validated)
  PsfInput psf;      // --psf FILE or --design (psf_input_from_options)
  RealStack scene;   // bands x H x W, row-major
};
// The options as a user typed them (TextOptions: preset, config, design, psf, levels, placement,
// scene, key, resample-bands, precision, tolerance, exact, tiles, tile-px), each checked, the scene
// and PSF file read: InputErrors naming the option as typed, before any device work.
ImagePlan plan_image(const TextOptions& a);
// DIR/sensor.png (the image, clipped to full scale) and skip.json (Camera's SkipReport), and the
// report: the PSF, sizes, seconds, what was skipped, the error bound, the clipping, the files.
std::string run_image(Runtime& rt, const ImagePlan& q, const std::string& dir);

}  // namespace qdo
