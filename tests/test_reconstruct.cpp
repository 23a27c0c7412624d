// `qdo reconstruct` and the camera as built (reconstruct.hpp): tiles blend
// with weights summing to 1 (a pointwise decoder tiles exactly; the Wiener decoder within a stated
// tolerance of a whole-image one), the command's cube is the run's Wiener decoder's estimate of the
// capture (the decoder `qdo eval` builds), crops, darks and several frames act as stated, the
// spectra are the cube's, `qdo eval --psf / --design` evaluates through the camera as built and
// says so, and bad input is refused (exit 2) naming the file or argument. Doctest suite
// "reconstruct"; the network's fine-tune for a measured PSF is in tests/net (suite "net").
#include <nlohmann/json.hpp>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>
#include <memory>
#include <tuple>

#include "commands_common.hpp"
#include "reconstruct_common.hpp"
#include "common.hpp"
#include "qdo/decode/decoder_registry.hpp"
#include "qdo/decode/tiled.hpp"
#include "qdo/physics/demosaic_reference.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/io.hpp"
#include "qdo/physics/optics.hpp"
#include "qdo/physics/psf_source.hpp"
#include "qdo/physics/raw_reference.hpp"
#include "qdo/asbuilt/reconstruct.hpp"
#include "qdo/design/run_folder.hpp"
#include "qdo/physics/simulator.hpp"
#include "qdo/decode/wiener.hpp"

using namespace qdo;
using namespace qdo::test;
using namespace qdo::test::commands_suite;
using namespace qdo::test::reconstruct_suite;
namespace fs = std::filesystem;
using nlohmann::json;

namespace {

// A pointwise linear decoder (bands x 3 matrix applied to every pixel): any tiling of it must give
// the untiled estimate exactly, since the blending weights sum to 1.
class PointwiseDecoder final : public Decoder {
 public:
  explicit PointwiseDecoder(std::size_t bands) : bands_(bands) {}
  RealStack decode(const RealStack& y) const override {
    RealStack x(bands_, y.rows, y.cols, 0.0);
    for (std::size_t b = 0; b < bands_; ++b)
      for (std::size_t c = 0; c < 3; ++c)
        for (std::size_t i = 0; i < y.plane_size(); ++i) x.plane(b)[i] += (0.1 * double(b + 1) - 0.07 * double(c)) * y.plane(c)[i];
    return x;
  }
  std::size_t batch() const override { return 3; }
  std::size_t bands() const override { return bands_; }
  std::size_t channels() const override { return 3; }

 private:
  std::size_t bands_;
};

}  // namespace

