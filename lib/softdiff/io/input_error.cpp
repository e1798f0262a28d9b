#include <softdiff/io/input_error.hpp>

#include <algorithm>
#include <cctype>
#include <numeric>
#include <sstream>

namespace softdiff::io {

void throw_input_error(const Where& where, std::string_view message) {
  std::string text = where.str();
  text += ": ";
  text += message;
  throw InputError(one_line(text));
}

std::string one_line(std::string_view text) {
  std::string out;
  out.reserve(text.size());
  for (const char c : text) {
    const auto u = static_cast<unsigned char>(c);
    if (c == '\n') {
      out += "\\n";
    } else if (c == '\t') {
      out += "\\t";
    } else if (u < 0x20 || u == 0x7f) {
      static const char hex[] = "0123456789abcdef";
      out += "\\x";
      out += hex[u >> 4];
      out += hex[u & 15];
    } else {
      out += c;
    }
  }
  return out;
}

int edit_distance(std::string_view a, std::string_view b) {
  const auto lower = [](char c) { return static_cast<char>(std::tolower(static_cast<unsigned char>(c))); };
  const size_t n = a.size(), m = b.size();
  // d[i][j]: distance between a[0, i) and b[0, j); three rows suffice for transpositions.
  std::vector<int> prev2(m + 1), prev(m + 1), cur(m + 1);
  std::iota(prev.begin(), prev.end(), 0);
  for (size_t i = 1; i <= n; ++i) {
    cur[0] = static_cast<int>(i);
    for (size_t j = 1; j <= m; ++j) {
      const int cost = lower(a[i - 1]) == lower(b[j - 1]) ? 0 : 1;
      cur[j] = std::min({prev[j] + 1, cur[j - 1] + 1, prev[j - 1] + cost});
      if (i > 1 && j > 1 && lower(a[i - 1]) == lower(b[j - 2]) && lower(a[i - 2]) == lower(b[j - 1]))
        cur[j] = std::min(cur[j], prev2[j - 2] + 1);
    }
    std::swap(prev2, prev);
    std::swap(prev, cur);
  }
  return prev[m];
}

std::optional<std::string> closest_match(std::string_view word, const std::vector<std::string>& candidates) {
  std::optional<std::string> best;
  int best_distance = 0;
  for (const std::string& c : candidates) {
    const size_t len = std::max(word.size(), c.size());
    const int limit = len <= 1 ? 0 : len <= 3 ? 1 : len <= 6 ? 2 : 3;
    const int d = edit_distance(word, c);
    if (d <= limit && (!best || d < best_distance)) {
      best = c;
      best_distance = d;
    }
  }
  if (best) return best;
  const auto starts_with = [](std::string_view s, std::string_view prefix) {
    return s.size() >= prefix.size() && edit_distance(s.substr(0, prefix.size()), prefix) == 0;
  };
  for (const std::string& c : candidates)
    if ((word.size() >= 3 && starts_with(c, word)) || (c.size() >= 3 && starts_with(word, c))) return c;
  return std::nullopt;
}

std::string join(const std::vector<std::string>& items, std::string_view separator) {
  std::string out;
  for (size_t i = 0; i < items.size(); ++i) {
    if (i) out += separator;
    out += items[i];
  }
  return out;
}

std::string format_number(double value) {
  std::ostringstream s;
  s.precision(12);
  s << value;
  return s.str();
}

}  // namespace softdiff::io
