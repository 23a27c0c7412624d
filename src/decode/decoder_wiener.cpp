// The registry's "wiener" (decoder_registry.hpp): the Wiener decoder (wiener.hpp) built for the
// PSF stack on the prior's grid, OTF = psf_to_otf(psf, prior.rows, prior.cols).
#include <memory>

#include "qdo/decode/decoder_registry.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/decode/wiener.hpp"

namespace qdo {

DecoderEntry wiener_decoder_entry() {
  DecoderEntry e;
  e.name = "wiener";
  e.summary = "the linear MMSE (Wiener) decoder of the PSF camera under the scene prior (REFERENCE §3b)";
  e.make = [](const DecoderInputs& in) -> std::unique_ptr<Decoder> {
    if (in.encoder) reject("decoder", "wiener", "a shift-invariant PSF camera (cg decodes any linear encoder)");
    if (!in.spec.params.empty()) reject("decoder", in.spec.to_string(), "wiener without parameters");
    return std::make_unique<WienerDecoder>(wiener::psf_to_otf(in.psf, in.prior.rows, in.prior.cols), in.srf, in.prior,
                                           in.noise_sigma);
  };
  return e;
}

}  // namespace qdo
