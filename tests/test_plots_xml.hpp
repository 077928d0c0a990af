// Well-formedness checks for the SVG files of cli/plot_svg.hpp (tests/test_plots_*.cpp): a small
// balanced-tag checker that needs nothing, and xmllint when it is installed.
#pragma once

#include <unistd.h>

#include <cctype>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "cli_runner.hpp"

namespace ridgewatch::test {

/// Empty if `xml` is a well-formed document as far as this checker sees: every element closed in
/// order, one root element, attribute values quoted, no raw '<' in text or attributes, every '&' an
/// entity. Otherwise a description of the first problem and where it is.
inline std::string xml_problem(const std::string& xml) {
  std::vector<std::string> open;
  int roots = 0;
  std::size_t i = 0;
  auto entity_ok = [&](std::size_t at) {
    for (const char* e : {"&amp;", "&lt;", "&gt;", "&quot;", "&apos;"})
      if (xml.compare(at, std::string(e).size(), e) == 0) return true;
    return xml.compare(at, 2, "&#") == 0;
  };
  while (i < xml.size()) {
    if (xml[i] == '&' && !entity_ok(i)) return "bare '&' at " + std::to_string(i);
    if (xml[i] != '<') {
      if (xml[i] == '>') return "bare '>' at " + std::to_string(i);
      if (open.empty() && !std::isspace(static_cast<unsigned char>(xml[i]))) return "text outside the root at " + std::to_string(i);
      ++i;
      continue;
    }
    if (xml.compare(i, 5, "<?xml") == 0) {
      const auto e = xml.find("?>", i);
      if (e == std::string::npos || i != 0) return "bad XML declaration";
      i = e + 2;
      continue;
    }
    if (xml.compare(i, 9, "<!DOCTYPE") == 0) {
      const auto e = xml.find('>', i);
      if (e == std::string::npos || roots > 0) return "bad DOCTYPE";
      i = e + 1;
      continue;
    }
    if (xml.compare(i, 4, "<!--") == 0) {
      const auto e = xml.find("-->", i);
      if (e == std::string::npos) return "unclosed comment";
      i = e + 3;
      continue;
    }
    const bool closing = i + 1 < xml.size() && xml[i + 1] == '/';
    std::size_t j = i + (closing ? 2 : 1);
    std::string name;
    while (j < xml.size() && (std::isalnum(static_cast<unsigned char>(xml[j])) || xml[j] == '-' || xml[j] == ':' || xml[j] == '_')) name += xml[j++];
    if (name.empty()) return "tag without a name at " + std::to_string(i);
    // Attributes: name="value" pairs up to '>' or '/>'.
    bool self_closing = false;
    for (;;) {
      while (j < xml.size() && std::isspace(static_cast<unsigned char>(xml[j]))) ++j;
      if (j >= xml.size()) return "unterminated tag <" + name;
      if (xml[j] == '>') {
        ++j;
        break;
      }
      if (xml.compare(j, 2, "/>") == 0 && !closing) {
        self_closing = true;
        j += 2;
        break;
      }
      if (closing) return "attribute in a closing tag </" + name;
      const std::size_t a = j;
      while (j < xml.size() && xml[j] != '=' && !std::isspace(static_cast<unsigned char>(xml[j])) && xml[j] != '>') ++j;
      if (j == a || j >= xml.size() || xml[j] != '=') return "attribute without a value in <" + name + " at " + std::to_string(a);
      ++j;
      if (j >= xml.size() || (xml[j] != '"' && xml[j] != '\'')) return "unquoted attribute in <" + name;
      const char q = xml[j++];
      const std::size_t e = xml.find(q, j);
      if (e == std::string::npos) return "unterminated attribute in <" + name;
      for (std::size_t k = j; k < e; ++k) {
        if (xml[k] == '<') return "raw '<' in an attribute of <" + name;
        if (xml[k] == '&' && !entity_ok(k)) return "bare '&' in an attribute of <" + name;
      }
      j = e + 1;
    }
    if (closing) {
      if (open.empty() || open.back() != name) return "</" + name + "> does not close <" + (open.empty() ? "" : open.back()) + ">";
      open.pop_back();
    } else {
      if (open.empty() && ++roots > 1) return "second root element <" + name + ">";
      if (!self_closing) open.push_back(name);
    }
    i = j;
  }
  if (!open.empty()) return "unclosed <" + open.back() + ">";
  if (roots != 1) return "no root element";
  return "";
}

/// True when xmllint is installed (then tests also let it parse the files).
inline bool have_xmllint() { return std::system("command -v xmllint >/dev/null 2>&1") == 0; }

/// xmllint's verdict on a file: empty if well-formed, else its messages.
inline std::string xmllint_problem(const std::filesystem::path& file) {
  const auto log = std::filesystem::temp_directory_path() / ("rw-xmllint-" + std::to_string(::getpid()) + ".log");
  const int rc = std::system(("xmllint --noout " + shell_quote(file.string()) + " 2>" + shell_quote(log.string())).c_str());
  std::string msg = slurp(log);
  std::filesystem::remove(log);
  return rc == 0 ? "" : (msg.empty() ? "xmllint failed" : msg);
}

}  // namespace ridgewatch::test
