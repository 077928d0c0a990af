// Minimal JSON text helpers for the command-line outputs (objects are written field by field).
#pragma once

#include <string>
#include <string_view>

namespace ridgewatch::cli {

/// JSON string literal with quotes and escapes.
std::string json_string(std::string_view text);
/// Shortest round-trippable decimal for finite values (up to 17 significant digits), `null` for NaN/Inf.
std::string json_number(double value);

}  // namespace ridgewatch::cli
