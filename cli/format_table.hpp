// `--format table` for analyze, modes, compare and diagnose: renders the command's JSON output (one
// JSON value per line) as aligned text. Generic over the JSON, so fields the commands add later show
// up without a change here.
//   - scalars of an object: "key: value" lines (nested objects as "parent.key");
//   - an array of objects (modes, parameters, steps, the events of analyze): one table, a column per
//     scalar key (in order of first appearance; the fields of a nested object as columns of their
//     own), a row per element;
//   - an array of arrays of numbers (a correlation matrix): rows of numbers.
// Numbers: 5 significant digits for keys naming a frequency (…hz…, not …sd…), 4 otherwise, integers as they
// are; null prints as "-".
#pragma once

#include <string>

namespace ridgewatch::cli {

/// `json_lines`: one JSON value per line (what the commands print). Lines that are not JSON are
/// passed through unchanged.
std::string format_table(const std::string& json_lines);

/// A number with `digits` significant digits in the shortest of fixed/scientific notation.
std::string format_number(double x, int digits);

}  // namespace ridgewatch::cli
