// The decoder a run uses, as given on the command line (`--decoder`), parsed without LibTorch:
//   wiener                       the linear MMSE decoder (REFERENCE §3b)
//   resunet                      the paper's Res-UNet at a default size that trains in minutes on
//                                2 CPU cores at the small preset (depth 4, filter root 16)
//   resunet:paper                the paper's size (depth 7, filter root 32; 1.217e8 parameters)
//   resunet:depth=D,root=R       any size: D in [1, 10] levels, R in [1, 1024] filters (either key
//                                may be left out; the default's value is then used)
// A bad spec is an InputError naming the key and the value.
#pragma once
#include <cstddef>
#include <string>

namespace qdo {

struct DecoderSpec {
  enum class Kind { Wiener, ResUNet } kind = Kind::Wiener;
  std::size_t depth = 4, root = 16;  // Res-UNet levels and first-level filters (Kind::ResUNet)
  std::string to_string() const;     // canonical form: "wiener" or "resunet:depth=D,root=R"
};

DecoderSpec decoder_spec_from_string(const std::string& spec);

}  // namespace qdo
