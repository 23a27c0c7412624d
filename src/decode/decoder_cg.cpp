// The registry's "cg" (decoder_registry.hpp): the conjugate-gradient MAP decoder (CgDecoder,
// encoders.hpp) of the camera: DecoderInputs::encoder when given (CASSI), else the PSF camera
// as a DoeEncoder (psf_to_otf(psf, prior.rows, prior.cols), srf). Parameters: tolerance=T (the
// relative residual, in (0, 1), default 1e-6) and max_iterations=N (1 to 1000000, default 5000).
#include <cmath>
#include <cstdlib>
#include <memory>

#include "qdo/decode/decoder_registry.hpp"
#include "qdo/decode/encoders.hpp"
#include "qdo/runtime/error.hpp"

namespace qdo {

namespace {
double number(const DecoderSpec& spec, const std::string& key, const std::string& def, double lo, double hi,
              const std::string& allowed) {
  const std::string v = spec.param(key, def);
  char* end = nullptr;
  const double x = std::strtod(v.c_str(), &end);
  if (v.empty() || *end || !std::isfinite(x) || x < lo || x > hi) reject("--decoder cg key '" + key + "'", v, allowed);
  return x;
}
}  // namespace

DecoderEntry cg_decoder_entry() {
  DecoderEntry e;
  e.name = "cg";
  e.summary =
      "the conjugate-gradient MAP decoder of any linear camera under the scene prior; cg:tolerance=T,max_iterations=N";
  e.make = [](const DecoderInputs& in) -> std::unique_ptr<Decoder> {
    for (const auto& kv : in.spec.params)
      if (kv.first != "tolerance" && kv.first != "max_iterations")
        reject("--decoder cg key", kv.first, "tolerance or max_iterations");
    CgOptions o;
    o.tolerance = number(in.spec, "tolerance", "1e-6", 1e-300, 1, "a relative residual in (0, 1]");
    const double it = number(in.spec, "max_iterations", "5000", 1, 1e6, "an integer from 1 to 1000000");
    if (it != std::floor(it))
      reject("--decoder cg key 'max_iterations'", in.spec.param("max_iterations"), "an integer from 1 to 1000000");
    o.max_iterations = static_cast<std::size_t>(it);
    std::shared_ptr<const Encoder> enc = in.encoder;
    if (!enc) enc = std::make_shared<DoeEncoder>(wiener::psf_to_otf(in.psf, in.prior.rows, in.prior.cols), in.srf);
    return std::make_unique<CgDecoder>(std::move(enc), in.prior, in.noise_sigma, o);
  };
  return e;
}

}  // namespace qdo
