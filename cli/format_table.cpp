#include "cli/format_table.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <sstream>
#include <vector>

#include <nlohmann/json.hpp>

namespace ridgewatch::cli {

namespace {

using json = nlohmann::ordered_json;

// A frequency (f_hz, band_hz, sample_rate_hz) gets 5 digits (0.02 % of 854 Hz is 0.17 Hz); its
// standard deviation (f_sd_hz) does not need them.
bool is_frequency_key(const std::string& key) {
  return key.find("hz") != std::string::npos && key.find("sd") == std::string::npos;
}

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

// Flattens the scalar fields of one table row; a nested object's fields become columns of their own,
// named by their key ("parent.key" only when the row has a field of that name already).
void flatten(const json& obj, const std::string& prefix, std::vector<std::pair<std::string, std::string>>& cells,
             const json* top = nullptr) {
  for (auto it = obj.begin(); it != obj.end(); ++it) {
    const bool clash = top != nullptr && top->contains(it.key());
    const std::string key = prefix.empty() || !clash ? it.key() : prefix + "." + it.key();
    if (it->is_object() && prefix.empty()) {
      flatten(*it, it.key(), cells, &obj);
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
  // Columns of long text (evidence, notes) would make every row as wide as the longest sentence: they
  // leave the table and follow it as "[row] column: text" lines. Names (the source file, a stream) stay
  // columns whatever their length: a long path is an identifier, not prose.
  constexpr std::size_t kLongText = 40;
  const auto is_name = [](const std::string& c) { return c == "source" || c == "file" || c == "stream"; };
  std::vector<std::string> long_columns;
  for (const auto& c : columns)
    for (const auto& row : cells)
      for (const auto& [k, v] : row)
        if (k == c && !is_name(c) && v.size() > kLongText && std::find(long_columns.begin(), long_columns.end(), c) == long_columns.end())
          long_columns.push_back(c);
  std::erase_if(columns, [&](const std::string& c) {
    return std::find(long_columns.begin(), long_columns.end(), c) != long_columns.end();
  });
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
  std::vector<std::string> header = columns;
  if (!long_columns.empty()) {  // a row number to refer to
    header.insert(header.begin(), "#");
    width.insert(width.begin(), std::to_string(rows.size()).size());
  }
  line(header);
  for (std::size_t r = 0; r < grid.size(); ++r) {
    if (!long_columns.empty()) grid[r].insert(grid[r].begin(), std::to_string(r + 1));
    line(grid[r]);
  }
  for (std::size_t r = 0; r < rows.size(); ++r)
    for (const auto& c : long_columns)
      for (const auto& [k, v] : cells[r])
        if (k == c && !v.empty()) o << indent << "[" << r + 1 << "] " << c << ": " << v << "\n";
}

// An object of equal-length arrays of scalars (nested objects of such arrays included), e.g. a
// backbone {amplitude_rel: [...], measured: {f_hz: [...], zeta: [...]}}: its columns, or false.
bool columns_of(const json& obj, const std::string& prefix, std::vector<std::pair<std::string, const json*>>& cols,
                std::size_t& rows) {
  for (auto it = obj.begin(); it != obj.end(); ++it) {
    const std::string key = prefix.empty() ? it.key() : prefix + "." + it.key();
    if (it->is_object()) {
      if (!columns_of(*it, key, cols, rows)) return false;
      continue;
    }
    if (!it->is_array() || it->size() <= 4) return false;
    for (const auto& x : *it)
      if (x.is_structured()) return false;
    if (rows != 0 && it->size() != rows) return false;
    rows = it->size();
    cols.emplace_back(key, &*it);
  }
  return !cols.empty();
}

void write_columns(std::ostream& o, const std::vector<std::pair<std::string, const json*>>& cols, std::size_t rows,
                   const std::string& indent) {
  json table = json::array();
  for (std::size_t r = 0; r < rows; ++r) {
    json row = json::object();
    for (const auto& [name, values] : cols) row[name] = (*values)[r];
    table.push_back(std::move(row));
  }
  write_table(o, table, indent);
}

void write_object(std::ostream& o, const json& obj, const std::string& prefix, const std::string& indent) {
  // Scalars first, so the header of a result stays together; then tables and nested sections.
  for (auto it = obj.begin(); it != obj.end(); ++it)
    if (is_scalarish(*it)) o << indent << prefix << it.key() << ": " << scalar(*it, it.key()) << "\n";
  for (auto it = obj.begin(); it != obj.end(); ++it) {
    if (is_scalarish(*it)) continue;
    const std::string key = prefix + it.key();
    std::vector<std::pair<std::string, const json*>> cols;
    std::size_t rows = 0;
    if (it->is_object() && columns_of(*it, "", cols, rows)) {
      o << "\n" << indent << key << ":\n";
      write_columns(o, cols, rows, indent + "  ");
    } else if (it->is_object()) {
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
    } else if (std::none_of(it->begin(), it->end(), [](const json& e) { return e.is_structured(); })) {
      // A long array of scalars (a spectrum, a time series): wrapped lines of values.
      o << "\n" << indent << key << ":\n";
      std::string line = indent + " ";
      for (const auto& e : *it) {
        const std::string cell = " " + scalar(e, it.key());
        if (line.size() + cell.size() > 100 && line.size() > indent.size() + 1) {
          o << line << "\n";
          line = indent + " ";
        }
        line += cell;
      }
      o << line << "\n";
    } else {  // a mixed array: one element per line
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
