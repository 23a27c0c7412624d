// Where a camera's PSF comes from, decided once at the edge and turned into a PsfSource in one
// place: the run's own design, a design simulated (lens:NM, flat, or a design .h5 file such as
// qdo fit's as-built design), or a PSF stack file (qdo calibrate's measured stack, qdo psf's).
// Commands parse their --psf / --design into a PsfSpec, read it against the configuration before
// any work (read_psf_input: no device), then make the source (make_psf_source).
//
//   stack:   bands x S x S reals, row-major, S = cfg.sensor_size_px() (psf_source.hpp's layout)
//   heights: N x N metres, row-major, N = cfg.n
#pragma once
#include <memory>
#include <string>

#include "qdo/data/config.hpp"
#include "qdo/physics/psf_source.hpp"
#include "qdo/runtime/runtime.hpp"
#include "qdo/physics/simulator.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo {

struct PsfSpec {
  enum class Kind { Run, Design, File };
  Kind kind = Kind::Run;
  std::string value;     // Design: lens:NM, flat or a design .h5; File: a PSF stack .h5; Run: ""
  std::string argument;  // the option it came from ("--design", "--psf"), named in refusals
};

// From a command's two options, at most one given: an InputError naming design_argument,
// "either <psf_argument> or <design_argument>, not both (<why>)", when both are; neither: Run.
PsfSpec psf_spec_from_options(const std::string& psf, const std::string& design, const std::string& psf_argument,
                              const std::string& design_argument, const std::string& why);

// What a spec names, read and checked against cfg without a device.
struct PsfInput {
  PsfSpec spec;
  RealStack stack;  // File: bands x S x S, checked (read_psf_stack_for)
  Map2D heights;    // Run and Design: N x N metres, checked (design_heights_from_spec)
  bool from_file() const { return spec.kind == PsfSpec::Kind::File; }
  // One line for reports: "PSF file X", "fitted design X (simulated)", "the run's design X (simulated)"
  // (run_design: the run's design file, for Run).
  std::string describe(const std::string& run_design = "") const;
};
// Run takes run_heights (N x N, the run's design; an InputError naming spec.argument when absent).
PsfInput read_psf_input(const PsfSpec& spec, const SystemConfig& cfg, const Map2D* run_heights = nullptr);

// The device source of an input: the file's stack (StackPsfSource), or a Simulator with the
// heights (its field not kept: no adjoint follows; compute() makes the PSF).
struct SpecPsfSource {
  std::unique_ptr<Simulator> sim;
  std::unique_ptr<StackPsfSource> file;
  const PsfSource& source() const { return sim ? static_cast<const PsfSource&>(*sim) : *file; }
  void compute() {
    if (sim) sim->compute_psf();
  }
};
SpecPsfSource make_psf_source(Runtime& rt, const SystemConfig& cfg, Precision p, const PsfInput& in);
// The sensor-grid stack of an input (bands x S x S): the file's, or the heights' simulated.
RealStack psf_stack(Runtime& rt, const SystemConfig& cfg, Precision p, const PsfInput& in);

}  // namespace qdo
