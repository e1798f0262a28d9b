#include <softdiff/io/yaml_tree.hpp>

#include <yaml-cpp/eventhandler.h>
#include <yaml-cpp/yaml.h>

#include <cctype>
#include <charconv>
#include <cmath>
#include <limits>
#include <sstream>

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

namespace {

// Counts the documents of a YAML stream. yaml-cpp 0.7 (Debian's) loops forever,
// allocating, on some invalid input such as "\n  , a:" (found by tests/fuzz): its
// parser keeps returning a null document without consuming a token, so
// YAML::LoadAll never ends (jbeder/yaml-cpp#1040, fixed upstream after 0.7 by
// #1319). A document that is a lone null at the same place as the previous one is
// that loop: it is reported as a syntax error at that place.
class DocumentCounter : public YAML::EventHandler {
 public:
  void OnDocumentStart(const YAML::Mark& m) override {
    start_ = m;
    events_ = 0;
    null_ = false;
  }
  void OnDocumentEnd() override {}
  void OnNull(const YAML::Mark& m, YAML::anchor_t) override {
    ++events_;
    null_ = true;
    null_mark_ = m;
  }
  void OnAlias(const YAML::Mark&, YAML::anchor_t) override { ++events_; }
  void OnScalar(const YAML::Mark&, const std::string&, YAML::anchor_t, const std::string&) override { ++events_; }
  void OnSequenceStart(const YAML::Mark&, const std::string&, YAML::anchor_t, YAML::EmitterStyle::value) override {
    ++events_;
  }
  void OnSequenceEnd() override {}
  void OnMapStart(const YAML::Mark&, const std::string&, YAML::anchor_t, YAML::EmitterStyle::value) override {
    ++events_;
  }
  void OnMapEnd() override {}

  const YAML::Mark& start() const { return start_; }
  // The document was a lone null at mark m.
  bool lone_null_at(const YAML::Mark& m) const { return events_ == 1 && null_ && null_mark_.pos == m.pos; }
  bool lone_null() const { return events_ == 1 && null_; }
  const YAML::Mark& null_mark() const { return null_mark_; }

 private:
  YAML::Mark start_, null_mark_;
  int events_ = 0;
  bool null_ = false;
};

}  // namespace

Node parse(const std::string& text, bool from_set) {
  Converter converter(from_set);
  YAML::Node first;
  int documents = 0;
  YAML::Mark second;
  try {
    std::istringstream in(text);
    YAML::Parser parser(in);
    DocumentCounter counter;
    YAML::Mark previous_null;
    bool previous_lone_null = false;
    while (parser.HandleNextDocument(counter)) {
      if (previous_lone_null && counter.lone_null_at(previous_null)) {
        const auto pos = static_cast<std::size_t>(previous_null.pos);
        const std::string what = pos < text.size() ? "unexpected '" + std::string(1, text[pos]) + "'" : "unexpected input";
        throw ParseError{converter.mark(previous_null), "", "YAML syntax error: " + what};
      }
      previous_lone_null = counter.lone_null();
      previous_null = counter.null_mark();
      if (++documents == 2) second = counter.start();
    }
    if (documents > 0) first = YAML::Load(text);
  } catch (const YAML::ParserException& e) {
    throw ParseError{converter.mark(e.mark), "", "YAML syntax error: " + e.msg};
  } catch (const YAML::Exception& e) {
    throw ParseError{converter.mark(e.mark), "", "YAML error: " + e.msg};
  }
  if (documents == 0) {
    Node n;
    n.mark = converter.mark(YAML::Mark{});
    return n;
  }
  if (documents > 1)
    throw ParseError{converter.mark(second), "",
                     "expected one YAML document, found " + std::to_string(documents) + " (separated by '---')"};
  return converter.convert(first, "", 0);
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
