// The decoder registry: a DecoderSpec's name (decoder_spec.hpp) -> a factory of a Decoder
// (decoder.hpp). `qdo eval` (evaluate_run, eval.hpp) and `qdo sweep` build every decoder they
// evaluate through it, from the inputs below.
//
// Built in (src/decode/decoder_registry.cpp lists them, one line each; each in its own file):
//   wiener    the Wiener decoder for the PSF stack (decoder_wiener.cpp)
//   resunet   the Res-UNet trained with the optics (decoder_resunet.cpp): a design run trains it
//             (DecoderEntry::train), evaluation decodes with the run's (DecoderInputs::run_network)
//   cg        the conjugate-gradient MAP decoder (CgDecoder, encoders.hpp) of the camera: the PSF
//             camera (DoeEncoder) or DecoderInputs::encoder; parameters tolerance=T (default 1e-6)
//             and max_iterations=N (default 5000) (decoder_cg.cpp)
// Another decoder is one new .cpp: a factory and either a line in the built-in list or, from any
// program (a test, a plugin), register_decoder() / a static DecoderRegistration. Its name can then
// be given wherever a DecoderSpec is parsed (e.g. `qdo eval RUN --decoder-kind NAME:key=value`).
//
// One mechanism for training and evaluation: an entry with a `train` factory is a decoder trained
// with the optics. `qdo design --decoder NAME` (objective network) makes it through
// make_trained_decoder(), trains it with the optics (joint.hpp) and keeps its state in the run
// folder; `qdo eval`, `qdo reconstruct` and `qdo sweep` decode with the run's trained state through
// the entry's `make` (by default the state in inference mode, NetworkImageDecoder).
#pragma once
#include <Eigen/Dense>

#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "qdo/decode/decoder.hpp"
#include "qdo/decode/decoder_spec.hpp"
#include "qdo/decode/network_decoder.hpp"
#include "qdo/runtime/types.hpp"
#include "qdo/decode/wiener.hpp"

namespace qdo {

class Encoder;  // encoders.hpp

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
  // --decoder matched); false for decoders built from the PSF (Wiener, CG). True exactly when
  // `train` is set (register_decoder checks it).
  bool trained = false;
  // The decoder at evaluation. May be left empty for a trained decoder: the registry then decodes
  // with the run's state (DecoderInputs::run_network) in inference mode, 8 images per batch.
  DecoderFactory make;
  // A trained decoder's fresh, trainable state (network_decoder.hpp: train, reconstruct, save, load)
  // from the run's settings (NetworkSettings::spec names this entry); empty for the others.
  NetworkFactory train;
};

// Adds a decoder; InputError when the name is malformed or already registered, when it has neither
// factory, or when `trained` and `train` disagree.
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
// A fresh trained decoder for a design run: the `train` factory of s.spec's entry (InputError
// naming `decoder` when the entry has none, i.e. the decoder is not trained with the optics).
std::unique_ptr<NetworkDecoder> make_trained_decoder(const NetworkSettings& s);

}  // namespace qdo
