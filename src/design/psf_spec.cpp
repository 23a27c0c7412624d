// Where a camera's PSF comes from (psf_spec.hpp): the spec, its input read without a device, and
// the one place that turns it into a PsfSource.
#include "qdo/design/psf_spec.hpp"

#include "qdo/runtime/error.hpp"
#include "qdo/design/run_folder.hpp"

namespace qdo {

PsfSpec psf_spec_from_options(const std::string& psf, const std::string& design, const std::string& psf_argument,
                              const std::string& design_argument, const std::string& why) {
  if (!psf.empty() && !design.empty())
    reject(design_argument, design, "either " + psf_argument + " or " + design_argument + ", not both (" + why + ")");
  if (!psf.empty()) return {PsfSpec::Kind::File, psf, psf_argument};
  if (!design.empty()) return {PsfSpec::Kind::Design, design, design_argument};
  return {PsfSpec::Kind::Run, "", design_argument};
}

std::string PsfInput::describe(const std::string& run_design) const {
  switch (spec.kind) {
    case PsfSpec::Kind::File: return "PSF file " + spec.value;
    case PsfSpec::Kind::Design: return "fitted design " + spec.value + " (simulated)";
    case PsfSpec::Kind::Run: break;
  }
  return "the run's design " + (run_design.empty() ? std::string() : run_design + " ") + "(simulated)";
}

PsfInput read_psf_input(const PsfSpec& spec, const SystemConfig& cfg, const Map2D* run_heights) {
  PsfInput in;
  in.spec = spec;
  switch (spec.kind) {
    case PsfSpec::Kind::File: in.stack = read_psf_stack_for(cfg, spec.value, spec.argument); break;
    case PsfSpec::Kind::Design: in.heights = design_heights_from_spec(cfg, spec.value, spec.argument); break;
    case PsfSpec::Kind::Run:
      if (!run_heights) reject(spec.argument, "(missing)", "a design: lens:NM, flat, or a design .h5 file");
      in.heights = *run_heights;
      break;
  }
  return in;
}

SpecPsfSource make_psf_source(Runtime& rt, const SystemConfig& cfg, Precision p, const PsfInput& in) {
  SpecPsfSource s;
  if (in.from_file()) {
    s.file = std::make_unique<StackPsfSource>(rt, cfg, p, in.stack, "PSF file '" + in.spec.value + "'");
  } else {
    s.sim = std::make_unique<Simulator>(rt, cfg, p);
    s.sim->set_keep_field(false);  // no adjoint follows (Simulator::set_keep_field)
    s.sim->set_heights(in.heights);
  }
  return s;
}

RealStack psf_stack(Runtime& rt, const SystemConfig& cfg, Precision p, const PsfInput& in) {
  if (in.from_file()) return in.stack;
  SpecPsfSource s = make_psf_source(rt, cfg, p, in);
  s.compute();
  return s.sim->psf_sensor();
}

}  // namespace qdo
