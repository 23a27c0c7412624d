// Export of a design's mask set: the GDSII library (mask layers, alignment marks, aperture
// outline; src/fab/gds.cpp), manifest.json, the read-back check against the design, PNG previews and
// the Markdown sheet manifest.md. API and conventions: include/qdo/fab/fab.hpp.
#include "qdo/fab/fab.hpp"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <sstream>

#include "fab/fab_internal.hpp"
#include "qdo/runtime/error.hpp"
#include "qdo/data/figure.hpp"
#include "qdo/data/io.hpp"

namespace fs = std::filesystem;
using nlohmann::json;

namespace qdo::fab {

namespace {

// Corner of pixel (0, 0) in nm: the optical axis (sample (N/2, N/2)) at the origin.
std::int64_t origin_nm(std::size_t n, std::int64_t pitch_nm) {
  return -(std::int64_t(n / 2) * pitch_nm) - pitch_nm / 2;
}

gds::Polygon cross_polygon(std::int64_t cx, std::int64_t cy, std::int64_t arm, std::int64_t half_w) {
  const std::int64_t a = arm, w = half_w;
  const std::int64_t pts[12][2] = {{-w, -a}, {w, -a}, {w, -w}, {a, -w}, {a, w},  {w, w},
                                   {w, a},   {-w, a}, {-w, w}, {-a, w}, {-a, -w}, {-w, -w}};
  gds::Polygon p;
  for (const auto& q : pts) p.push_back({cx + q[0], cy + q[1]});
  p.push_back(p.front());
  return p;
}

gds::Polygon disk_polygon(double radius_nm, std::size_t vertices) {
  gds::Polygon p;
  for (std::size_t k = 0; k < vertices; ++k) {
    const double t = 2.0 * M_PI * double(k) / double(vertices);
    const gds::Point q{std::llround(radius_nm * std::cos(t)), std::llround(radius_nm * std::sin(t))};
    if (p.empty() || q != p.back()) p.push_back(q);
  }
  if (p.back() == p.front()) p.pop_back();
  p.push_back(p.front());
  return p;
}

std::string md_escape(const std::string& s) {
  std::string o;
  for (char ch : s) o += ch == '|' ? std::string("\\|") : std::string(1, ch);
  return o;
}

}  // namespace

ExportResult export_design(const Design& d, const SystemConfig& cfg, const ExportOptions& o) {
  if (o.out.empty()) reject("out", "(missing)", "an output folder");
  std::vector<std::pair<double, double>> curve;
  if (!o.dose_curve_csv.empty()) {
    if (o.scheme != Scheme::Greyscale) reject("dose_curve", o.dose_curve_csv, "only with the greyscale scheme");
    const CsvTable t = read_csv(o.dose_curve_csv);
    const auto& dep = t.column("depth_nm");
    const auto& dose = t.column("dose");
    for (std::size_t i = 0; i < dep.size(); ++i) {
      if (!std::isfinite(dep[i]) || !std::isfinite(dose[i])) reject("dose curve row " + std::to_string(i + 1), o.dose_curve_csv, "numbers");
      curve.push_back({dep[i], dose[i]});
    }
  }
  ExportResult res;
  try {
    res.plan = plan_masks(d, cfg, o.scheme, o.constraints, curve);  // every check before any writing
  } catch (const InputError& e) {  // a pixel or level named: say which design it is in
    const auto src = o.provenance.find("source");
    if (src == o.provenance.end() || src->second.empty()) throw;
    throw InputError("design '" + src->second + "': " + e.what());
  }
  const MaskPlan& plan = res.plan;
  const std::size_t n = plan.n;
  const std::int64_t p = plan.pitch_nm, org = origin_nm(n, p);
  if (!(o.mark_arm_um > o.mark_width_um && o.mark_width_um > 0 && o.mark_margin_um > o.mark_arm_um))
    reject("alignment mark", to_str(o.mark_arm_um) + "/" + to_str(o.mark_width_um) + "/" + to_str(o.mark_margin_um),
           "margin > arm > width > 0 (um)");
  if (o.aperture_vertices < 16 || o.aperture_vertices > 8000) reject("aperture_vertices", o.aperture_vertices, "in [16, 8000]");

  // GDSII library: mask layers, marks, aperture.
  gds::Library lib;
  lib.name = "QDO_" + to_string(plan.scheme);
  std::vector<std::size_t> mask_polys(plan.masks.size(), 0), mask_verts(plan.masks.size(), 0);
  for (std::size_t m = 0; m < plan.masks.size(); ++m) {
    const Mask& mk = plan.masks[m];
    for (auto& poly : gds::merge_pixels(mk.drawn, n, n)) {
      gds::Boundary b;
      b.layer = mk.layer;
      for (auto& q : poly) b.points.push_back({org + q.x * p, org + q.y * p});
      mask_verts[m] += b.points.size() - 1;
      ++mask_polys[m];
      lib.boundaries.push_back(std::move(b));
    }
    res.polygons += mask_polys[m];
    res.vertices += mask_verts[m];
  }
  const std::int64_t half_field = std::int64_t(n / 2) * p + p / 2;
  const std::int64_t mc = half_field + std::llround(o.mark_margin_um * 1e3);
  const std::int64_t arm = std::llround(o.mark_arm_um * 1e3), hw = std::llround(o.mark_width_um * 1e3 / 2);
  for (int sx : {-1, 1})
    for (int sy : {-1, 1}) lib.boundaries.push_back({kMarkLayer, 0, cross_polygon(sx * mc, sy * mc, arm, hw)});
  lib.boundaries.push_back({kApertureLayer, 0, disk_polygon(cfg.aperture_radius() * 1e9, o.aperture_vertices)});

  make_output_dir(o.out, "out");
  const fs::path dir(o.out);
  gds::write((dir / "masks.gds").string(), lib);
  res.files.push_back("masks.gds");

  // Manifest.
  json j;
  j["format"] = "qdo fab export 1";
  j["scheme"] = to_string(plan.scheme);
  j["method"] = plan.method;
  j["scheme_note"] = plan.scheme == Scheme::Binary
                         ? "k binary-coded masks; a level's etch is the sum of the depths of the masks open over it"
                     : plan.scheme == Scheme::Nested
                         ? "L - 1 nested masks in order; mask m opens every pixel at or below the m-th highest level and etches one free step"
                         : "one layer per level written in a single greyscale exposure; dose per layer from the dose table";
  j["gds"] = {{"file", "masks.gds"},
              {"library", lib.name},
              {"structure", lib.structure},
              {"database_unit_m", 1e-9},
              {"user_unit_m", 1e-6},
              {"datatype", 0},
              {"alignment_mark_layer", kMarkLayer},
              {"aperture_layer", kApertureLayer}};
  j["material"] = cfg.material;
  j["base_wavelength_nm"] = cfg.base_wavelength_nm;
  j["h_max_nm"] = plan.h_max_m * 1e9;
  j["base_plate_m"] = cfg.base_plate_m;
  j["aperture_radius_m"] = cfg.aperture_radius();
  j["pitch_m"] = cfg.pitch_m;
  j["grid"] = {{"n", n},
               {"pitch_nm", p},
               {"pixel_00_corner_nm", {org, org}},
               {"mapping", "pixel (row i, col j) covers x in [c + j p, c + (j+1) p], y in [c + i p, c + (i+1) p] nm, c = pixel_00_corner_nm; "
                           "the optical axis (sample (N/2, N/2)) at the origin; y grows with the row (a GDS viewer shows the PNGs flipped vertically)"}};
  j["blank_top_nm"] = plan.top_m * 1e9;
  j["etch_convention"] =
      "H is the glass relief above the base plate. The blank's unetched surface is the highest level (blank_top_nm); each pixel is etched "
      "by etch_depth_nm = blank_top - H. REFERENCE's etch depth h_max - H (etch_depth_from_h_max_nm) differs by the constant h_max - "
      "blank_top (a uniformly thinner relief layer: only a constant phase).";
  j["tone"] = "drawn polygons = open (etched) regions: dark-field masks for a positive resist (invert for a negative resist)";
  std::map<int, int> layer_of;
  for (std::size_t m = 0; m < plan.masks.size(); ++m) layer_of[int(m)] = plan.masks[m].layer;
  j["levels"] = json::array();
  for (const auto& L : plan.levels) {
    json lj;
    lj["index"] = L.index;
    lj["height_nm"] = L.height_m * 1e9;
    lj["etch_depth_nm"] = (plan.top_m - L.height_m) * 1e9;
    lj["etch_depth_from_h_max_nm"] = (plan.h_max_m - L.height_m) * 1e9;
    lj["pixels"] = L.pixels;
    json layers = json::array();
    for (int m : L.masks) layers.push_back(layer_of[m]);
    lj["mask_layers"] = layers;
    if (!L.pixels) lj["note"] = "unused: not fabricated";
    j["levels"].push_back(lj);
  }
  j["masks"] = json::array();
  for (std::size_t m = 0; m < plan.masks.size(); ++m) {
    const Mask& mk = plan.masks[m];
    json mj;
    mj["layer"] = mk.layer;
    mj["name"] = mk.name;
    mj["etch_depth_nm"] = mk.etch_depth_m * 1e9;
    mj["tone"] = "dark-field (drawn = open = etched)";
    mj["polygons"] = mask_polys[m];
    mj["vertices"] = mask_verts[m];
    mj["open_pixels"] = mk.pixels;
    mj["open_area_um2"] = double(mk.pixels) * double(p) * double(p) * 1e-6;
    if (plan.scheme == Scheme::Greyscale) mj["relative_dose"] = mk.relative_dose;
    mj["preview"] = "mask_L" + std::to_string(mk.layer) + ".png";
    j["masks"].push_back(mj);
  }
  if (plan.scheme == Scheme::Greyscale) {
    j["dose_table"] = json::array();
    for (const auto& mk : plan.masks)
      j["dose_table"].push_back({{"layer", mk.layer}, {"etch_depth_nm", mk.etch_depth_m * 1e9}, {"relative_dose", mk.relative_dose}});
    j["dose_calibration"] = o.dose_curve_csv.empty() ? "linear placeholder: dose = etch / deepest etch; replace with the fab's curve (--dose-curve)"
                                                     : "interpolated from " + o.dose_curve_csv;
  }
  j["process"] = plan.scheme == Scheme::Greyscale
                     ? "one greyscale write; the alignment crosses (layer 254) are written with it"
                     : "mask 1 prints the alignment crosses (copy layer 254 onto every mask plate); every later mask is aligned to them; "
                       "each mask: expose, develop, etch its depth, strip";
  j["alignment_marks"] = {{"layer", kMarkLayer},
                          {"shape", "crosses"},
                          {"centres_nm", {{-mc, -mc}, {mc, -mc}, {-mc, mc}, {mc, mc}}},
                          {"arm_half_length_um", o.mark_arm_um},
                          {"arm_width_um", o.mark_width_um}};
  j["aperture"] = {{"layer", kApertureLayer}, {"radius_um", cfg.aperture_radius() * 1e6}, {"vertices", o.aperture_vertices},
                   {"note", "reference outline of the circular aperture (a filled polygon), not an etch layer"}};
  j["constraints"] = {{"min_feature_um", o.constraints.min_feature_um},
                      {"max_levels", o.constraints.max_levels > 0 ? o.constraints.max_levels : scheme_max_levels(plan.scheme)},
                      {"max_height_nm", o.constraints.max_height_nm > 0 ? o.constraints.max_height_nm : plan.h_max_m * 1e9},
                      {"level_tolerance_nm", o.constraints.level_tolerance_nm}};
  j["provenance"] = o.provenance;
  j["polygons"] = res.polygons;
  j["vertices"] = res.vertices;
  write_text_atomic((dir / "manifest.json").string(), j.dump(2) + "\n");
  res.files.push_back("manifest.json");

  // Read everything back with the project's reader and check it against the design.
  const Reconstruction rec = reconstruct_export(o.out);
  for (std::size_t i = 0; i < n * n; ++i) {
    if (rec.level_of_pixel[i] != plan.level_of_pixel[i])
      throw Error("export check failed: " + pixel_name(i, n) + " reads back as level " + std::to_string(rec.level_of_pixel[i]) +
                  ", the design has level " + std::to_string(plan.level_of_pixel[i]));
    res.max_height_error_nm = std::max(res.max_height_error_nm, std::fabs(rec.height_m.data[i] - d.height_m.data[i]) * 1e9);
  }
  if (res.max_height_error_nm > o.constraints.level_tolerance_nm)
    throw Error("export check failed: heights rebuilt from the masks differ from the design by " + to_str(res.max_height_error_nm) + " nm");
  j["check"] = {{"reader", "qdo::gds::read + rasterize at pixel centres"},
                {"level_map_identical", true},
                {"max_height_error_nm", res.max_height_error_nm}};
  write_text_atomic((dir / "manifest.json").string(), j.dump(2) + "\n");

  // Previews from the read-back polygons.
  const gds::Library back = gds::read(readable_output((dir / "masks.gds").string()));
  for (const Mask& mk : plan.masks) {
    std::vector<gds::Polygon> polys;
    for (const auto& b : back.boundaries)
      if (b.layer == mk.layer) {
        gds::Polygon g;
        for (const auto& q : b.points) g.push_back({(q.x - org) / p, (q.y - org) / p});
        polys.push_back(std::move(g));
      }
    const auto bits = gds::rasterize(polys, n, n);
    std::vector<unsigned char> px(bits.size());
    for (std::size_t i = 0; i < bits.size(); ++i) px[i] = bits[i] ? 255 : 0;
    const std::string name = "mask_L" + std::to_string(mk.layer) + ".png";
    write_png((dir / name).string(), n, n, 1, px);
    res.files.push_back(name);
  }
  write_height_figure((dir / "heights_from_masks.png").string(), "Heights the masks make (" + to_str(plan.masks.size()) + " layers)",
                      rec.height_m, cfg.pitch_m);
  res.files.push_back("heights_from_masks.png");

  // Markdown sheet.
  std::ostringstream md;
  md << "# Mask set: " << to_string(plan.scheme) << " scheme\n\n";
  md << "| item | value |\n|---|---|\n";
  for (const auto& [k, v] : o.provenance) md << "| " << md_escape(k) << " | " << md_escape(v) << " |\n";
  md << "| scheme | " << to_string(plan.scheme) << " (" << plan.method << ") |\n";
  md << "| material | " << cfg.material << " |\n";
  md << "| h_max (2pi at " << cfg.base_wavelength_nm << " nm) | " << nm(plan.h_max_m, 2) << " nm |\n";
  md << "| base plate | " << cfg.base_plate_m * 1e3 << " mm |\n";
  md << "| grid | " << n << " x " << n << " pixels at " << p << " nm (" << double(n * std::size_t(p)) * 1e-3 << " um field) |\n";
  md << "| aperture | radius " << cfg.aperture_radius() * 1e6 << " um (layer " << kApertureLayer << ") |\n";
  md << "| blank top (unetched surface) | " << nm(plan.top_m, 2) << " nm above the base plate |\n";
  md << "| GDSII | masks.gds, 1 nm database unit, 1 um user unit, structure DOE; alignment crosses on layer " << kMarkLayer << " |\n";
  md << "| mask polygons | " << res.polygons << " (" << res.vertices << " vertices) |\n";
  md << "| read-back check | level map identical; max height error " << res.max_height_error_nm << " nm |\n\n";
  md << "Etch depths are measured from the blank's unetched surface (the highest level): etch = blank top - H. "
        "REFERENCE's h_max - H differs by a constant (a thinner relief layer; only a constant phase). "
        "Drawn polygons are the open (etched) regions: dark-field masks for a positive resist.\n\n";
  md << "## Levels\n\n| level | height (nm) | etch depth (nm) | h_max - H (nm) | pixels | mask layers |\n|---:|---:|---:|---:|---:|---|\n";
  for (const auto& L : plan.levels) {
    md << "| " << L.index << " | " << nm(L.height_m) << " | " << nm(plan.top_m - L.height_m) << " | " << nm(plan.h_max_m - L.height_m)
       << " | " << L.pixels << " | ";
    for (std::size_t k = 0; k < L.masks.size(); ++k) md << (k ? ", " : "") << layer_of[L.masks[k]];
    md << (L.pixels ? "" : " (unused)") << " |\n";
  }
  md << "\n## Masks\n\n| layer | name | etch depth (nm) | tone | polygons | vertices | open area (mm^2) |"
     << (plan.scheme == Scheme::Greyscale ? " relative dose |" : "") << " preview |\n|---:|---|---:|---|---:|---:|---:|"
     << (plan.scheme == Scheme::Greyscale ? "---:|" : "") << "---|\n";
  for (std::size_t m = 0; m < plan.masks.size(); ++m) {
    const Mask& mk = plan.masks[m];
    md << "| " << mk.layer << " | " << mk.name << " | " << nm(mk.etch_depth_m) << " | dark-field | " << mask_polys[m] << " | "
       << mask_verts[m] << " | " << double(mk.pixels) * double(p) * double(p) * 1e-12 << " |";
    if (plan.scheme == Scheme::Greyscale) md << " " << mk.relative_dose << " |";
    md << " mask_L" << mk.layer << ".png |\n";
  }
  md << "\nProcess: " << j["process"].get<std::string>() << ".\n";
  if (plan.scheme == Scheme::Greyscale) md << "\nDose calibration: " << j["dose_calibration"].get<std::string>() << ".\n";
  md << "\nFiles: masks.gds, manifest.json, this sheet, mask_L*.png (white = open), heights_from_masks.png (the height map rebuilt from "
        "the GDSII polygons and these depths).\n";
  write_text_atomic((dir / "manifest.md").string(), md.str());
  res.files.push_back("manifest.md");
  return res;
}

}  // namespace qdo::fab
