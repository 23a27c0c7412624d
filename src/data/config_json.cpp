// The system configuration as JSON (include/qdo/data/config.hpp): the one field list, reading with
// checked values and a suggestion for unknown keys, and writing.
#include "qdo/data/config.hpp"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <nlohmann/json.hpp>
#include <utility>

#include "qdo/runtime/error.hpp"
#include "data/json_strict.hpp"
#include "qdo/data/materials.hpp"

namespace qdo {

using nlohmann::json;

namespace {

constexpr std::size_t kMaxJsonBytes = std::size_t{1} << 20;

// A JSON value as quoted in an error message: scalars as written (strings shortened), arrays
// and objects by type and size only. Never dumps a structured value: a value nested 100,000
// deep (well under the 1 MiB cap) would overflow the stack in the recursive serializer.
std::string quote(const json& v) {
  constexpr std::size_t kMax = 60;
  if (v.is_array()) return "an array of " + std::to_string(v.size()) + " elements";
  if (v.is_object()) return "an object with " + std::to_string(v.size()) + " keys";
  std::string s = v.dump(-1, ' ', false, json::error_handler_t::replace);
  if (s.size() > kMax) s = s.substr(0, kMax) + "...\" (" + std::to_string(s.size()) + " characters)";
  return s;
}

double get_number(const std::string& key, const json& v) {
  if (!v.is_number()) reject(key, quote(v), "expected a number");
  return v.get<double>();
}

unsigned long long get_uint(const std::string& key, const json& v) {
  if (v.is_number_unsigned()) return v.get<unsigned long long>();
  if (v.is_number_float()) {
    const double d = v.get<double>();
    if (d >= 0 && d <= 9007199254740992.0 && d == std::floor(d)) return static_cast<unsigned long long>(d);
  }
  reject(key, quote(v), "expected a non-negative integer");
}

std::size_t get_size(const std::string& key, const json& v) {
  const unsigned long long u = get_uint(key, v);
  if (u > std::numeric_limits<std::size_t>::max()) reject(key, quote(v), "expected a non-negative integer");
  return static_cast<std::size_t>(u);
}

bool get_bool(const std::string& key, const json& v) {
  if (!v.is_boolean()) reject(key, quote(v), "expected true or false");
  return v.get<bool>();
}

std::string get_string(const std::string& key, const json& v) {
  if (!v.is_string()) reject(key, quote(v), "expected a string");
  return v.get<std::string>();
}

using Setter = std::function<void(SystemConfig&, const std::string&, const json&)>;
using Getter = std::function<nlohmann::ordered_json(const SystemConfig&)>;

// One configuration field: its JSON key (= the SystemConfig member's name), how it is read from
// JSON (checked, InputError naming the key) and how it is written.
struct Field {
  std::string key;
  Setter read;
  Getter write;
};

Field number_field(const char* key, double SystemConfig::*m) {
  return {key, [m](SystemConfig& c, const std::string& k, const json& v) { c.*m = get_number(k, v); },
          [m](const SystemConfig& c) { return nlohmann::ordered_json(c.*m); }};
}
Field size_field(const char* key, std::size_t SystemConfig::*m) {
  return {key, [m](SystemConfig& c, const std::string& k, const json& v) { c.*m = get_size(k, v); },
          [m](const SystemConfig& c) { return nlohmann::ordered_json(c.*m); }};
}
Field bool_field(const char* key, bool SystemConfig::*m) {
  return {key, [m](SystemConfig& c, const std::string& k, const json& v) { c.*m = get_bool(k, v); },
          [m](const SystemConfig& c) { return nlohmann::ordered_json(c.*m); }};
}
// An enum stored as one of two strings.
template <typename E>
Field choice_field(const char* key, E SystemConfig::*m, const char* a, E ea, const char* b, E eb) {
  return {key,
          [=](SystemConfig& c, const std::string& k, const json& v) {
            const std::string s = get_string(k, v);
            if (s == a) c.*m = ea;
            else if (s == b) c.*m = eb;
            else reject(k, quote(v), std::string("\"") + a + "\" or \"" + b + "\"");
          },
          [=](const SystemConfig& c) { return nlohmann::ordered_json(c.*m == ea ? a : b); }};
}

// The one field list: every JSON key (= SystemConfig field name, in declaration order), how it is
// read and how it is written (config_from_json_text and config_to_json_text both walk it).
const std::vector<Field>& fields() {
  static const std::vector<Field> t = {
      size_field("n", &SystemConfig::n),
      number_field("pitch_m", &SystemConfig::pitch_m),
      number_field("wavelength_start_nm", &SystemConfig::wavelength_start_nm),
      number_field("wavelength_step_nm", &SystemConfig::wavelength_step_nm),
      size_field("bands", &SystemConfig::bands),
      {"scene_distance_m",
       [](SystemConfig& c, const std::string& k, const json& v) {
         if (v.is_string()) {
           if (v.get<std::string>() != "inf") reject(k, quote(v), "expected a number of metres or the string \"inf\"");
           c.scene_at_infinity = true;
           c.scene_distance_m = std::numeric_limits<double>::infinity();
         } else {
           if (!v.is_number()) reject(k, quote(v), "expected a number of metres or the string \"inf\"");
           c.scene_at_infinity = false;
           c.scene_distance_m = v.get<double>();
         }
       },
       [](const SystemConfig& c) { return c.scene_at_infinity ? nlohmann::ordered_json("inf") : nlohmann::ordered_json(c.scene_distance_m); }},
      {"object_points",
       [](SystemConfig& c, const std::string& k, const json& v) {
         const std::string allowed = "an array of [distance_m or \"inf\", field_x_deg, field_y_deg] triples";
         if (!v.is_array()) reject(k, quote(v), allowed);
         if (v.size() > 4096) reject(k, quote(v), "at most 4096 points");
         c.object_points.clear();
         for (std::size_t i = 0; i < v.size(); ++i) {
           const json& e = v[i];
           const std::string ki = k + "[" + std::to_string(i) + "]";
           if (!e.is_array() || e.size() != 3) reject(ki, quote(e), allowed);
           ObjectPoint p;
           if (e[0].is_string() && e[0].get<std::string>() == "inf") p.distance_m = std::numeric_limits<double>::infinity();
           else if (e[0].is_number()) p.distance_m = e[0].get<double>();
           else reject(ki + " distance", quote(e[0]), "a distance > 0 m (a number) or the string \"inf\"");
           p.field_x_deg = get_number(ki + " field_x_deg", e[1]);
           p.field_y_deg = get_number(ki + " field_y_deg", e[2]);
           c.object_points.push_back(p);
         }
       },
       // Omitted when empty (the default single on-axis point): configurations without object
       // points write the same JSON as before.
       [](const SystemConfig& c) {
         if (c.object_points.empty()) return nlohmann::ordered_json();
         nlohmann::ordered_json a = nlohmann::ordered_json::array();
         for (const ObjectPoint& p : c.object_points)
           a.push_back({p.at_infinity() ? nlohmann::ordered_json("inf") : nlohmann::ordered_json(p.distance_m), p.field_x_deg,
                        p.field_y_deg});
         return a;
       }},
      number_field("sensor_distance_m", &SystemConfig::sensor_distance_m),
      number_field("aperture_radius_m", &SystemConfig::aperture_radius_m),
      {"aperture_edge",
       [](SystemConfig& c, const std::string& k, const json& v) {
         const std::string e = get_string(k, v);
         if (e == "inclusive") c.aperture_edge = ApertureEdge::Inclusive;
         else if (e == "strict") c.aperture_edge = ApertureEdge::Strict;
         else if (e == "area") c.aperture_edge = ApertureEdge::Area;
         else reject(k, quote(v), "\"inclusive\", \"strict\" or \"area\"");
       },
       [](const SystemConfig& c) {
         return nlohmann::ordered_json(c.aperture_edge == ApertureEdge::Strict ? "strict"
                                       : c.aperture_edge == ApertureEdge::Area ? "area"
                                                                                : "inclusive");
       }},
      {"aperture_offset_m",
       [](SystemConfig& c, const std::string& k, const json& v) {
         if (!v.is_array() || v.size() != 2) reject(k, quote(v), "an array [x, y] of two numbers of metres");
         c.aperture_offset_x_m = get_number(k + "[0]", v[0]);
         c.aperture_offset_y_m = get_number(k + "[1]", v[1]);
       },
       // Omitted at (0, 0): configurations with a centred axis write the same JSON as before.
       [](const SystemConfig& c) {
         if (!c.aperture_offset()) return nlohmann::ordered_json();
         return nlohmann::ordered_json::array({c.aperture_offset_x_m, c.aperture_offset_y_m});
       }},
      {"material",
       [](SystemConfig& c, const std::string& k, const json& v) {
         c.material = material_by_name(get_string(k, v)).name;  // canonical name; aliases accepted
       },
       [](const SystemConfig& c) { return nlohmann::ordered_json(c.material); }},
      number_field("base_wavelength_nm", &SystemConfig::base_wavelength_nm),
      number_field("base_plate_m", &SystemConfig::base_plate_m),
      choice_field("propagator", &SystemConfig::propagator, "fresnel", Propagator::Fresnel, "asm", Propagator::AngularSpectrum),
      size_field("padding_px", &SystemConfig::padding_px),
      bool_field("strict_sampling", &SystemConfig::strict_sampling),
      number_field("sensor_pitch_m", &SystemConfig::sensor_pitch_m),
      size_field("scene_size_px", &SystemConfig::scene_size_px),
      {"camera", [](SystemConfig& c, const std::string& k, const json& v) { c.camera = get_string(k, v); },
       [](const SystemConfig& c) { return nlohmann::ordered_json(c.camera); }},
      bool_field("srf_interpolate", &SystemConfig::srf_interpolate),
      choice_field("convolution", &SystemConfig::convolution, "linear", ConvolutionMode::Linear, "circular",
                   ConvolutionMode::Circular),
      number_field("read_noise_sigma", &SystemConfig::read_noise_sigma),
      number_field("full_well_photons", &SystemConfig::full_well_photons),
      {"noise_seed", [](SystemConfig& c, const std::string& k, const json& v) { c.noise_seed = get_uint(k, v); },
       [](const SystemConfig& c) { return nlohmann::ordered_json(c.noise_seed); }},
      {"cfa",
       [](SystemConfig& c, const std::string& k, const json& v) {
         const std::string s = get_string(k, v);
         for (Cfa e : {Cfa::None, Cfa::RGGB, Cfa::GRBG, Cfa::GBRG, Cfa::BGGR})
           if (s == to_string(e)) {
             c.cfa = e;
             return;
           }
         reject(k, quote(v), "\"none\", \"rggb\", \"grbg\", \"gbrg\" or \"bggr\"");
       },
       [](const SystemConfig& c) { return nlohmann::ordered_json(to_string(c.cfa)); }},
      number_field("black_level_dn", &SystemConfig::black_level_dn),
      number_field("gain", &SystemConfig::gain),
      size_field("bit_depth", &SystemConfig::bit_depth),
  };
  return t;
}

std::size_t edit_distance(const std::string& a, const std::string& b) {
  std::vector<std::size_t> row(b.size() + 1);
  for (std::size_t j = 0; j <= b.size(); ++j) row[j] = j;
  for (std::size_t i = 1; i <= a.size(); ++i) {
    std::size_t diag = row[0];
    row[0] = i;
    for (std::size_t j = 1; j <= b.size(); ++j) {
      const std::size_t up = row[j];
      row[j] = std::min({row[j] + 1, row[j - 1] + 1, diag + (a[i - 1] == b[j - 1] ? 0u : 1u)});
      diag = up;
    }
  }
  return row[b.size()];
}

[[noreturn]] void reject_unknown_key(const std::string& key) {
  if (key.size() > 60) throw InputError("unknown key '" + key.substr(0, 60) + "...' (" + std::to_string(key.size()) + " characters)");
  std::string allowed = "preset";
  std::string best;
  std::size_t best_d = std::max<std::size_t>(3, key.size() / 3) + 1;
  for (const Field& f : fields()) {
    allowed += ", " + f.key;
    const std::size_t d = edit_distance(key, f.key);
    if (d < best_d) best_d = d, best = f.key;
  }
  throw InputError("unknown key '" + key + "'" + (best.empty() ? "" : " (did you mean '" + best + "'?)") +
                   "; allowed keys: " + allowed);
}

}  // namespace

SystemConfig config_from_json_text(const std::string& text, const std::string& origin) {
  try {
    if (text.size() > kMaxJsonBytes)
      reject("configuration size", std::to_string(text.size()) + " bytes", "at most 1 MiB of JSON");
    json j;
    try {
      j = parse_json_strict(text, "");
    } catch (const json::exception& e) {  // parse_error, and out_of_range for numbers like 1e999
      throw InputError(std::string("invalid JSON: ") + e.what());
    }
    if (!j.is_object()) reject("top level", j.type_name(), "expected a JSON object {\"key\": value, ...}");
    SystemConfig c = preset_config(j.contains("preset") ? get_string("preset", j.at("preset")) : std::string("paper"));
    for (const auto& item : j.items()) {
      if (item.key() == "preset") continue;
      const auto& table = fields();
      const auto it = std::find_if(table.begin(), table.end(), [&](const Field& f) { return f.key == item.key(); });
      if (it == table.end()) reject_unknown_key(item.key());
      it->read(c, item.key(), item.value());
    }
    // A file without "preset" starts from the paper's values but is not the paper preset: its
    // provenance (psf.h5, config.json) must not say "paper".
    if (!j.contains("preset")) c.preset = "custom";
    c.validate();
    return c;
  } catch (const InputError& e) {
    throw InputError(origin + ": " + e.what());
  }
}

SystemConfig config_from_json_file(const std::string& path) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) reject("config file", path, "no such regular file");
  std::ifstream in(path, std::ios::binary);
  if (!in) reject("config file", path, "cannot be opened for reading");
  std::string text(kMaxJsonBytes + 1, '\0');
  in.read(&text[0], static_cast<std::streamsize>(text.size()));
  if (in.bad()) reject("config file", path, "read error");
  text.resize(static_cast<std::size_t>(in.gcount()));
  return config_from_json_text(text, path);
}

std::string config_to_json_text(const SystemConfig& c) {
  nlohmann::ordered_json j;
  const std::vector<std::string> presets = preset_names();
  // "preset" only names the starting point; every key follows, so it matters only for the
  // informational SystemConfig::preset field (omitted when not a known preset, e.g. "custom").
  if (std::find(presets.begin(), presets.end(), c.preset) != presets.end()) j["preset"] = c.preset;
  for (const Field& f : fields()) {
    nlohmann::ordered_json v = f.write(c);
    if (!v.is_null()) j[f.key] = std::move(v);  // null: a key left out at its default (object_points)
  }
  return j.dump(2) + "\n";
}

}  // namespace qdo
