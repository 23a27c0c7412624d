// The decoder registry: a DecoderSpec's name (decoder_spec.hpp) -> a factory of a Decoder
// (decoder.hpp). `qdo eval` (evaluate_run, eval.hpp) and `qdo sweep` build every decoder they
// evaluate through it, from the inputs below.
//
// Built in (src/decode/decoder_registry.cpp lists them, one line each; each in its own file):
//   wiener    the Wiener decoder for the PSF stack (decoder_wiener.cpp)
//   resunet   the run's trained network (decoder_resunet.cpp; needs DecoderInputs::run_network)
//   cg        the conjugate-gradient MAP decoder (CgDecoder, encoders.hpp) of the camera: the PSF
//             camera (DoeEncoder) or DecoderInputs::encoder; parameters tolerance=T (default 1e-6)
//             and max_iterations=N (default 5000) (decoder_cg.cpp)
// Another decoder is one new .cpp: a factory and either a line in the built-in list or, from any
// program (a test, a plugin), register_decoder() / a static DecoderRegistration. Its name can then
// be given wherever a DecoderSpec is parsed (e.g. `qdo eval RUN --decoder-kind NAME:key=value`).
#pragma once
#include <Eigen/Dense>

#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "qdo/decode/decoder.hpp"
#include "qdo/decode/decoder_spec.hpp"
#include "qdo/runtime/types.hpp"
#include "qdo/decode/wiener.hpp"

namespace qdo {

class Encoder;         // encoders.hpp
class NetworkDecoder;  // network_decoder.hpp

// What a decoder is built from. Grids: the S x S patch grid of the evaluation (the prior's).
struct DecoderInputs {
  DecoderSpec spec;                        // the decoder asked for (its parameters, for Kind::Named)
  RealStack psf;                           // bands x S x S sensor PSF stack (axis at S/2) the decoder is built for
  Eigen::MatrixXd srf;                     // 3 x bands sensor response (optics.hpp sensor_response)
  std::shared_ptr<const Encoder> encoder;  // a camera that is not a PSF (CASSI); null: the PSF camera (psf, srf)
  wiener::SpectralPrior prior;             // the scene prior on the S x S grid
  double noise_sigma = 0;                  // the measurement noise the decoder assumes (>= 0)
  // The run's trained network (a network run), loaded when called; empty outside a run folder.
  std::function<std::unique_ptr<NetworkDecoder>()> run_network;
};

using DecoderFactory = std::function<std::unique_ptr<Decoder>(const DecoderInputs&)>;

struct DecoderEntry {
  std::string name;     // the spec's name (DecoderSpec::kind_name()): lower-case letters, digits, '-', '_'
  std::string summary;  // one line: what it is, its parameters
  // Trained with the optics, so fixed to the design it was trained for (evaluate_run's rule for
  // --decoder matched); false for decoders built from the PSF (Wiener, CG).
  bool trained = false;
  DecoderFactory make;
};

// Adds a decoder; InputError when the name is malformed, already registered, or the factory empty.
void register_decoder(DecoderEntry entry);
// register_decoder() at static initialisation: `static const DecoderRegistration r{{"toy", ...}};`
// in a file linked into the program (an object file, not an unreferenced static-library member).
struct DecoderRegistration {
  explicit DecoderRegistration(DecoderEntry entry);
};

// Whether `name` is registered (built in or added).
bool decoder_registered(const std::string& name);
// Every registered name: the built-in ones first, then the added ones in the order added.
std::vector<std::string> decoder_names();
// The entry of `name`; InputError naming the known ones for an unknown name.
DecoderEntry decoder_entry(const std::string& name);
// The decoder in.spec names, built from `in` by its factory (InputError as decoder_entry, or the
// factory's own for inputs it cannot use).
std::unique_ptr<Decoder> make_decoder(const DecoderInputs& in);

}  // namespace qdo
