// The PSF source seam (include/qdo/physics/psf_source.hpp): the camera takes any PsfSource (the 2-D
// simulator, the radial engine, a fixed stack such as a PSF file) and gives the same images for the
// same stack; `qdo simulate --psf` and `qdo image --psf` with a stack written by `qdo psf` give the
// images of the design that made it; a stack for other bands or another sensor grid is refused
// naming both, before anything is written.
#include <algorithm>
#include <cmath>
#include <fstream>

#include "common.hpp"
#include "qdo/physics/camera.hpp"
#include "qdo/physics/capture_pipeline.hpp"
#include "qdo/data/io.hpp"
#include "qdo/physics/psf_source.hpp"
#include "qdo/design/psf_spec.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/physics/radial.hpp"
#include "qdo/physics/simulator.hpp"

using namespace qdo;
using namespace qdo::test;
namespace fs = std::filesystem;

namespace {

SkipOptions exact() {
  SkipOptions o;
  o.exact = true;
  return o;
}

fs::path write_config(const fs::path& dir, const SystemConfig& c, const std::string& name) {
  const fs::path f = dir / name;
  std::ofstream(f) << config_to_json_text(c) << "\n";
  return f;
}

// A new kind of PSF source, written the way a user adds one (one class, nothing else touched): a
// Gaussian blob of width sigma_px sensor pixels per band, growing with the wavelength, each band
// summing to 1, held on the device by a StackPsfSource it delegates to; its one parameter is sigma,
// whose gradient it takes on the host (dL/dsigma = sum g * dstack/dsigma, by central difference
// of its own closed form).
class GaussianPsfSource final : public PsfSource {
 public:
  GaussianPsfSource(Runtime& rt, const SystemConfig& cfg, Precision p, double sigma_px)
      : sigma_(sigma_px), stack_(rt, cfg, p, blob(cfg, sigma_px), "gaussian blob") {}
  static RealStack blob(const SystemConfig& cfg, double sigma_px) {
    const std::size_t s = cfg.sensor_size_px();
    RealStack st(cfg.bands, s, s);
    for (std::size_t b = 0; b < cfg.bands; ++b) {
      const double w = sigma_px * (1.0 + 0.1 * double(b));
      double sum = 0;
      for (std::size_t y = 0; y < s; ++y)
        for (std::size_t x = 0; x < s; ++x) {
          const double dy = double(y) - double(s / 2), dx = double(x) - double(s / 2);
          sum += st(b, y, x) = std::exp(-(dx * dx + dy * dy) / (2 * w * w));
        }
      for (std::size_t i = 0; i < s * s; ++i) st.plane(b)[i] /= sum;
    }
    return st;
  }
  Runtime& runtime() const override { return stack_.runtime(); }
  const SystemConfig& config() const override { return stack_.config(); }
  Precision precision() const override { return stack_.precision(); }
  std::size_t sensor_size() const override { return stack_.sensor_size(); }
  std::size_t psf_planes() const override { return stack_.psf_planes(); }
  bool psf_ready() const override { return true; }
  const cl::Buffer& psf_sensor_buffer() const override { return stack_.psf_sensor_buffer(); }
  std::uint64_t psf_generation() const override { return stack_.psf_generation(); }
  RealStack psf_sensor() const override { return stack_.psf_sensor(); }
  std::size_t parameter_count() const override { return 1; }
  std::vector<double> parameter_vjp(const cl::Buffer& g_psf_sensor) override {
    const RealStack g = read_stack(g_psf_sensor);
    const double h = 1e-5 * sigma_;
    const RealStack up = blob(config(), sigma_ + h), down = blob(config(), sigma_ - h);
    double acc = 0;
    for (std::size_t i = 0; i < g.data.size(); ++i) acc += g.data[i] * (up.data[i] - down.data[i]) / (2 * h);
    return {acc};
  }
  std::string describe() const override { return "gaussian blob, sigma " + to_str(sigma_) + " px"; }

