// Tiled decoding (tiled.hpp): tile starts and blending weights, the mirror boundary, and the
// prior regridded for it.
#include "qdo/decode/tiled.hpp"

#include <algorithm>
#include <cmath>
#include <utility>

#include "qdo/data/datasets.hpp"
#include "qdo/decode/wiener_masked.hpp"
#include "qdo/runtime/error.hpp"

namespace qdo {

std::vector<std::size_t> tile_starts(std::size_t size, std::size_t tile, std::size_t overlap) {
  if (tile == 0 || size < tile)
    reject("image size", size, "at least the decoder's tile of " + to_str(tile) + " px (the grid it was trained on) on each side");
  if (overlap >= tile) reject("--overlap", overlap, "below the tile size " + to_str(tile) + " px");
  std::vector<std::size_t> s;
  const std::size_t stride = tile - overlap;
  for (std::size_t a = 0;; a += stride) {
    if (a + tile >= size) {
      s.push_back(size - tile);
      break;
    }
    s.push_back(a);
  }
  return s;
}

std::vector<std::vector<double>> tile_weights(const std::vector<std::size_t>& starts, std::size_t tile, std::size_t size) {
  const double pi = 3.14159265358979323846;
  std::vector<std::vector<double>> w(starts.size(), std::vector<double>(tile, 1.0));
  for (std::size_t k = 0; k < starts.size(); ++k) {
    // The overlap with the previous and the next tile; a ramp sin²(π/2 (t + 1/2) / L) across it.
    const std::size_t left = k > 0 && starts[k - 1] + tile > starts[k] ? starts[k - 1] + tile - starts[k] : 0;
    const std::size_t right = k + 1 < starts.size() && starts[k] + tile > starts[k + 1] ? starts[k] + tile - starts[k + 1] : 0;
    for (std::size_t t = 0; t < tile; ++t) {
      if (left > 0 && t < left) w[k][t] *= std::pow(std::sin(pi / 2 * (double(t) + 0.5) / double(left)), 2);
      if (right > 0 && tile - 1 - t < right) w[k][t] *= std::pow(std::sin(pi / 2 * (double(tile - 1 - t) + 0.5) / double(right)), 2);
    }
  }
  std::vector<double> sum(size, 0.0);
  for (std::size_t k = 0; k < starts.size(); ++k)
    for (std::size_t t = 0; t < tile; ++t) sum[starts[k] + t] += w[k][t];
  for (std::size_t k = 0; k < starts.size(); ++k)
    for (std::size_t t = 0; t < tile; ++t) w[k][t] /= sum[starts[k] + t];
  return w;
}

TileBoundary tile_boundary_from_string(const std::string& s, const std::string& argument) {
  if (s == "circular") return TileBoundary::Circular;
  if (s == "mirror") return TileBoundary::Mirror;
  if (s == "linear") return TileBoundary::Linear;
  reject(argument, s, "circular, mirror or linear");
}

std::string to_string(TileBoundary b) {
  return b == TileBoundary::Mirror ? "mirror" : b == TileBoundary::Linear ? "linear" : "circular";
}

namespace {

// The Linear boundary's geometry: an h x w image recorded at (at, at) of a rows x cols grid.
void check_psf_reach(const RealStack& psf, std::size_t h, std::size_t w, std::size_t rows, std::size_t cols) {
  // The PSF reaches P/2 from its axis: the window [P/2, P/2 + h) sees sources in [0, h + P).
  if (psf.rows > rows - h || psf.cols > cols - w)
    reject("PSF", to_str(psf.rows) + " x " + to_str(psf.cols),
           "at most " + to_str(rows - h) + " x " + to_str(cols - w) + " px for the linear boundary's grid (it reaches P/2 from its axis)");
}
Map2D window_mask(std::size_t rows, std::size_t cols, std::size_t at, std::size_t h, std::size_t w) {
  Map2D m(rows, cols, 0.0);
  for (std::size_t r = at; r < at + h; ++r)
    for (std::size_t c = at; c < at + w; ++c) m(r, c) = 1.0;
  return m;
}
// x (planes x h x w) placed at (at, at) on a rows x cols grid of zeros.
RealStack embed(const RealStack& x, std::size_t rows, std::size_t cols, std::size_t at) {
  RealStack out(x.planes, rows, cols, 0.0);
  for (std::size_t p = 0; p < x.planes; ++p)
    for (std::size_t r = 0; r < x.rows; ++r)
      for (std::size_t c = 0; c < x.cols; ++c) out(p, at + r, at + c) = x(p, r, c);
  return out;
}

}  // namespace

std::shared_ptr<const Encoder> linear_tile_encoder(const RealStack& psf, const Eigen::MatrixXd& srf, std::size_t tile) {
  check_psf_reach(psf, tile, tile, 2 * tile, 2 * tile);
  return std::make_shared<const MaskedEncoder>(std::make_shared<const DoeEncoder>(wiener::psf_to_otf(psf, 2 * tile, 2 * tile), srf),
                                               window_mask(2 * tile, 2 * tile, tile / 2, tile, tile));
}

std::unique_ptr<Decoder> linear_tile_wiener(const RealStack& psf, const Eigen::MatrixXd& srf, const wiener::SpectralPrior& prior,
                                            double noise_sigma, std::size_t tile) {
  check_psf_reach(psf, tile, tile, 2 * tile, 2 * tile);
  return std::make_unique<MaskedWienerDecoder>(wiener::psf_to_otf(psf, 2 * tile, 2 * tile), srf, regrid_prior(prior, 2 * tile, 2 * tile),
                                               window_mask(2 * tile, 2 * tile, tile / 2, tile, tile), noise_sigma);
}

RealStack wiener_decode_linear(const RealStack& y, const RealStack& psf, const Eigen::MatrixXd& srf, const wiener::SpectralPrior& prior,
                               double noise_sigma) {
  const std::size_t p = std::max(psf.rows, psf.cols), rows = y.rows + p, cols = y.cols + p, at = p / 2;
  check_psf_reach(psf, y.rows, y.cols, rows, cols);
  const MaskedWienerDecoder dec(wiener::psf_to_otf(psf, rows, cols), srf, regrid_prior(prior, rows, cols),
                                window_mask(rows, cols, at, y.rows, y.cols), noise_sigma);
  return crop_window(dec.decode(embed(y, rows, cols, at)), at, at, y.rows, y.cols);
}

wiener::SpectralPrior regrid_prior(const wiener::SpectralPrior& p, std::size_t rows, std::size_t cols) {
  p.validate();
  wiener::SpectralPrior q = p;
  q.rows = rows;
  q.cols = cols;
  const double scale = double(rows * cols) / double(p.rows * p.cols);
  for (std::size_t i = 0; i < p.bands * p.bands; ++i) q.cov[i] *= scale;  // bin 0 = DC
  q.validate();
  return q;
}

namespace {

// A tile as the decoder takes it: itself, its whole-sample mirror extension to 2 tile x 2 tile, or
// (Linear) placed at tile/2 on a 2 tile x 2 tile grid of zeros (the unrecorded pixels).
RealStack tile_input(const RealStack& t, std::size_t tile, TileBoundary boundary) {
  if (boundary == TileBoundary::Circular) return t;
  const std::size_t e = 2 * tile;
  if (boundary == TileBoundary::Linear) return embed(t, e, e, tile / 2);
  RealStack x(t.planes, e, e);
  for (std::size_t ch = 0; ch < t.planes; ++ch)
    for (std::size_t r = 0; r < e; ++r)
      for (std::size_t c = 0; c < e; ++c) x(ch, r, c) = t(ch, r < tile ? r : e - 1 - r, c < tile ? c : e - 1 - c);
  return x;
}

// The tile x tile window of y at (row, col).
RealStack tile_at(const RealStack& y, std::size_t row, std::size_t col, std::size_t tile) { return crop_patch(y, {row, col}, tile); }

}  // namespace

std::vector<RealStack> decoder_tiles(const RealStack& y, std::size_t tile, std::size_t overlap, TileBoundary boundary) {
  std::vector<RealStack> out;
  if (y.rows == tile && y.cols == tile) {
    out.push_back(tile_input(y, tile, boundary));
    return out;
  }
  for (std::size_t r : tile_starts(y.rows, tile, overlap))
    for (std::size_t c : tile_starts(y.cols, tile, overlap)) out.push_back(tile_input(tile_at(y, r, c, tile), tile, boundary));
  return out;
}

RealStack decode_tiled(const Decoder& dec, const RealStack& y, std::size_t tile, std::size_t overlap,
                       const std::function<void(std::size_t, std::size_t)>& progress, TileBoundary boundary) {
  if (y.planes != dec.channels()) reject("sensor image planes", y.planes, "the decoder's " + to_str(dec.channels()) + " channels");
  // The part of the decoder's grid that is the tile: all of it (Circular), the first tile x tile
  // (Mirror) or the window at tile/2 (Linear).
  const std::size_t keep_at = boundary == TileBoundary::Linear ? tile / 2 : 0;
  auto input = [&](const RealStack& t) { return tile_input(t, tile, boundary); };
  auto output = [&](const RealStack& x) { return boundary == TileBoundary::Circular ? x : crop_window(x, keep_at, keep_at, tile, tile); };
  if (y.rows == tile && y.cols == tile) {
    RealStack x = output(dec.decode(input(y)));
    if (progress) progress(1, 1);
    return x;
  }
  const auto rs = tile_starts(y.rows, tile, overlap), cs = tile_starts(y.cols, tile, overlap);
  const auto wr = tile_weights(rs, tile, y.rows), wc = tile_weights(cs, tile, y.cols);
  const std::size_t total = rs.size() * cs.size(), batch = std::max<std::size_t>(1, dec.batch());
  RealStack out(dec.bands(), y.rows, y.cols, 0.0);
  std::vector<std::pair<std::size_t, std::size_t>> pending;
  std::vector<RealStack> ys;
  std::size_t done = 0;
  auto flush = [&] {
    const std::vector<RealStack> xs = dec.decode_batch(ys);
    for (std::size_t k = 0; k < xs.size(); ++k) {
      const auto [i, j] = pending[k];
      const RealStack x = output(xs[k]);
      for (std::size_t b = 0; b < x.planes; ++b)
        for (std::size_t r = 0; r < tile; ++r)
          for (std::size_t c = 0; c < tile; ++c) out(b, rs[i] + r, cs[j] + c) += wr[i][r] * wc[j][c] * x(b, r, c);
    }
    done += xs.size();
    pending.clear();
    ys.clear();
    if (progress) progress(done, total);
  };
  for (std::size_t i = 0; i < rs.size(); ++i)
    for (std::size_t j = 0; j < cs.size(); ++j) {
      ys.push_back(input(tile_at(y, rs[i], cs[j], tile)));
      pending.push_back({i, j});
      if (ys.size() == batch) flush();
    }
  if (!ys.empty()) flush();
  return out;
}

}  // namespace qdo
