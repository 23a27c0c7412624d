// A decoder over an image larger than its grid: S x S tiles (S the decoder's grid, the prior's and
// the training crops'), overlapping and blended, and how a tile's edges meet the decoder's circular
// model. `qdo reconstruct` decodes captures through it (reconstruct.hpp); any program with a
// Decoder (decoder.hpp) can.
//
//   y:   channels x H x W (the sensor image, row-major planes), H, W >= S
//   out: bands x H x W
#pragma once
#include <cstddef>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "qdo/decode/decoder.hpp"
#include "qdo/decode/encoders.hpp"
#include "qdo/decode/wiener.hpp"
#include "qdo/runtime/types.hpp"

namespace qdo {

// Tiles of `tile` x `tile` over an rows x cols image, neighbours overlapping by at least
// `overlap` pixels: starts 0, tile - overlap, ... and rows - tile last (every pixel covered).
// Requires rows, cols >= tile and overlap < tile (InputError).
std::vector<std::size_t> tile_starts(std::size_t size, std::size_t tile, std::size_t overlap);
// The 1-D blending weights of tiles at `starts` (tile long each) over `size` pixels: a sin² ramp
// across each overlap with a neighbour (flat at the image's edges), normalised so that at every
// pixel the weights of the tiles covering it sum to 1. weights[k][t]: tile k, pixel starts[k] + t.
std::vector<std::vector<double>> tile_weights(const std::vector<std::size_t>& starts, std::size_t tile, std::size_t size);
// How a tile's edges meet the decoder's circular model (a PSF camera's decoder assumes the scene
// repeats: y = circular blur, REFERENCE §3b). A capture is not circular: light from outside a tile
// lands inside it, and a deconvolving decoder (Wiener at small sigma) turns that mismatch into
// ringing over the whole tile.
//   circular  the tile is decoded as it is, on the decoder's tile x tile grid: the model the decoder
//             was built and trained with, exact for captures simulated circularly (`qdo eval`'s
//             patches); the network's only choice (it was trained on circular S x S patches)
//   mirror    the tile is extended by its mirror image to 2 tile x 2 tile (whole-sample symmetric:
//             the extension is continuous across every wrap) and decoded on that grid (dec built
//             for it), the first tile x tile kept: the boundary mismatch shrinks to the PSF's
//             asymmetry
//   linear    the camera's own model: the tile is the recorded centre window of a capture of a
//             scene on a 2 tile x 2 tile grid (the tile at offset tile/2, zeros around it, the
//             unrecorded pixels masked out: MaskedEncoder), so light reaching the tile from
//             outside it is explained by scene outside it, exactly as long as the PSF reaches at
//             most tile/2 from its axis (a PSF of at most tile x tile). The decoder is the MAP
//             estimate under that model by conjugate gradients: the Wiener decoder's objective
//             (the same prior and sigma) by linear_tile_wiener, any encoder's by CgDecoder on
//             linear_tile_encoder; the centre window of its estimate is kept. Slower than mirror
//             (iterations instead of one division per frequency), and the one that matches a real
//             capture.
enum class TileBoundary { Circular, Mirror, Linear };
TileBoundary tile_boundary_from_string(const std::string& s, const std::string& argument = "--boundary");
std::string to_string(TileBoundary b);

// The tiles of y (channels x H x W) as decode_tiled hands them to the decoder, in its order: tile x
// tile (Circular), their mirror extensions to 2 tile x 2 tile (Mirror), or each on a 2 tile x 2 tile
// grid of zeros at offset tile/2 (Linear). For what looks at the
// decoder's inputs before decoding (wiener::gcv_noise_sigma in qdo reconstruct).
std::vector<RealStack> decoder_tiles(const RealStack& y, std::size_t tile, std::size_t overlap, TileBoundary boundary);

// The PSF camera of the Linear boundary on its 2 tile x 2 tile grid: the circular camera of psf
// (bands x P x P, axis at P/2, P <= tile; else InputError naming the PSF's size) and srf (C x bands),
// recording only the window [tile/2, tile/2 + tile)² (MaskedEncoder).
std::shared_ptr<const Encoder> linear_tile_encoder(const RealStack& psf, const Eigen::MatrixXd& srf, std::size_t tile);
// The Wiener decoder of the Linear boundary: the same camera and window, the prior regridded to
// 2 tile x 2 tile (regrid_prior), solved in the measurement space (MaskedWienerDecoder).
// prior: on the tile x tile grid.
std::unique_ptr<Decoder> linear_tile_wiener(const RealStack& psf, const Eigen::MatrixXd& srf, const wiener::SpectralPrior& prior,
                                            double noise_sigma, std::size_t tile);

// The linear boundary on a whole image, without tiles: y (C x H x W) the recorded window of a scene
// (H + P) x (W + P) (P the PSF's size, the window at P/2), the Wiener decoder's objective for that
// scene (MaskedWienerDecoder, the prior regridded from any grid), its centre H x W returned
// (bands x H x W). noise_sigma > 0. Python's qdo.wiener_decode(boundary="linear").
RealStack wiener_decode_linear(const RealStack& y, const RealStack& psf, const Eigen::MatrixXd& srf, const wiener::SpectralPrior& prior,
                               double noise_sigma);

// dec's estimate of y (channels x H x W) on tile x tile tiles (weights: the product of the row and
// column weights above, which sums to 1 at every pixel), decoded dec.batch() at a time;
// progress(done, total) after each batch. Returns bands x H x W. An image of exactly tile x tile
// is one tile. With Mirror and Linear, dec decodes 2 tile x 2 tile images (see TileBoundary).
RealStack decode_tiled(const Decoder& dec, const RealStack& y, std::size_t tile, std::size_t overlap,
                       const std::function<void(std::size_t, std::size_t)>& progress = {},
                       TileBoundary boundary = TileBoundary::Circular);

// The prior on another rows x cols grid: the same bins (their edges do not depend on the grid,
// wiener::radial_bin), the DC bin scaled by the ratio of the grid areas (its scene-mean part
// grows with H·W; wiener.hpp). What the Wiener decoder needs on the mirror boundary's 2S grid.
wiener::SpectralPrior regrid_prior(const wiener::SpectralPrior& p, std::size_t rows, std::size_t cols);

}  // namespace qdo
