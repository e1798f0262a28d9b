#pragma once
// Building InputError messages: one line `FILE:LINE:COL: PATH: message`, and the
// "did you mean" suggestion for a misspelt key or value.
#include <softdiff/core/error.hpp>
#include <softdiff/io/scene.hpp>

#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace softdiff::io {

// Throws InputError("<where.str()>: <message>"), made one line (see one_line).
[[noreturn]] void throw_input_error(const Where& where, std::string_view message);

// Control characters (a newline in a quoted YAML key or value, say) escaped as
// \n, \t, \xHH, so that every message is one line.
std::string one_line(std::string_view text);

// Optimal-string-alignment (Damerau-Levenshtein) distance, case-insensitive.
int edit_distance(std::string_view a, std::string_view b);

// The candidate closest to `word`, if it is close enough to be a plausible
// misspelling: edit distance <= 1 for words up to 3 characters, <= 2 up to 6,
// <= 3 beyond (single letters only differ by case); failing that, a candidate
// that `word` is a prefix of (or the reverse), for words of 3+ characters.
std::optional<std::string> closest_match(std::string_view word, const std::vector<std::string>& candidates);

// "a, b, c"
std::string join(const std::vector<std::string>& items, std::string_view separator = ", ");

// A double as short as it reads: 0.5, 1e-10, 200000.
std::string format_number(double value);

}  // namespace softdiff::io
