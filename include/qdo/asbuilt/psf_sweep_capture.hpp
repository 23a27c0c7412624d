// A simulated monochromator sweep of a point source, as a library call (what `qdo simulate
// --capture psf-sweep` runs): the raw frames and dark frames `qdo calibrate` reads
// (include/qdo/physics/calibrate.hpp), made with the design's sensor PSF through the sensor as
// built (ref::raw_forward: mosaic, noise, black level, gain, clipping, bit depth).
//
// For each configured band b, the sensor PSF (bands x S x S, axis at (S/2, S/2)) is placed with its
// axis at the centre of an F x F frame, scaled so the brightest colour's peak is `peak` of full
// well, each colour c weighted by its response srf(c, b) relative to the band's largest (as a
// monochromator at that band lights it): DIR/frames/psf_<nm>nm.png; then `darks` frames of no light
// (DIR/darks/dark_<k>.png). Frame k (the bands in order, then the darks) draws its noise as scene k
// of one batch (counters from the configuration's noise_seed). Also DIR/psf.h5 (the PSF stack
// imaged), sweep.h5 (wavelengths, amplitudes, each frame's largest code value, the provenance) and
// frames.png (the frames' S x S windows above the black level).
//
// Two steps: plan_psf_sweep_capture checks every input on the host, before any device work;
// capture_psf_sweep computes the PSF and writes the files. Refusals are InputErrors naming the
// argument, the value and what is allowed; the labels carry the names a caller such as the command
// line uses (varying_capture.hpp's InputLabel).
#pragma once
#include <cstddef>
#include <functional>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "qdo/data/config.hpp"
#include "qdo/design/psf_spec.hpp"
#include "qdo/asbuilt/varying_capture.hpp"
#include "qdo/physics/raw_reference.hpp"
#include "qdo/runtime/runtime.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo {

struct PsfSweepCaptureSpec {
  std::size_t frame_px = 0;                     // F, in [S, 8192] (S = cfg.sensor_size_px()); 0: S + 64
  std::optional<std::pair<long, long>> centre;  // (row, col) frame pixel of the optical axis; empty: (F/2, F/2)
  double peak = 0.6;                            // the brightest colour's peak, a fraction of full well in (0, 1]
  std::size_t darks = 8;                        // dark frames, in [1, 1000]
  std::string design;                           // sweep.h5's "design" attribute (what the PSF is of)
  std::string provenance = "capture_psf_sweep";  // sweep.h5's "source" attribute
  InputLabel centre_label{"centre", ""};        // text empty: "ROW,COL" of the centre
  InputLabel psf_label{"psf", ""};              // a band without light; text empty: the input's spec value
  InputLabel config_label{"cfg", ""};           // a configuration without a raw sensor (check_raw_capture_config)
};

// The frames' geometry, checked: F x F frames, the S x S PSF window's axis at (centre_row,
// centre_col), the window inside the frame.
struct PsfSweepGeometry {
  std::size_t frame_px = 0, psf_px = 0;
  long centre_row = 0, centre_col = 0;
};
PsfSweepGeometry plan_psf_sweep_capture(const SystemConfig& cfg, const PsfSweepCaptureSpec& spec);

struct PsfSweepCaptureResult {
  PsfSweepGeometry geometry;
  RealStack psf;                        // bands x S x S, the sensor PSF stack imaged (psf.h5)
  std::vector<double> wavelengths_nm;   // bands
  std::vector<double> amplitude;        // bands: full well per unit of the unit-sum PSF (brightest colour)
  std::vector<double> peak_dn;          // bands: each frame's largest code value, DN
  RawCounts frames, darks;              // the raw clipping tallies of the PSF frames and of the dark frames
  std::size_t frames_saturated = 0;     // PSF frames holding a saturated pixel
  double seconds = 0;                   // the frames and darks, made and written (after the PSF)
  std::string psf_description;          // the PSF source's one-line description
};

// The sweep of `in` (read_psf_input: a PSF file's stack, or heights simulated in precision p) into
// DIR (which exists; the caller claims it). progress (when set) is called after each PSF frame
// with its band index and the seconds since the first. InputError: the plan's refusals (before any
// device work), a band whose PSF or sensor response is dark.
PsfSweepCaptureResult capture_psf_sweep(Runtime& rt, const SystemConfig& cfg, Precision p, const PsfInput& in,
                                        const PsfSweepCaptureSpec& spec, const std::string& dir,
                                        const std::function<void(std::size_t band, double seconds)>& progress = {});

}  // namespace qdo
