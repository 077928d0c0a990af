#include "cli/format_table.hpp"

#include <cmath>
#include <cstdio>
#include <sstream>
#include <vector>

#include <nlohmann/json.hpp>

namespace ridgewatch::cli {

namespace {

using json = nlohmann::ordered_json;

bool is_frequency_key(const std::string& key) { return key.find("hz") != std::string::npos; }

std::string scalar(const json& v, const std::string& key) {
  if (v.is_null()) return "-";
  if (v.is_boolean()) return v.get<bool>() ? "true" : "false";
  if (v.is_number_integer() || v.is_number_unsigned()) return v.dump();
  if (v.is_number_float()) return format_number(v.get<double>(), is_frequency_key(key) ? 5 : 4);
  if (v.is_string()) return v.get<std::string>();
  if (v.is_array()) {  // a short array of scalars, e.g. an interval [lo, hi]
    std::string s = "[";
    for (std::size_t i = 0; i < v.size(); ++i) s += (i ? ", " : "") + scalar(v[i], key);
    return s + "]";
  }
  return v.dump();
}

bool is_scalarish(const json& v) {
  if (!v.is_array()) return !v.is_object();
  for (const auto& e : v)
    if (e.is_object() || e.is_array()) return false;
  return v.size() <= 4;
}

bool is_table(const json& v) {
  if (!v.is_array() || v.empty()) return false;
  for (const auto& e : v)
    if (!e.is_object()) return false;
  return true;
}

bool is_matrix(const json& v) {
  if (!v.is_array() || v.empty()) return false;
  for (const auto& row : v) {
    if (!row.is_array()) return false;
    for (const auto& x : row)
      if (!x.is_number() && !x.is_null()) return false;
  }
  return true;
}

// Flattens the scalar fields of one table row (nested objects one level deep as "a.b").
void flatten(const json& obj, const std::string& prefix, std::vector<std::pair<std::string, std::string>>& cells) {
  for (auto it = obj.begin(); it != obj.end(); ++it) {
    const std::string key = prefix.empty() ? it.key() : prefix + "." + it.key();
    if (it->is_object() && prefix.empty()) {
      flatten(*it, key, cells);
    } else if (is_scalarish(*it)) {
      cells.emplace_back(key, scalar(*it, it.key()));
    }
  }
}

void write_table(std::ostream& o, const json& rows, const std::string& indent) {
  std::vector<std::string> columns;
  std::vector<std::vector<std::pair<std::string, std::string>>> cells(rows.size());
  for (std::size_t r = 0; r < rows.size(); ++r) {
    flatten(rows[r], "", cells[r]);
    for (const auto& [k, v] : cells[r]) {
      bool seen = false;
      for (const auto& c : columns) seen = seen || c == k;
      if (!seen) columns.push_back(k);
    }
  }
  std::vector<std::vector<std::string>> grid(rows.size(), std::vector<std::string>(columns.size(), ""));
  std::vector<std::size_t> width(columns.size());
  for (std::size_t c = 0; c < columns.size(); ++c) width[c] = columns[c].size();
  for (std::size_t r = 0; r < rows.size(); ++r)
    for (const auto& [k, v] : cells[r])
      for (std::size_t c = 0; c < columns.size(); ++c)
        if (columns[c] == k) {
          grid[r][c] = v;
          width[c] = std::max(width[c], v.size());
        }
  auto line = [&](const std::vector<std::string>& fields) {
    std::string s = indent;
    for (std::size_t c = 0; c < fields.size(); ++c)
      s += fields[c] + (c + 1 < fields.size() ? std::string(width[c] + 2 - fields[c].size(), ' ') : "");
    while (!s.empty() && s.back() == ' ') s.pop_back();
    o << s << "\n";
  };
  line(columns);
  for (const auto& row : grid) line(row);
}

void write_object(std::ostream& o, const json& obj, const std::string& prefix, const std::string& indent) {
  // Scalars first, so the header of a result stays together; then tables and nested sections.
  for (auto it = obj.begin(); it != obj.end(); ++it)
    if (is_scalarish(*it)) o << indent << prefix << it.key() << ": " << scalar(*it, it.key()) << "\n";
  for (auto it = obj.begin(); it != obj.end(); ++it) {
    if (is_scalarish(*it)) continue;
    const std::string key = prefix + it.key();
    if (it->is_object()) {
      write_object(o, *it, key + ".", indent);
    } else if (is_table(*it)) {
      o << "\n" << indent << key << ":\n";
      write_table(o, *it, indent + "  ");
    } else if (is_matrix(*it)) {
      o << "\n" << indent << key << ":\n";
      for (const auto& row : *it) {
        std::string s = indent + " ";
        for (const auto& x : row) {
          std::string cell = scalar(x, it.key());
          s += std::string(cell.size() < 10 ? 10 - cell.size() : 1, ' ') + cell;
        }
        o << s << "\n";
      }
    } else if (it->is_array() && it->empty()) {
      o << indent << key << ": (none)\n";
    } else {  // a long array of scalars or a mixed array: one element per line
      o << "\n" << indent << key << ":\n";
      for (const auto& e : *it) o << indent << "  " << (e.is_structured() ? e.dump() : scalar(e, it.key())) << "\n";
    }
  }
}

}  // namespace

std::string format_number(double x, int digits) {
  if (!std::isfinite(x)) return "-";
  char buf[64];
  std::snprintf(buf, sizeof buf, "%.*g", digits, x);
  return buf;
}

std::string format_table(const std::string& json_lines) {
  std::ostringstream o;
  std::istringstream in(json_lines);
  json objects = json::array();  // consecutive JSON Lines objects (analyze events) form one table
  auto flush_objects = [&] {
    if (objects.empty()) return;
    if (objects.size() == 1) {
      write_object(o, objects[0], "", "");
    } else {
      write_table(o, objects, "");
    }
    objects = json::array();
  };
  for (std::string line; std::getline(in, line);) {
    json v = json::parse(line, nullptr, false);
    if (v.is_discarded()) {
      flush_objects();
      o << line << "\n";
    } else if (v.is_object()) {
      objects.push_back(std::move(v));
    } else {
      flush_objects();
      o << scalar(v, "") << "\n";
    }
  }
  flush_objects();
  return o.str();
}

}  // namespace ridgewatch::cli
