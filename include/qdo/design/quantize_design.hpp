// qdo quantize as a library call: a design's heights quantized post hoc to L uniform levels
// (doe.hpp: quantize_heights) and written as a design .h5 file.
#pragma once
#include <string>

#include "qdo/runtime/parse.hpp"

namespace qdo {

// The options as a user typed them (TextOptions: preset, config, design, levels (required),
// placement, out (the .h5 file; its folder is created)), each checked (InputError naming the option
// as typed); writes the file with its provenance (source, mode, levels, placement) and returns the
// report: levels, placement, mean |H_q - H_f| (nm), the level heights (nm) and the file written.
std::string quantize_design_file(const TextOptions& a);

}  // namespace qdo
