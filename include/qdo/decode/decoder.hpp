// The one decoder interface: a sensor image in, a cube estimate out. Implemented by the Wiener
// decoder (wiener.hpp), the conjugate-gradient MAP decoder (CgDecoder, encoders.hpp) and, through
// an adapter, the network decoder (NetworkImageDecoder, network_decoder.hpp); `qdo eval`, the
// test-set evaluation (testset.hpp) and `qdo sweep` build them through the registry
// (decoder_registry.hpp) and use them only through this interface.
//
// Shapes (Stack<T> row-major, types.hpp): sensor images channels() x H x W' (W' = W for the
// shift-invariant cameras), cube estimates bands() x H x W, not clipped.
#pragma once
#include <cstddef>
#include <string>
#include <vector>

#include "qdo/runtime/types.hpp"

namespace qdo {

class Decoder {
 public:
  virtual ~Decoder() = default;
  // y: channels() x H x W' sensor image -> bands() x H x W cube estimate.
  virtual RealStack decode(const RealStack& y) const = 0;
  // One estimate per image, in order. The default decodes one image at a time; a network decodes
  // the whole batch in one call.
  virtual std::vector<RealStack> decode_batch(const std::vector<RealStack>& ys) const {
    std::vector<RealStack> out;
    out.reserve(ys.size());
    for (const RealStack& y : ys) out.push_back(decode(y));
    return out;
  }
  // Images per decode_batch() call of the test-set evaluation (testset::evaluate), >= 1.
  virtual std::size_t batch() const { return 1; }
  virtual std::size_t bands() const = 0;
  virtual std::size_t channels() const = 0;
  // One line naming the decoder in `qdo eval`'s metrics.json ("imaging"), e.g. "Wiener decoder";
  // "" lets the caller name it by its spec.
  virtual std::string description() const { return ""; }
};

}  // namespace qdo
