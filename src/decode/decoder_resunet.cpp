// The registry's "resunet" (decoder_registry.hpp): trained by a design run through the LibTorch
// plugin's factory (make_network_decoder); at evaluation the network a run trained with its optics
// (DecoderInputs::run_network), in inference mode, batches of 8 images. A network cannot be
// built from a PSF: outside a network run it is refused.
#include <memory>

#include "qdo/decode/decoder_registry.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/decode/network_decoder.hpp"

namespace qdo {

DecoderEntry resunet_decoder_entry() {
  DecoderEntry e;
  e.name = "resunet";
  e.summary = "the run's Res-UNet, trained with the optics (a network run's; inference mode)";
  e.trained = true;
  e.train = make_network_decoder;  // the LibTorch plugin's Res-UNet (network_decoder.hpp)
  e.make = [](const DecoderInputs& in) -> std::unique_ptr<Decoder> {
    if (!in.run_network)
      reject("decoder", in.spec.to_string(), "a decoder built from the camera (the network is a run's: qdo eval RUN)");
    return std::make_unique<NetworkImageDecoder>(in.run_network(), in.psf.planes, 8,
                                                 "the run's network (" + in.spec.to_string() + ", inference mode)");
  };
  return e;
}

}  // namespace qdo
