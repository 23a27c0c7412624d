// The texts of an SVG figure (figure.hpp writes every text as a <text> element), for tests that
// check what a figure says: its title, axis labels, legend entries.
#pragma once
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

namespace qdo::test {

inline void append_utf8(std::string& out, unsigned long cp) {
  if (cp < 0x80) {
    out += static_cast<char>(cp);
  } else if (cp < 0x800) {
    out += static_cast<char>(0xC0 | (cp >> 6));
    out += static_cast<char>(0x80 | (cp & 0x3F));
  } else if (cp < 0x10000) {
    out += static_cast<char>(0xE0 | (cp >> 12));
    out += static_cast<char>(0x80 | ((cp >> 6) & 0x3F));
    out += static_cast<char>(0x80 | (cp & 0x3F));
  } else {
    out += static_cast<char>(0xF0 | (cp >> 18));
    out += static_cast<char>(0x80 | ((cp >> 12) & 0x3F));
    out += static_cast<char>(0x80 | ((cp >> 6) & 0x3F));
    out += static_cast<char>(0x80 | (cp & 0x3F));
  }
}

// XML character data with its references (&#x..;, &#..;, &amp; ...) decoded to UTF-8.
inline std::string xml_decode(const std::string& s) {
  std::string out;
  for (std::size_t i = 0; i < s.size(); ++i) {
    if (s[i] != '&') {
      out += s[i];
      continue;
    }
    const std::size_t end = s.find(';', i);
    if (end == std::string::npos) {
      out += s.substr(i);
      break;
    }
    const std::string ref = s.substr(i + 1, end - i - 1);
    if (ref.size() > 2 && ref[0] == '#' && (ref[1] == 'x' || ref[1] == 'X'))
      append_utf8(out, std::stoul(ref.substr(2), nullptr, 16));
    else if (ref.size() > 1 && ref[0] == '#')
      append_utf8(out, std::stoul(ref.substr(1)));
    else if (ref == "amp")
      out += '&';
    else if (ref == "lt")
      out += '<';
    else if (ref == "gt")
      out += '>';
    else if (ref == "quot")
      out += '"';
    else if (ref == "apos")
      out += '\'';
    else
      out += "&" + ref + ";";
    i = end;
  }
  return out;
}

// The text of each <text> element of an SVG file: its character data with the nested tags
// (PLplot's <tspan> runs for fonts, super- and subscripts) removed, references decoded.
inline std::vector<std::string> svg_texts(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream ss;
  ss << in.rdbuf();
  const std::string svg = ss.str();
  std::vector<std::string> texts;
  std::size_t pos = 0;
  while ((pos = svg.find("<text", pos)) != std::string::npos) {
    const std::size_t open_end = svg.find('>', pos);
    const std::size_t close = svg.find("</text>", pos);
    if (open_end == std::string::npos || close == std::string::npos) break;
    std::string inner;
    bool in_tag = false;
    for (std::size_t i = open_end + 1; i < close; ++i) {
      if (svg[i] == '<')
        in_tag = true;
      else if (svg[i] == '>')
        in_tag = false;
      else if (!in_tag)
        inner += svg[i];
    }
    texts.push_back(xml_decode(inner));
    pos = close + 7;
  }
  return texts;
}

// Whether `texts` (svg_texts) holds an element containing `part`.
inline bool svg_has(const std::vector<std::string>& texts, const std::string& part) {
  for (const std::string& t : texts)
    if (t.find(part) != std::string::npos) return true;
  return false;
}

}  // namespace qdo::test
