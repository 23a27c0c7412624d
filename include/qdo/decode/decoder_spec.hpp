// A decoder as named on the command line (`qdo design --decoder`, `qdo eval --decoder-kind`,
// `qdo sweep --grid decoder=`) and in a run's config.json ("decoder"), parsed without LibTorch:
//   wiener                       the linear MMSE decoder (REFERENCE §3b)
//   resunet                      the paper's Res-UNet at a default size that trains in minutes on
//                                2 CPU cores at the small preset (depth 4, filter root 16)
//   resunet:paper                the paper's size (depth 7, filter root 32; 1.217e8 parameters)
//   resunet:depth=D,root=R       any size: D in [1, 10] levels, R in [1, 1024] filters (either key
//                                may be left out; the default's value is then used)
//   NAME[:key=value,...]         any other decoder of the registry (decoder_registry.hpp), e.g. cg,
//                                with its own parameters (the registered factory reads them)
// A bad spec, or a NAME the registry does not know, is an InputError naming the key and the value
// (and, for an unknown name, every known one).
#pragma once
#include <cstddef>
#include <string>
#include <utility>
#include <vector>

namespace qdo {

struct DecoderSpec {
  // Wiener and ResUNet have their own grammar and meaning in a design run (Wiener: the closed-form
  // objective's decoder; ResUNet: trained with the optics). Named: any other registered decoder.
  enum class Kind { Wiener, ResUNet, Named } kind = Kind::Wiener;
  std::size_t depth = 4, root = 16;  // Res-UNet levels and first-level filters (Kind::ResUNet)
  std::string name;                  // Kind::Named: the registry name (lower-case letters, digits, '-', '_')
  std::vector<std::pair<std::string, std::string>> params;  // Kind::Named: key=value pairs in the order given

  // The registry's name of the decoder: "wiener", "resunet" or `name`.
  std::string kind_name() const;
  // Whether it is trained with the optics (objective network, qdo/design/joint.hpp): a resunet
  // spec, or a registered decoder whose entry has a `train` factory (decoder_registry.hpp).
  bool network() const;
  // The value of parameter `key` (Kind::Named), or `def` when it is not given.
  std::string param(const std::string& key, const std::string& def = "") const;
  // Canonical form: "wiener", "resunet:depth=D,root=R", "NAME" or "NAME:k1=v1,k2=v2" (parameters
  // in the order given). decoder_spec_from_string(s.to_string()) == s.
  std::string to_string() const;
  bool operator==(const DecoderSpec& o) const { return to_string() == o.to_string(); }
  bool operator!=(const DecoderSpec& o) const { return !(*this == o); }
};

DecoderSpec decoder_spec_from_string(const std::string& spec);

}  // namespace qdo