 private:
  RealStack read_stack(const cl::Buffer& b) const {
    const std::size_t s = sensor_size(), n = psf_planes() * s * s;
    RealStack out(psf_planes(), s, s);
    if (precision() == Precision::F64) {
      runtime().queue().enqueueReadBuffer(b, CL_TRUE, 0, n * sizeof(double), out.data.data());
    } else {
      std::vector<float> f(n);
      runtime().queue().enqueueReadBuffer(b, CL_TRUE, 0, n * sizeof(float), f.data());
      std::copy(f.begin(), f.end(), out.data.begin());
    }
    return out;
  }
  double sigma_;
  StackPsfSource stack_;
};

}  // namespace

TEST_SUITE("psf-source") {
  TEST_CASE("a new kind of PSF source is one class: the camera and the capture pipeline take it, its gradient chains") {
    SystemConfig c = tiny_config(32, 3);
    c.read_noise_sigma = 0;  // the camera alone adds the configuration's noise; compare noiseless images
    c.full_well_photons = 0;
    if (!skip_unless(runtime().has_fp64(), "float64 device")) return;
    const Precision p = Precision::F64;
    GaussianPsfSource g(runtime(), c, p, 1.5);
    const RealStack scene = random_cube(c.bands, 20, 18, 7);
    // The camera and the capture pipeline image through it exactly as through a fixed stack of its PSF.
    StackPsfSource fixed(runtime(), c, p, g.psf_sensor(), "the same stack");
    Camera from_new(g), from_fixed(fixed);
    CHECK(from_new.images({scene}, exact())[0].data == from_fixed.images({scene}, exact())[0].data);
    PipelineOptions opt;
    opt.noise = false;
    CapturePipeline pipe(runtime(), c, p, opt);
    const CaptureFrame f = pipe.run(g, scene);
    // (The pipeline's camera runs with skipping tolerances 0, not the exact reorganisation: the
    // same sums in another order, equal to double rounding.)
    const RealStack want = from_fixed.images({scene}, exact())[0];
    const double top = *std::max_element(want.data.begin(), want.data.end());
    for (std::size_t i = 0; i < want.data.size(); ++i) CHECK(std::fabs(f.clean.data[i] - want.data[i]) <= 1e-12 * top);
    // Its parameter's gradient through the pipeline's adjoint: L = <w, clean>, dL/dsigma against a
    // central difference of L over sigma (both in double).
    const RealStack w = random_cube(3, 20, 18, 8);
    CaptureGradient cg;
    cg.clean = w;
    const CaptureGradient back = pipe.vjp(cg);
    cl::Buffer gbuf(runtime().context(), CL_MEM_READ_WRITE, back.psf.data.size() * sizeof(double));
    runtime().queue().enqueueWriteBuffer(gbuf, CL_TRUE, 0, back.psf.data.size() * sizeof(double), back.psf.data.data());
    const double analytic = g.parameter_vjp(gbuf).at(0);
    const auto loss = [&](double sigma) {
      GaussianPsfSource gs(runtime(), c, p, sigma);
      CapturePipeline pp(runtime(), c, p, opt);
      const CaptureFrame ff = pp.run(gs, scene);
      double l = 0;
      for (std::size_t i = 0; i < w.data.size(); ++i) l += w.data[i] * ff.clean.data[i];
      return l;
    };
    const double h = 1e-4, numeric = (loss(1.5 + h) - loss(1.5 - h)) / (2 * h);
    CHECK(std::fabs(analytic) > 1e-6);
    CHECK(std::fabs(analytic - numeric) <= 1e-6 * std::max(1.0, std::fabs(numeric)));
  }


  TEST_CASE("a camera gives the same images from the simulator and from a fixed stack of its PSF") {
    const SystemConfig c = tiny_config(32, 3);
    const std::vector<RealStack> scenes{random_cube(c.bands, 20, 18, 5), random_cube(c.bands, 20, 18, 6)};
    for (const Precision p : device_precisions(runtime())) {
      CAPTURE(to_string(p));
      Simulator sim(runtime(), c, p);
      CHECK_FALSE(sim.psf_ready());
      sim.set_heights(random_heights(c.n, c.h_max_m(), 3));
      sim.compute_psf();
      REQUIRE(sim.psf_ready());
      CHECK(sim.parameter_count() == c.n * c.n);
      const RealStack psf = sim.psf_sensor();
      StackPsfSource fixed(runtime(), c, p, psf, "test stack");
      CHECK(fixed.parameter_count() == 0);
      CHECK(fixed.psf_sensor().data == psf.data);
      Camera from_sim(sim), from_stack(fixed);
      const auto a = from_sim.images(scenes, exact()), b = from_stack.images(scenes, exact());
      REQUIRE(a.size() == b.size());
      // The stack holds the device's own values (float32 read back to double and written again is
      // exact), so the images are identical, not merely close.
      for (std::size_t k = 0; k < a.size(); ++k) CHECK(a[k].data == b[k].data);
      // The camera follows its source: a new stack is a new generation and new images.
      const std::uint64_t g = fixed.psf_generation();
      RealStack flat(c.bands, psf.rows, psf.cols);
      for (auto& v : flat.data) v = 1.0 / double(psf.rows * psf.cols);
      fixed.set(flat);
      CHECK(fixed.psf_generation() == g + 1);
      CHECK(from_stack.images(scenes, exact())[0].data != b[0].data);
      // A fixed stack has no parameters to take a gradient to.
      CHECK_THROWS_AS(fixed.parameter_vjp(sim.psf_sensor_buffer()), Error);
    }
  }

  TEST_CASE("a PSF spec: one of --psf and --design, read without a device, made into a source in one place") {
    const SystemConfig c = tiny_config(32, 3);
    // Both refused naming the design option and the reason; neither: the run's design.
    CHECK_THROWS_WITH_AS(psf_spec_from_options("a.h5", "b.h5", "--psf", "--design", "one camera"),
                         doctest::Contains("either --psf or --design, not both (one camera)"), InputError);
    CHECK(psf_spec_from_options("", "", "--psf", "--design", "x").kind == PsfSpec::Kind::Run);
    CHECK_THROWS_WITH_AS(read_psf_input(psf_spec_from_options("", "", "--psf", "--design", "x"), c), doctest::Contains("--design"),
                         InputError);
    // A design by name: the lens's heights, simulated; its stack is the simulator's.
    const PsfInput lens = read_psf_input(psf_spec_from_options("", "lens:500", "--psf", "--design", "x"), c);
    CHECK(lens.spec.kind == PsfSpec::Kind::Design);
    CHECK(lens.heights.data == lens_design(c, 500).data);
    CHECK(lens.describe() == "fitted design lens:500 (simulated)");
    const RealStack from_design = psf_stack(runtime(), c, Precision::F64, lens);
    Simulator sim(runtime(), c, Precision::F64);
    sim.set_heights(lens_design(c, 500));
    sim.compute_psf();
    CHECK(from_design.data == sim.psf_sensor().data);
    // A file: its stack as read and checked, the same through the source.
    const auto dir = temp_dir("psf_spec");
    const std::string file = (dir / "psf.h5").string();
    write_psf(file, from_design, c.wavelengths_nm(), c.sensor_pitch_m);
    const PsfInput stack = read_psf_input(psf_spec_from_options(file, "", "--psf", "--design", "x"), c);
    CHECK(stack.from_file());
    CHECK(stack.describe() == "PSF file " + file);
    CHECK(psf_stack(runtime(), c, Precision::F64, stack).data == from_design.data);
    SpecPsfSource src = make_psf_source(runtime(), c, Precision::F64, stack);
    src.compute();
    CHECK(src.source().psf_sensor().data == from_design.data);
    // The run's design, given as heights.
    const Map2D flat = flat_design(c);
    const PsfInput run = read_psf_input(psf_spec_from_options("", "", "--psf", "--design", "x"), c, &flat);
    CHECK(run.describe("RUN/design.h5") == "the run's design RUN/design.h5 (simulated)");
    // A missing file is refused naming it.
    CHECK_THROWS_WITH_AS(read_psf_input(psf_spec_from_options((dir / "none.h5").string(), "", "--psf", "--design", "x"), c),
                         doctest::Contains("none.h5"), InputError);
    std::filesystem::remove_all(dir);
  }

  TEST_CASE("the radial engine is a PSF source for the camera too") {
    SystemConfig c = tiny_config(32, 3);
    RadialEngine radial(runtime(), c, runtime().has_fp64() ? Precision::F64 : Precision::F32);
    CHECK_FALSE(radial.psf_ready());
    std::vector<double> rings(c.n / 2);
    for (std::size_t k = 0; k < rings.size(); ++k) rings[k] = c.h_max_m() * double(k % 5) / 5.0;
    radial.compute_psf(rings);
    REQUIRE(radial.psf_ready());
    CHECK(radial.parameter_count() == c.n / 2);
    StackPsfSource fixed(runtime(), c, radial.precision(), radial.psf_sensor(), "radial stack");
    const std::vector<RealStack> scenes{random_cube(c.bands, 16, 16, 9)};
    Camera a(radial), b(fixed);
    CHECK(a.images(scenes, exact())[0].data == b.images(scenes, exact())[0].data);
    // Its parameter gradient is the ring gradient of psf_sensor_vjp.
    RealStack g = random_cube(c.bands, radial.sensor_size(), radial.sensor_size(), 4);
    const std::vector<double> host = radial.psf_sensor_vjp(g);
    cl::Buffer gb(runtime().context(), CL_MEM_READ_WRITE, g.size() * real_size(radial.precision()));
    runtime().write_reals(gb, g.data.data(), g.size(), radial.precision());
    CHECK(radial.parameter_vjp(gb) == host);
  }

  TEST_CASE("a fixed stack is checked against the configuration before any device work") {
    const SystemConfig c = tiny_config(32, 3);
    const std::size_t s = c.sensor_size_px();
    RealStack ok(c.bands, s, s);
    for (auto& v : ok.data) v = 1.0 / double(s * s);
    RealStack wrong_bands(c.bands + 1, s, s);
    std::string e = input_error_of([&] { StackPsfSource(runtime(), c, Precision::F32, wrong_bands, "x"); });
    CHECK(e.find(to_str(c.bands + 1) + " x " + to_str(s)) != std::string::npos);
    CHECK(e.find(to_str(c.bands) + " x " + to_str(s) + " x " + to_str(s)) != std::string::npos);
    RealStack negative = ok;
    negative.data[7] = -1e-3;
    CHECK(input_error_of([&] { StackPsfSource(runtime(), c, Precision::F32, negative, "x"); }).find(">= 0") != std::string::npos);
    RealStack half = ok;
    for (std::size_t i = 0; i < s * s; ++i) half.data[s * s + i] *= 0.5;  // band 1 sums to 0.5
    e = input_error_of([&] { StackPsfSource(runtime(), c, Precision::F32, half, "x"); });
    CHECK(e.find("band 1") != std::string::npos);
    CHECK(e.find("sums to 0.5") != std::string::npos);
  }

  TEST_CASE("qdo simulate --psf and qdo image --psf with qdo psf's stack give the design's images") {
    const fs::path dir = temp_dir("psf_source_cmd");
    const SystemConfig c = tiny_config(32, 3);
    const std::string cfg = "--config " + write_config(dir, c, "tiny.json").string();
    write_cube((dir / "scene.h5").string(), random_cube(c.bands, 24, 20, 11), c.wavelengths_nm());
    const std::string scene = " --scene " + (dir / "scene.h5").string();
    for (const Precision p : device_precisions(runtime())) {
      CAPTURE(to_string(p));
      const std::string prec = " --precision " + to_string(p), tag = to_string(p);
      Run r = qdo_run("psf " + cfg + " --design lens:500" + prec + " --out " + (dir / ("psf_" + tag)).string());
      CAPTURE(r.out);
      REQUIRE(r.code == 0);
      const std::string psf_file = (dir / ("psf_" + tag) / "psf.h5").string();
      r = qdo_run("simulate " + cfg + " --design lens:500" + scene + prec + " --out " + (dir / ("design_" + tag)).string());
      REQUIRE(r.code == 0);
      r = qdo_run("simulate " + cfg + " --psf " + psf_file + scene + prec + " --out " + (dir / ("file_" + tag)).string());
      CAPTURE(r.out);
      REQUIRE(r.code == 0);
      CHECK(r.out.find("PSF file") != std::string::npos);
      const auto want = h5_read((dir / ("design_" + tag) / "sensor.h5").string(), "/rgb").data;
      const auto got = h5_read((dir / ("file_" + tag) / "sensor.h5").string(), "/rgb").data;
      // qdo psf writes the device's values in the run's precision: the same stack, the same image,
      // up to the FFT plans each process chose (FFTW_MEASURE picks by timing; under load a plan
      // may differ): a few units of the precision's rounding on values <= 1.
      REQUIRE(got.size() == want.size());
      double worst = 0;
      for (std::size_t i = 0; i < got.size(); ++i) worst = std::max(worst, std::fabs(got[i] - want[i]));
      CAPTURE(worst);
      CHECK(worst <= (p == Precision::F64 ? 1e-12 : 1e-6));
      // The stack simulate used is written back in the same layout, and reads as the same stack.
      CHECK(read_psf_stack_file((dir / ("file_" + tag) / "psf.h5").string()).psf_sensor.data ==
            read_psf_stack_file(psf_file).psf_sensor.data);
      CHECK_FALSE(fs::exists(dir / ("file_" + tag) / "design.png"));
      // qdo image too (its skip report and PNG; the image itself is checked through simulate).
      r = qdo_run("image " + cfg + " --psf " + psf_file + scene + prec + " --exact --out " + (dir / ("image_" + tag)).string());
      CAPTURE(r.out);
      CHECK(r.code == 0);
      CHECK(fs::exists(dir / ("image_" + tag) / "skip.json"));
    }
    fs::remove_all(dir);
  }

  TEST_CASE("a PSF file for other bands or another sensor grid is refused naming both, nothing written") {
    const fs::path dir = temp_dir("psf_source_refuse");
    const SystemConfig c = tiny_config(32, 3);
    const std::string cfg = "--config " + write_config(dir, c, "tiny.json").string();
    write_cube((dir / "scene.h5").string(), random_cube(c.bands, 16, 16, 1), c.wavelengths_nm());
    const std::string scene = " --scene " + (dir / "scene.h5").string();
    const std::size_t s = c.sensor_size_px();
    auto stack = [](std::size_t b, std::size_t n) {
      RealStack st(b, n, n);
      for (auto& v : st.data) v = 1.0 / double(n * n);
      return st;
    };
    struct Bad {
      std::string name, file, want1, want2;
    };
    std::vector<Bad> bad;
    // Four bands where the configuration has three.
    SystemConfig four = tiny_config(32, 4);
    write_psf((dir / "bands.h5").string(), stack(4, s), four.wavelengths_nm(), c.sensor_pitch_m);
    bad.push_back({"bands", "bands.h5", "4 x " + to_str(s) + " x " + to_str(s), "3 x " + to_str(s) + " x " + to_str(s)});
    // Another size.
    write_psf((dir / "size.h5").string(), stack(3, s + 2), c.wavelengths_nm(), c.sensor_pitch_m);
    bad.push_back({"size", "size.h5", "3 x " + to_str(s + 2), "3 x " + to_str(s) + " x " + to_str(s)});
    // Another pitch (a native-grid stack, say).
    write_psf((dir / "pitch.h5").string(), stack(3, s), c.wavelengths_nm(), c.pitch_m);
    bad.push_back({"pitch", "pitch.h5", "pitch of " + to_str(c.pitch_m * 1e6), "pitch of " + to_str(c.sensor_pitch_m * 1e6)});
    // The same band count on another wavelength grid.
    std::vector<double> shifted = c.wavelengths_nm();
    for (double& w : shifted) w += 10;
    write_psf((dir / "grid.h5").string(), stack(3, s), shifted, c.sensor_pitch_m);
    bad.push_back({"grid", "grid.h5", to_str(shifted.front()) + " ... " + to_str(shifted.back()), to_str(c.wavelengths_nm().front())});
    // Not a PSF file at all.
    write_cube((dir / "cube.h5").string(), stack(3, s), c.wavelengths_nm());
    bad.push_back({"nostack", "cube.h5", "/psf_sensor", "cube.h5"});
    for (const Bad& b : bad) {
      CAPTURE(b.name);
      for (const char* cmd : {"simulate", "image"}) {
        CAPTURE(cmd);
        const fs::path out = dir / ("out_" + b.name + cmd);
        const Run r = qdo_run(std::string(cmd) + " " + cfg + " --psf " + (dir / b.file).string() + scene + " --out " + out.string());
        CAPTURE(r.out);
        CHECK(r.code == 2);
        CHECK(r.out.find(b.want1) != std::string::npos);
        CHECK(r.out.find(b.want2) != std::string::npos);
        CHECK_FALSE(fs::exists(out));
      }
    }
    // One PSF source at a time.
    write_psf((dir / "good.h5").string(), stack(3, s), c.wavelengths_nm(), c.sensor_pitch_m);
    const Run both = qdo_run("simulate " + cfg + " --psf " + (dir / "good.h5").string() + " --design flat" + scene +
                             " --out " + (dir / "both").string());
    CHECK(both.code == 2);
    CHECK(both.out.find("either --psf or --design") != std::string::npos);
    const Run release = qdo_run("simulate " + cfg + " --psf " + (dir / "good.h5").string() + scene + " --formation release --out " +
                                (dir / "rel").string());
    CHECK(release.code == 2);
    CHECK(release.out.find("native-grid PSF") != std::string::npos);
    // A run folder's psf.h5 from before the dataset name was unified (/psf) still reads.
    h5_write((dir / "legacy.h5").string(),
             {H5Dataset{"/psf", {3, s, s}, stack(3, s).data, {{"pitch_m", c.sensor_pitch_m}}, {}},
              H5Dataset{"/wavelengths_nm", {3}, c.wavelengths_nm(), {}, {}}});
    const PsfStackFile legacy = read_psf_stack_file((dir / "legacy.h5").string());
    CHECK(legacy.dataset == "/psf");
    const Run ok = qdo_run("simulate " + cfg + " --psf " + (dir / "legacy.h5").string() + scene + " --out " + (dir / "legacy").string());
    CAPTURE(ok.out);
    CHECK(ok.code == 0);
    fs::remove_all(dir);
  }

  TEST_CASE("qdo eval --psf with qdo psf's stack of the run's design gives the run's own metrics; another grid is refused") {
    const fs::path dir = temp_dir("psf_source_eval");
    const SystemConfig c = tiny_config(32, 3);
    const std::string cfg = "--config " + write_config(dir, c, "tiny.json").string();
    const fs::path run = dir / "run";
    // No height noise at evaluation: the run's own metrics must come from the noiseless design's PSF.
    Run r = qdo_run("design " + cfg + " --noise-at-test off --mode qdo+a --levels 4 --epochs 5 --steps-per-epoch 2 --t0 1 --t1 4 "
                    "--synthetic-scenes 3 --seed 3 --max-steps 2 --out " + run.string());
    CAPTURE(r.out);
    REQUIRE(r.code == 0);
    r = qdo_run("psf " + cfg + " --design " + (run / "design.h5").string() + " --out " + (dir / "psf").string());
    REQUIRE(r.code == 0);
    r = qdo_run("eval " + run.string() + " --synthetic-scenes 2 --out " + (dir / "own").string());
    CAPTURE(r.out);
    REQUIRE(r.code == 0);
    r = qdo_run("eval " + run.string() + " --synthetic-scenes 2 --psf " + (dir / "psf" / "psf.h5").string() + " --out " +
                (dir / "file").string());
    CAPTURE(r.out);
    REQUIRE(r.code == 0);
    // The same PSF (qdo psf wrote the device's float32 values), the same measurements and decoder:
    // the same metrics and reconstructions, up to the FFT plans each process chose (FFTW_MEASURE
    // picks by timing): within float32 rounding.
    const CsvTable mf = read_csv((dir / "file" / "metrics.csv").string()), mo = read_csv((dir / "own" / "metrics.csv").string());
    REQUIRE(mf.header == mo.header);
    REQUIRE(!mo.columns.empty());
    REQUIRE(!mo.columns[0].empty());
    CHECK(mf.raw[0] == mo.raw[0]);  // the same scenes
    for (std::size_t col = 1; col < mo.columns.size(); ++col)
      for (std::size_t row = 0; row < mo.columns[col].size(); ++row) {
        CAPTURE(mo.header[col]);
        CHECK(mf.columns[col].at(row) == doctest::Approx(mo.columns[col][row]).epsilon(1e-5));
      }
    const auto rf = h5_read((dir / "file" / "reconstructions.h5").string(), "/recon_0").data;
    const auto ro = h5_read((dir / "own" / "reconstructions.h5").string(), "/recon_0").data;
    REQUIRE(rf.size() == ro.size());
    double worst = 0;
    for (std::size_t i = 0; i < rf.size(); ++i) worst = std::max(worst, std::fabs(rf[i] - ro[i]));
    CAPTURE(worst);
    CHECK(worst <= 1e-5);
    // A stack of other bands, or of another size, is refused naming both; nothing is written.
    const std::size_t s = c.sensor_size_px();
    RealStack four(4, s, s), big(3, s + 4, s + 4);
    for (auto& v : four.data) v = 1.0 / double(s * s);
    for (auto& v : big.data) v = 1.0 / double((s + 4) * (s + 4));
    write_psf((dir / "four.h5").string(), four, tiny_config(32, 4).wavelengths_nm(), c.sensor_pitch_m);
    write_psf((dir / "big.h5").string(), big, c.wavelengths_nm(), c.sensor_pitch_m);
    for (const auto& [file, found] : std::vector<std::pair<std::string, std::string>>{
             {"four.h5", "4 x " + to_str(s) + " x " + to_str(s)}, {"big.h5", "3 x " + to_str(s + 4) + " x " + to_str(s + 4)}}) {
      CAPTURE(file);
      const fs::path out = dir / ("refused_" + file);
      const Run bad = qdo_run("eval " + run.string() + " --psf " + (dir / file).string() + " --out " + out.string());
      CAPTURE(bad.out);
      CHECK(bad.code == 2);
      CHECK(bad.out.find(found) != std::string::npos);
      CHECK(bad.out.find("3 x " + to_str(s) + " x " + to_str(s)) != std::string::npos);
      CHECK_FALSE(fs::exists(out));
    }
    // --psf picks the camera; --levels would pick heights: refused.
    const Run both = qdo_run("eval " + run.string() + " --levels 2 --psf " + (dir / "psf" / "psf.h5").string() + " --out " +
                             (dir / "both").string());
    CHECK(both.code == 2);
    CHECK_FALSE(fs::exists(dir / "both"));
    fs::remove_all(dir);
  }
}
