#include <softdiff/io/yaml_tree.hpp>

#include <yaml-cpp/yaml.h>

#include <cctype>
#include <charconv>
#include <cmath>
#include <limits>

namespace softdiff::io::yaml {

const Entry* Node::find(std::string_view key) const {
  for (const Entry& e : entries)
    if (e.key == key) return &e;
  return nullptr;
}

Entry* Node::find(std::string_view key) {
  for (Entry& e : entries)
    if (e.key == key) return &e;
  return nullptr;
}

const Node* Node::get(std::string_view key) const {
  const Entry* e = find(key);
  return e ? &e->value : nullptr;
}

std::string join_path(std::string_view parent, std::string_view key) {
  std::string out(parent);
  if (!out.empty()) out += '.';
  out += key;
  return out;
}

std::string index_path(std::string_view parent, std::size_t index) {
  return std::string(parent) + "[" + std::to_string(index) + "]";
}

namespace {

constexpr int max_depth = 64;
constexpr std::size_t max_nodes = 1'000'000;  // aliases can expand a small file enormously

class Converter {
 public:
  explicit Converter(bool from_set) : from_set_(from_set) {}

  Mark mark(const YAML::Mark& m) const {
    if (from_set_) return {0, 0, true};
    if (m.is_null()) return {};
    return {m.line + 1, m.column + 1, false};
  }

  Node convert(const YAML::Node& y, const std::string& path, int depth) {
    if (++count_ > max_nodes) throw ParseError{mark(y.Mark()), path, "too many YAML nodes (aliases expanding?)"};
    if (depth > max_depth)  // no path: it would be 64 levels long
      throw ParseError{mark(y.Mark()), "", "YAML nested more than " + std::to_string(max_depth) + " levels deep (a recursive alias?)"};
    Node n;
    n.mark = mark(y.Mark());
    switch (y.Type()) {
      case YAML::NodeType::Undefined:
      case YAML::NodeType::Null:
        n.type = Node::Type::null;
        break;
      case YAML::NodeType::Scalar: {
        n.type = Node::Type::scalar;
        n.scalar = y.Scalar();
        const std::string& tag = y.Tag();
        n.quoted = tag == "!" || tag == "tag:yaml.org,2002:str";
        break;
      }
      case YAML::NodeType::Sequence:
        n.type = Node::Type::sequence;
        n.items.reserve(y.size());
        for (std::size_t i = 0; i < y.size(); ++i) n.items.push_back(convert(y[i], index_path(path, i), depth + 1));
        break;
      case YAML::NodeType::Map:
        n.type = Node::Type::map;
        for (auto it = y.begin(); it != y.end(); ++it) {
          const YAML::Node key = it->first;  // copies: the iterator's pair is a temporary
          const YAML::Node value = it->second;
          if (!key.IsScalar())
            throw ParseError{mark(key.Mark()), path, "map keys must be plain names, got " + std::string(key.IsNull() ? "an empty key" : "a list or map")};
          std::string entry_path = join_path(path, key.Scalar());
          if (const Entry* first = n.find(key.Scalar())) {
            std::string message = "duplicate key";
            if (first->key_mark.line > 0) message += " (first given at line " + std::to_string(first->key_mark.line) + ")";
            throw ParseError{mark(key.Mark()), entry_path, message};
          }
          Entry e;
          e.key = key.Scalar();
          e.key_mark = mark(key.Mark());
          e.value = convert(value, entry_path, depth + 1);
          n.entries.push_back(std::move(e));
        }
        break;
    }
    return n;
  }

 private:
  bool from_set_;
  std::size_t count_ = 0;
};

}  // namespace

Node parse(const std::string& text, bool from_set) {
  Converter converter(from_set);
  std::vector<YAML::Node> docs;
  try {
    docs = YAML::LoadAll(text);
  } catch (const YAML::ParserException& e) {
    throw ParseError{converter.mark(e.mark), "", "YAML syntax error: " + e.msg};
  } catch (const YAML::Exception& e) {
    throw ParseError{converter.mark(e.mark), "", "YAML error: " + e.msg};
  }
  if (docs.empty()) {
    Node n;
    n.mark = converter.mark(YAML::Mark{});
    return n;
  }
  if (docs.size() > 1)
    throw ParseError{converter.mark(docs[1].Mark()), "",
                     "expected one YAML document, found " + std::to_string(docs.size()) + " (separated by '---')"};
  return converter.convert(docs[0], "", 0);
}

std::string describe(const Node& node) {
  switch (node.type) {
    case Node::Type::null: return "nothing (null)";
    case Node::Type::scalar: {
      constexpr std::size_t max_shown = 60;
      const std::string text = node.scalar.size() > max_shown ? node.scalar.substr(0, max_shown) + "..." : node.scalar;
      if (node.quoted) return "\"" + text + "\" (a quoted string)";
      return "'" + text + "'";
    }
    case Node::Type::sequence:
      if (node.items.empty()) return "an empty list";
      return "a list of " + std::to_string(node.items.size()) + (node.items.size() == 1 ? " item" : " items");
    case Node::Type::map: return "a map";
  }
  return "?";
}

namespace {

// The number written in s (whole string), YAML 1.2 core style: an optional sign,
// digits with an optional fraction and exponent. Not inf/nan, not hex.
std::optional<double> parse_number(std::string_view s) {
  if (!s.empty() && s.front() == '+') s.remove_prefix(1);
  if (s.empty()) return std::nullopt;
  for (char c : s)
    if (!(std::isdigit(static_cast<unsigned char>(c)) || c == '.' || c == 'e' || c == 'E' || c == '-' || c == '+'))
      return std::nullopt;
  double v = 0;
  const auto [end, ec] = std::from_chars(s.data(), s.data() + s.size(), v, std::chars_format::general);
  if (ec != std::errc() || end != s.data() + s.size() || !std::isfinite(v)) return std::nullopt;
  return v;
}

}  // namespace

std::optional<double> to_number(const Node& node) {
  if (!node.is_scalar() || node.quoted) return std::nullopt;
  return parse_number(node.scalar);
}

std::optional<long long> to_integer(const Node& node) {
  if (!node.is_scalar() || node.quoted) return std::nullopt;
  std::string_view s = node.scalar;
  if (!s.empty() && s.front() == '+') s.remove_prefix(1);
  long long i = 0;
  const auto [end, ec] = std::from_chars(s.data(), s.data() + s.size(), i);
  if (ec == std::errc() && end == s.data() + s.size()) return i;
  const std::optional<double> v = parse_number(node.scalar);
  if (!v || *v != std::floor(*v) || std::fabs(*v) > 9.0e15) return std::nullopt;  // integral and exact in a double
  return static_cast<long long>(*v);
}

std::optional<bool> to_bool(const Node& node) {
  if (!node.is_scalar() || node.quoted) return std::nullopt;
  const std::string& s = node.scalar;
  if (s == "true" || s == "True" || s == "TRUE") return true;
  if (s == "false" || s == "False" || s == "FALSE") return false;
  return std::nullopt;
}

}  // namespace softdiff::io::yaml
