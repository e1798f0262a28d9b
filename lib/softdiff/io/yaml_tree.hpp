#pragma once
// A YAML document as plain data: the scene loader's copy of yaml-cpp's tree, so
// that yaml-cpp stays inside io/*.cpp and --set can edit the tree. Every node keeps
// its 1-based position and whether it came from the scene file or from a --set
// value; a map keeps its entries in file order with their keys' positions.
// Duplicate keys are rejected while converting (yaml-cpp keeps them silently).
#include <cstddef>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

namespace softdiff::io::yaml {

struct Mark {
  int line = 0;            // 1-based; 0 if unknown
  int column = 0;          // 1-based
  bool from_set = false;   // written by --set (then line = column = 0)
};

struct Entry;

struct Node {
  enum class Type { null, scalar, sequence, map };
  Type type = Type::null;
  std::string scalar;          // Type::scalar: the text, without quotes
  bool quoted = false;         // Type::scalar: quoted (or tagged !!str): a string, never a number
  std::vector<Node> items;     // Type::sequence
  std::vector<Entry> entries;  // Type::map, in file order, keys unique
  Mark mark;

  bool is_null() const { return type == Type::null; }
  bool is_scalar() const { return type == Type::scalar; }
  bool is_sequence() const { return type == Type::sequence; }
  bool is_map() const { return type == Type::map; }

  // Map entry / value by key (nullptr if absent or if this is not a map).
  const Entry* find(std::string_view key) const;
  Entry* find(std::string_view key);
  const Node* get(std::string_view key) const;
};

struct Entry {
  std::string key;
  Mark key_mark;
  Node value;
};

// A syntax error, a duplicate key or an unusable key: where, the tree path (may
// be empty) and the message. The caller turns it into an InputError.
struct ParseError {
  Mark mark;
  std::string path;
  std::string message;
};

// Parse one YAML document (empty text: a null node). Throws ParseError.
// from_set: the text is a --set value; every node is marked from_set.
Node parse(const std::string& text, bool from_set);

// The node as an error message shows it: 'abc', "1e5" (a quoted string), a list, a map, nothing (null).
std::string describe(const Node& node);

// Scalar readers (nullopt if the node is not of that type). Numbers follow YAML 1.2:
// plain scalars like 1, -2.5, 1.0e5, .5; quoted scalars are strings. Non-finite
// values (inf, nan) are not numbers here.
std::optional<double> to_number(const Node& node);
// An integer: a plain decimal integer, or a number with an integral value (1e3).
std::optional<long long> to_integer(const Node& node);
// true/false (also True/TRUE/False/FALSE), plain.
std::optional<bool> to_bool(const Node& node);

// Path helpers: join_path("bodies[0]", "mass") = "bodies[0].mass"; index_path("bodies", 0) = "bodies[0]".
std::string join_path(std::string_view parent, std::string_view key);
std::string index_path(std::string_view parent, std::size_t index);

}  // namespace softdiff::io::yaml