TEST_SUITE("reconstruct") {
  TEST_CASE("tile starts cover the image and the blending weights sum to 1 at every pixel") {
    for (const auto& [size, tile, overlap] : {std::tuple<std::size_t, std::size_t, std::size_t>{16, 16, 4}, {17, 16, 4}, {100, 16, 4},
                                             {100, 16, 15}, {64, 16, 1}, {40, 32, 8}}) {
      CAPTURE(size);
      CAPTURE(tile);
      CAPTURE(overlap);
      const auto st = tile_starts(size, tile, overlap);
      REQUIRE(!st.empty());
      CHECK(st.front() == 0);
      CHECK(st.back() + tile == size);
      for (std::size_t k = 1; k < st.size(); ++k) {
        CHECK(st[k] > st[k - 1]);
        CHECK(st[k - 1] + tile >= st[k] + overlap);  // neighbours overlap by at least `overlap`
      }
      const auto w = tile_weights(st, tile, size);
      std::vector<double> sum(size, 0.0);
      for (std::size_t k = 0; k < st.size(); ++k)
        for (std::size_t t = 0; t < tile; ++t) {
          CHECK(w[k][t] >= 0);
          sum[st[k] + t] += w[k][t];
        }
      for (double s : sum) CHECK(s == doctest::Approx(1.0).epsilon(1e-12));
    }
    CHECK(input_error_of([] { (void)tile_starts(15, 16, 4); }).find("16") != std::string::npos);
    CHECK(input_error_of([] { (void)tile_starts(40, 16, 16); }).find("--overlap") != std::string::npos);
  }

  TEST_CASE("a pointwise decoder tiles exactly: the blend is a partition of unity") {
    const PointwiseDecoder dec(4);
    const RealStack y = uniform_stack(3, 53, 71, 5, 0, 1);
    const RealStack whole = dec.decode(y);
    std::size_t calls = 0, last_total = 0;
    const RealStack tiled = decode_tiled(dec, y, 16, 5, [&](std::size_t done, std::size_t total) {
      ++calls;
      CHECK(done <= total);
      last_total = total;
    });
    CHECK(max_abs_diff(tiled, whole) < 1e-13);
    CHECK(last_total == tile_starts(53, 16, 5).size() * tile_starts(71, 16, 5).size());
    CHECK(calls == (last_total + 2) / 3);  // one progress call per batch of 3
  }

  TEST_CASE("Wiener tiles with the mirror boundary are as close to the scene as a whole-frame decode; circular tiles ring; "
            "linear tiles beat both") {
    // A capture as a camera makes it: the centre n x n of a larger scene blurred by the PSF, so
    // light from outside the frame lands inside (not circular). Decoded whole (mirror-extended to
    // 2n x 2n, the Wiener decoder on that grid) and in t x t tiles (each mirror-extended to 2t x 2t,
    // blended); the prior is the same one, regridded (regrid_prior). They are not equal: a
    // deconvolution's response to the boundary mismatch spreads over the whole tile (measured here:
    // about 0.58 relative RMS between the two in the interior, 16 px from the frame's border, with
    // this random DOE's asymmetric PSF filling its S x S window). The statement: the mirror tiles'
    // interior error against the scene is within 10 % of the whole-frame decode's, and circular
    // tiles (the model taken literally) are worse than mirror tiles by more than 3 times. Linear
    // tiles (tiled.hpp: the same prior and sigma, the tile the recorded window of a 2t x 2t scene,
    // MaskedWienerDecoder) model the capture as it was made: under a quarter of the mirror tiles'
    // error (measured 0.050 against 0.456).
    const SystemConfig cfg = tiny();
    const std::size_t t = 32, n = 96, big = 160, off = 32, ov = 12;
    Simulator sim(runtime(), cfg, Precision::F64);
    sim.set_heights(smooth_heights(cfg, 3));
    sim.compute_psf();
    const RealStack psf = sim.psf_sensor();
    const Eigen::MatrixXd srf = sensor_response(cfg);
    std::vector<RealStack> train;
    for (unsigned k = 0; k < 8; ++k) train.push_back(smooth_scene(3, t, t, 100 + k));
    const wiener::SpectralPrior prior = wiener::estimate_prior(train, 8);
    const double sigma = 1e-3;
    const RealStack wide = smooth_scene(3, big, big, 7);
    const RealStack y_wide = wiener::simulate_measurement(wide, wiener::psf_to_otf(psf, big, big), srf);
    RealStack y(3, n, n), scene(3, n, n);
    for (std::size_t c = 0; c < 3; ++c)
      for (std::size_t r = 0; r < n; ++r)
        for (std::size_t x = 0; x < n; ++x) {
          y(c, r, x) = y_wide(c, r + off, x + off);
          scene(c, r, x) = wide(c, r + off, x + off);
        }
    const WienerDecoder whole(wiener::psf_to_otf(psf, 2 * n, 2 * n), srf, regrid_prior(prior, 2 * n, 2 * n), sigma);
    const WienerDecoder tile2(wiener::psf_to_otf(psf, 2 * t, 2 * t), srf, regrid_prior(prior, 2 * t, 2 * t), sigma);
    const WienerDecoder tile1(wiener::psf_to_otf(psf, t, t), srf, prior, sigma);
    const RealStack a = decode_tiled(whole, y, n, 0, {}, TileBoundary::Mirror);
    const RealStack b = decode_tiled(tile2, y, t, ov, {}, TileBoundary::Mirror);
    const RealStack c = decode_tiled(tile1, y, t, ov, {}, TileBoundary::Circular);
    const std::unique_ptr<Decoder> lin = linear_tile_wiener(psf, srf, prior, sigma, t);
    const RealStack l = decode_tiled(*lin, y, t, ov, {}, TileBoundary::Linear);
    auto rel_rms = [&](const RealStack& u, const RealStack& v) {
      double d2 = 0, s2 = 0;
      for (std::size_t p = 0; p < 3; ++p)
        for (std::size_t r = 16; r < n - 16; ++r)
          for (std::size_t x = 16; x < n - 16; ++x) {
            d2 += std::pow(u(p, r, x) - v(p, r, x), 2);
            s2 += std::pow(v(p, r, x), 2);
          }
      return std::sqrt(d2 / s2);
    };
    const double tiled_vs_whole = rel_rms(b, a), whole_err = rel_rms(a, scene), tiled_err = rel_rms(b, scene), circ_err = rel_rms(c, scene);
    const double lin_err = rel_rms(l, scene);
    MESSAGE("interior relative RMS: mirror tiles vs whole " << tiled_vs_whole << "; against the scene: whole " << whole_err
            << ", mirror tiles " << tiled_err << ", circular tiles " << circ_err << ", linear tiles " << lin_err);
    CHECK(tiled_vs_whole > 0);
    CHECK(tiled_err < 1.1 * whole_err);
    CHECK(circ_err > 3 * tiled_err);
    CHECK(lin_err < 0.25 * tiled_err);
  }

  TEST_CASE("qdo reconstruct --boundary linear: the linear boundary's Wiener decoder on the capture's tiles; its solver recorded") {
    const SharedRun& s = shared_run();
    REQUIRE(s.result.code == 0);
    const auto dir = temp_dir("recon_linear");
    const std::size_t S = tiny().sensor_size_px(), rows = S + S / 2, cols = 2 * S;
    // A capture larger than a tile (2 x 3 tiles with the default overlap S/4): through the run's
    // PSF, linearly (the centre of a larger scene's circular capture), 16-bit.
    const RealStack wide = smooth_scene(3, rows + S, cols + S, 12);
    const RealStack y_wide = camera_image(s.dir, wide);
    RealStack dn(3, rows, cols);
    for (std::size_t c = 0; c < 3; ++c)
      for (std::size_t r = 0; r < rows; ++r)
        for (std::size_t x = 0; x < cols; ++x) dn(c, r, x) = y_wide(c, r + S / 2, x + S / 2);
    dn = to_dn(dn);
    write_png16_rgb((dir / "cap.png").string(), dn);
    const Run r = qdo_run("reconstruct --run " + s.dir.string() + " --capture " + (dir / "cap.png").string() + " --boundary linear --out " +
                          (dir / "lin").string());
    CAPTURE(r.out);
    REQUIRE(r.code == 0);
    const RealStack cube = read_cube_h5(dir / "lin" / "cube.h5");
    RealStack y = dn;
    for (double& v : y.data) v /= 65535.0;
    RealStack expect = decode_tiled(*run_decoder(s.dir, TileBoundary::Linear), y, S, S / 4, {}, TileBoundary::Linear);
    for (double& v : expect.data) v = std::clamp(v, 0.0, 1.0);
    // The run's PSF simulated again in float32 against its psf.h5, each solve stopped at a relative
    // residual of 1e-5: the same estimate to 1e-4 of full scale.
    CHECK(max_abs_diff(cube, expect) < 1e-4);
    const json j = read_json(dir / "lin" / "reconstruct.json");
    CHECK(j.at("boundary") == "linear");
    const std::size_t tiles = tile_starts(rows, S, S / 4).size() * tile_starts(cols, S, S / 4).size();
    CHECK(tiles == 6);
    CHECK(j.at("tiles") == tiles);
    const json& solver = j.at("boundary_solver");
    CHECK(solver.at("tiles") == tiles);
    CHECK(solver.at("converged") == true);
    CHECK(solver.at("worst_relative_residual").get<double>() <= 1e-5);
    CHECK(solver.at("max_iterations").get<int>() >= 1);
  }

  TEST_CASE("qdo reconstruct of an RGB capture equals the run's Wiener decoder on it; crop, darks, frames and spectra as stated") {
    const SharedRun& s = shared_run();
    REQUIRE(s.result.code == 0);
    const auto dir = temp_dir("recon_cli");
    const std::size_t S = tiny().sensor_size_px();
    // One tile: the capture of a scene through the run's PSF, 16-bit.
    const RealStack scene = smooth_scene(3, S, S, 11);
    const RealStack dn = to_dn(camera_image(s.dir, scene));
    write_png16_rgb((dir / "cap.png").string(), dn);
    const Run r = qdo_run("reconstruct --run " + s.dir.string() + " --capture " + (dir / "cap.png").string() +
                          " --boundary circular --points '3,4;10,12' --boxes '2,2,5,6' --out " + (dir / "one").string());
    CAPTURE(r.out);
    REQUIRE(r.code == 0);
    const RealStack cube = read_cube_h5(dir / "one" / "cube.h5");
    REQUIRE(cube.planes == 3);
    REQUIRE(cube.rows == S);
    REQUIRE(cube.cols == S);
    RealStack y = dn;
    for (double& v : y.data) v /= 65535.0;
    RealStack expect = run_decoder(s.dir)->decode(y);
    for (double& v : expect.data) v = std::clamp(v, 0.0, 1.0);
    CHECK(max_abs_diff(cube, expect) < 1e-6);  // the run's PSF simulated again in float32 against its psf.h5
    const H5Dataset wl = h5_read((dir / "one" / "cube.h5").string(), "/wavelengths_nm");
    CHECK(wl.data == tiny().wavelengths_nm());
    CHECK(fs::exists(dir / "one" / "srgb.png"));
    CHECK(fs::exists(dir / "one" / "spectra.png"));
    // spectra.csv: the cube at the points, the mean over the box.
    const CsvTable sp = read_csv((dir / "one" / "spectra.csv").string());
    REQUIRE(sp.header.size() == 4);
    CHECK(sp.header[1] == "point 3,4");
    CHECK(sp.header[3] == "box 2,2,5,6");
    for (std::size_t b = 0; b < 3; ++b) {
      CHECK(sp.columns[1][b] == doctest::Approx(cube(b, 3, 4)).epsilon(1e-7));
      CHECK(sp.columns[2][b] == doctest::Approx(cube(b, 10, 12)).epsilon(1e-7));
      double m = 0;
      for (std::size_t yy = 2; yy < 7; ++yy)
        for (std::size_t xx = 2; xx < 8; ++xx) m += cube(b, yy, xx) / 30.0;
      CHECK(sp.columns[3][b] == doctest::Approx(m).epsilon(1e-7));
    }
    const json j = read_json(dir / "one" / "reconstruct.json");
    CHECK(j.at("tiles") == 1);
    CHECK(j.at("psf").get<std::string>().find("the run's design") != std::string::npos);
    // The same capture as a 16-bit TIFF gives the same cube.
    write_tiff16((dir / "cap.tif").string(), dn);
    const Run rt = qdo_run("reconstruct --run " + s.dir.string() + " --capture " + (dir / "cap.tif").string() +
                           " --boundary circular --out " + (dir / "one_tif").string());
    CAPTURE(rt.out);
    REQUIRE(rt.code == 0);
    CHECK(read_cube_h5(dir / "one_tif" / "cube.h5").data == cube.data);

    // Larger than a tile: tiled with progress lines; a crop of it equals the cropped capture.
    const RealStack big = to_dn(camera_image(s.dir, smooth_scene(3, 40, 36, 12)));
    write_png16_rgb((dir / "big.png").string(), big);
    const Run rb = qdo_run("reconstruct --run " + s.dir.string() + " --capture " + (dir / "big.png").string() + " --out " + (dir / "big").string());
    CAPTURE(rb.out);
    REQUIRE(rb.code == 0);
    // Progress after each batch of tiles (the linear boundary's decoder solves a batch on threads).
    const std::string all_tiles = std::to_string(tile_starts(40, S, S / 4).size() * tile_starts(36, S, S / 4).size());
    CHECK(rb.out.find("[reconstruct] tile " + all_tiles + "/" + all_tiles) != std::string::npos);
    const RealStack cb = read_cube_h5(dir / "big" / "cube.h5");
    CHECK(cb.rows == 40);
    CHECK(cb.cols == 36);
    CHECK(read_json(dir / "big" / "reconstruct.json").at("boundary") == "linear");  // the Wiener decoder's default
    CHECK(read_json(dir / "big" / "reconstruct.json").at("tiles").get<int>() == int(tile_starts(40, S, S / 4).size() * tile_starts(36, S, S / 4).size()));
    RealStack cropped(3, 20, 18);
    for (std::size_t c = 0; c < 3; ++c)
      for (std::size_t yy = 0; yy < 20; ++yy)
        for (std::size_t xx = 0; xx < 18; ++xx) cropped(c, yy, xx) = big(c, 2 + yy, 3 + xx);
    write_png16_rgb((dir / "cropped.png").string(), cropped);
    const Run rc = qdo_run("reconstruct --run " + s.dir.string() + " --capture " + (dir / "big.png").string() +
                           " --crop 2,3,20,18 --out " + (dir / "crop").string());
    const Run rc2 = qdo_run("reconstruct --run " + s.dir.string() + " --capture " + (dir / "cropped.png").string() + " --out " +
                            (dir / "crop2").string());
    REQUIRE(rc.code == 0);
    REQUIRE(rc2.code == 0);
    CHECK(max_abs_diff(read_cube_h5(dir / "crop" / "cube.h5"), read_cube_h5(dir / "crop2" / "cube.h5")) == 0);

    // Darks: captures 1000 DN above the first, two frames of it and a dark folder at 1000 DN give
    // the first reconstruction exactly.
    fs::create_directories(dir / "darks");
    write_png16_rgb((dir / "darks" / "d1.png").string(), RealStack(3, S, S, 999.0));
    write_png16_rgb((dir / "darks" / "d2.png").string(), RealStack(3, S, S, 1001.0));
    write_png16_rgb((dir / "cap_a.png").string(), to_dn(camera_image(s.dir, scene), 1000));
    write_png16_rgb((dir / "cap_b.png").string(), to_dn(camera_image(s.dir, scene), 1000));
    const Run rd = qdo_run("reconstruct --run " + s.dir.string() + " --capture " + (dir / "cap_a.png").string() + " --capture " +
                           (dir / "cap_b.png").string() + " --darks " + (dir / "darks").string() + " --boundary circular --out " + (dir / "dark").string());
    CAPTURE(rd.out);
    REQUIRE(rd.code == 0);
    CHECK(max_abs_diff(read_cube_h5(dir / "dark" / "cube.h5"), cube) < 1e-12);
    CHECK(read_json(dir / "dark" / "reconstruct.json").at("darks").size() == 2);

    // Exposure: percentile:100:0.5 scales the brightest value to 0.5.
    const Run re = qdo_run("reconstruct --run " + s.dir.string() + " --capture " + (dir / "cap.png").string() +
                           " --exposure percentile:100:0.5 --out " + (dir / "exp").string());
    REQUIRE(re.code == 0);
    const double maxv = *std::max_element(y.data.begin(), y.data.end());
    CHECK(read_json(dir / "exp" / "reconstruct.json").at("exposure_factor").get<double>() == doctest::Approx(0.5 / maxv).epsilon(1e-12));
    fs::remove_all(dir);
  }

  TEST_CASE("qdo reconstruct refuses bad input before any work, naming the file or argument (exit 2)") {
    const SharedRun& s = shared_run();
    REQUIRE(s.result.code == 0);
    const auto dir = temp_dir("recon_bad");
    const std::size_t S = tiny().sensor_size_px();
    write_png16_rgb((dir / "a.png").string(), RealStack(3, S, S, 100.0));
    write_png16_rgb((dir / "b.png").string(), RealStack(3, S + 2, S, 100.0));
    write_png16_rgb((dir / "small.png").string(), RealStack(3, S - 1, S, 100.0));
    write_png16_gray((dir / "gray.png").string(), Map2D(S, S, 100.0));
    const std::string base = "reconstruct --run " + s.dir.string() + " ";
    auto refused = [&](const std::string& args, const std::string& named, const std::string& out) {
      const Run r = qdo_run(base + args + " --out " + (dir / out).string());
      CAPTURE(args);
      CAPTURE(r.out);
      CHECK(r.code == 2);
      CHECK(r.out.find(named) != std::string::npos);
      CHECK(!fs::exists(dir / out / "cube.h5"));
    };
    refused("--capture " + (dir / "a.png").string() + " --capture " + (dir / "b.png").string(), "b.png", "o1");
    refused("--capture " + (dir / "gray.png").string(), "gray.png", "o2");
    refused("--capture " + (dir / "small.png").string(), "small.png", "o3");
    refused("--capture " + (dir / "a.png").string() + " --points '3,4;" + std::to_string(S) + ",0'", "--points", "o4");
    refused("--capture " + (dir / "a.png").string() + " --boxes 10,10,8,2", "--boxes", "o5");
    refused("--capture " + (dir / "a.png").string() + " --exposure percentile:0:1", "--exposure", "o6");
    refused("--capture " + (dir / "a.png").string() + " --crop 0,0,8,8", "--crop", "o7");
    refused("--capture " + (dir / "missing.png").string(), "missing.png", "o8");
    refused("--capture " + (dir / "a.png").string() + " --boundary wrap", "--boundary", "o11");
    refused("--capture " + (dir / "a.png").string() + " --noise-sigma 0", "--noise-sigma", "o12");  // the linear boundary needs sigma > 0
    // A PSF stack for another sensor grid (4 bands) and a design for another N.
    const SystemConfig other = tiny_config(32, 4);
    write_psf((dir / "psf4.h5").string(), RealStack(4, S, S, 1.0 / double(S * S)), other.wavelengths_nm(), other.sensor_pitch_m);
    refused("--capture " + (dir / "a.png").string() + " --psf " + (dir / "psf4.h5").string(), "psf4.h5", "o9");
    Design d48;
    d48.height_m = Map2D(48, 48, 0.0);
    d48.pitch_m = tiny().pitch_m;
    write_design((dir / "d48.h5").string(), d48);
    refused("--capture " + (dir / "a.png").string() + " --design " + (dir / "d48.h5").string(), "d48.h5", "o10");
    // A code value above the white level of a 12-bit sensor is named, with the pixel.
    SystemConfig c12 = tiny();
    c12.bit_depth = 12;
    CHECK(input_error_of([&] {
            CaptureOptions o;
            o.captures = {(dir / "hot.png").string()};
            RealStack img(3, S, S, 100.0);
            img(1, 2, 3) = 5000;
            write_png16_rgb(o.captures[0], img);
            (void)read_captures(c12, o);
          }).find("hot.png': code value 5000 at row 2, column 3") != std::string::npos);
    fs::remove_all(dir);
  }

  TEST_CASE("saturated, empty and clipped captures: refused when nothing can be reconstructed, noted when part is clipped") {
    const SharedRun& s = shared_run();
    REQUIRE(s.result.code == 0);
    const auto dir = temp_dir("recon_levels");
    const std::size_t S = tiny().sensor_size_px();
    SystemConfig c12 = tiny();
    c12.bit_depth = 12;
    c12.black_level_dn = 64;
    auto read = [&](const RealStack& img, const std::string& name, const std::string& darks = "") {
      CaptureOptions o;
      o.captures = {(dir / name).string()};
      o.darks_dir = darks;
      write_png16_rgb(o.captures[0], img);
      return read_captures(c12, o);
    };
    RealStack scene(3, S, S, 1000.0);
    for (std::size_t i = 0; i < scene.data.size(); ++i) scene.data[i] += double(i % 97);
    // Every value at the white level: overexposed, refused naming the file.
    CHECK(input_error_of([&] { read(RealStack(3, S, S, 4095.0), "white.png"); }).find("white.png': 100 % of the capture values") !=
          std::string::npos);
    // Every value at the black level (or all zero): no signal, refused.
    CHECK(input_error_of([&] { read(RealStack(3, S, S, 64.0), "black.png"); }).find("black.png': no signal") != std::string::npos);
    CHECK(input_error_of([&] { read(RealStack(3, S, S, 0.0), "zero.png"); }).find("no signal") != std::string::npos);
    // The lens cap on: the black level plus read noise (sigma 5 DN, seeded), nothing else.
    RealStack cap(3, S, S);
    std::mt19937 rng(5);
    std::normal_distribution<double> noise(64.0, 5.0);
    for (double& v : cap.data) v = std::max(0.0, std::round(noise(rng)));
    CHECK(input_error_of([&] { read(cap, "cap.png"); }).find("within the noise") != std::string::npos);
    // The darks given as the capture: no signal above the mean dark.
    fs::create_directories(dir / "darks");
    write_png16_rgb((dir / "darks" / "d0.PNG").string(), scene);  // upper-case extension: read, as calibrate reads it
    CHECK(input_error_of([&] { read(scene, "same.png", (dir / "darks").string()); }).find("above the mean dark") != std::string::npos);
    // Part clipped: read, with a note that counts the values.
    RealStack part = scene;
    for (std::size_t i = 0; i < 30; ++i) part.data[i] = 4095;
    const CaptureFiles f = read(part, "part.png");
    CHECK(f.saturated == 30);
    REQUIRE(f.notes.size() == 1);
    CHECK(f.notes[0].find("30 capture values") != std::string::npos);
    CHECK(read(scene, "fine.png").notes.empty());
    // Through the command: the note in stdout and reconstruct.json. The shared run's configuration
    // has no bit depth (white 65535).
    RealStack sat(3, S, S, 20000.0);
    for (std::size_t i = 0; i < sat.data.size(); ++i) sat.data[i] += double((i * 37) % 1000);
    for (std::size_t i = 0; i < 10; ++i) sat.data[i * 7] = 65535;
    write_png16_rgb((dir / "sat.png").string(), sat);
    const Run r = qdo_run("reconstruct --run " + s.dir.string() + " --capture " + (dir / "sat.png").string() + " --out " + (dir / "o").string());
    CAPTURE(r.out);
    REQUIRE(r.code == 0);
    CHECK(r.out.find("note: 10 capture values") != std::string::npos);
    CHECK(read_json(dir / "o" / "reconstruct.json").at("notes").size() == 1);
    // --truth-border leaving less than the SSIM window: refused before any work, naming the option.
    write_cube((dir / "truth.h5").string(), RealStack(tiny().bands, S, S, 0.5), tiny().wavelengths_nm());
    const Run b = qdo_run("reconstruct --run " + s.dir.string() + " --capture " + (dir / "sat.png").string() + " --truth " +
                          (dir / "truth.h5").string() + " --truth-border " + std::to_string(S / 2 - 1) + " --out " + (dir / "ob").string());
    CHECK(b.code == 2);
    CHECK_MESSAGE(b.out.find("--truth-border") != std::string::npos, b.out);
    CHECK(!fs::exists(dir / "ob" / "cube.h5"));
    fs::remove_all(dir);
  }

  TEST_CASE("a mosaic whose green sites sit on the other diagonal is refused, naming the file; the configured one passes") {
    // A colourful scene through RGGB: R at (0,0), G at (0,1) and (1,0), B at (1,1).
    const RealStack scene = smooth_scene(3, 32, 32, 4);
    RealStack raw(1, 32, 32);
    for (std::size_t y = 0; y < 32; ++y)
      for (std::size_t x = 0; x < 32; ++x) raw(0, y, x) = scene(std::size_t(cfa_channel(Cfa::RGGB, y, x)), y, x);
    CHECK_NOTHROW(check_mosaic_phase(raw, Cfa::RGGB, "f.png"));
    CHECK_NOTHROW(check_mosaic_phase(raw, Cfa::BGGR, "f.png"));  // R/B swapped: not visible without the scene
    const std::string e = input_error_of([&] { check_mosaic_phase(raw, Cfa::GRBG, "f.png"); });
    CHECK(e.find("f.png") != std::string::npos);
    CHECK(e.find("rggb or bggr") != std::string::npos);
    // A grey scene decides nothing.
    RealStack grey(1, 32, 32);
    for (std::size_t y = 0; y < 32; ++y)
      for (std::size_t x = 0; x < 32; ++x) grey(0, y, x) = scene(1, y, x);
    CHECK_NOTHROW(check_mosaic_phase(grey, Cfa::GRBG, "f.png"));
  }

  TEST_CASE("qdo eval --psf / --design evaluates the run's Wiener decoder refit for the camera as built and names it in metrics.json") {
    const SharedRun& s = shared_run();
    REQUIRE(s.result.code == 0);
    const auto dir = temp_dir("recon_eval");
    const std::string base = "eval " + s.dir.string() + " --synthetic-scenes 2 --renders 0 --out ";
    const Run own = qdo_run(base + (dir / "own").string());
    REQUIRE(own.code == 0);
    // A "measured" stack: the design's full-precision PSF written as a file; a "fitted" design:
    // design_full.h5 itself. Both differ from the run's quantized DOE.
    {
      Simulator sim(runtime(), tiny(), Precision::F32);
      sim.set_heights(read_design((s.dir / "design_full.h5").string()).height_m);
      sim.compute_psf();
      write_psf((dir / "measured.h5").string(), sim.psf_sensor(), tiny().wavelengths_nm(), tiny().sensor_pitch_m);
    }
    const Run mp = qdo_run(base + (dir / "psf").string() + " --psf " + (dir / "measured.h5").string());
    CAPTURE(mp.out);
    REQUIRE(mp.code == 0);
    const Run md = qdo_run(base + (dir / "design").string() + " --design " + (s.dir / "design_full.h5").string());
    CAPTURE(md.out);
    REQUIRE(md.code == 0);
    const json jo = read_json(dir / "own" / "metrics.json"), jp = read_json(dir / "psf" / "metrics.json"),
               jd = read_json(dir / "design" / "metrics.json");
    CHECK(jo.at("psf").get<std::string>().find("the run's design") != std::string::npos);
    CHECK(jp.at("psf").get<std::string>().find("measured.h5") != std::string::npos);
    CHECK(jd.at("psf").get<std::string>().find("design_full.h5") != std::string::npos);
    const double po = jo.at("mean").at("psnr_db").get<double>(), pp = jp.at("mean").at("psnr_db").get<double>(),
                 pd = jd.at("mean").at("psnr_db").get<double>();
    CHECK(po != pp);  // another PSF, another refit
    // The same camera through a file and through the design it was simulated from: equal metrics
    // (the PSF the same float32 stack).
    CHECK(pp == doctest::Approx(pd).epsilon(1e-9));
    // A PSF file for another grid, a design for another N: exit 2 naming the file.
    write_psf((dir / "psf4.h5").string(), RealStack(4, 16, 16, 1.0 / 256), tiny_config(32, 4).wavelengths_nm(), tiny().sensor_pitch_m);
    const Run bad = qdo_run(base + (dir / "bad").string() + " --psf " + (dir / "psf4.h5").string());
    CHECK(bad.code == 2);
    CHECK(bad.out.find("psf4.h5") != std::string::npos);
    Design d48;
    d48.height_m = Map2D(48, 48, 0.0);
    d48.pitch_m = tiny().pitch_m;
    write_design((dir / "d48.h5").string(), d48);
    const Run bad2 = qdo_run(base + (dir / "bad2").string() + " --design " + (dir / "d48.h5").string());
    CHECK(bad2.code == 2);
    CHECK(bad2.out.find("d48.h5") != std::string::npos);
    const Run both = qdo_run(base + (dir / "both").string() + " --design " + (s.dir / "design_full.h5").string() + " --psf " +
                             (dir / "measured.h5").string());
    CHECK(both.code == 2);
    fs::remove_all(dir);
  }
}
