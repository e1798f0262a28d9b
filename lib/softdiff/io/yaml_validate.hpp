#pragma once
// Table-driven validation of a YAML tree. A Spec describes what a node may be (a
// map with known fields, a list, a number in a range, one of some names, ...);
// the same description drives
//   - validate(): types, ranges, list lengths, enum values, unknown keys (with
//     the closest valid key), required keys, features not supported yet;
//   - apply_override(): --set KEY=VALUE, where KEY is checked against the Spec
//     (with suggestions) and list items of named maps are addressed by name.
// Checks that relate several keys (exactly one of steps/duration, ...) are left
// to the caller, which reads the validated tree.
#include <softdiff/io/scene.hpp>
#include <softdiff/io/yaml_tree.hpp>

#include <climits>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

namespace softdiff::io::schema {

enum class Kind {
  map,      // fields (unknown keys are errors); null counts as an empty map
  list,     // items of one Spec; null counts as an empty list unless the length is fixed
  number,   // finite, plain (not quoted)
  integer,  // number with an integral value
  boolean,  // true/false
  text,     // any scalar (a plain number is text too)
  name,     // [A-Za-z0-9_-]+
  choice,   // one of `choices`
};

struct Spec;
using SpecPtr = std::shared_ptr<const Spec>;

struct Field {
  std::string name;
  SpecPtr spec;
  bool required = false;
  // A key of the format whose feature is not implemented yet: present, it is an
  // error "not supported yet (planned: <planned>)" unless accepted(value) (e.g. an
  // empty list, or contact with enabled: false).
  std::string planned;
  bool (*accepted)(const yaml::Node&) = nullptr;
  std::string planned_hint;  // appended to that error
  // --set: giving this key removes that one (steps <-> duration).
  std::string excludes;
};

struct Spec {
  Kind kind = Kind::text;
  std::string expected;  // for "expected <expected>, got ...": "a number", "a list of 3 numbers [x, y, z]"
  // number, integer: the valid range (message "must be > 0", "must be in [0, 0.5)")
  std::optional<double> min, max;
  // number: a sequence is validated against this instead (a plane's offset: a number or
  // a schedule [[t, offset], ...]); null: numbers only.
  SpecPtr or_sequence;
  bool min_open = false, max_open = false;
  long long int_max = INT_MAX;  // integer: what the C++ field holds
  // choice
  std::vector<std::string> choices;
  std::vector<std::pair<std::string, std::string>> planned_choices;  // value, feature: "not supported yet"
  std::string hint;  // appended to a bad choice
  // text
  bool nonempty = false;
  // list
  SpecPtr item;
  std::size_t min_items = 0, max_items = SIZE_MAX;
  bool unique = false;     // scalar items must differ
  std::string item_noun;   // items are maps with a unique `name`; --set may address them by it ("body")
  // map
  std::vector<Field> fields;
  std::string shorthand;   // a scalar value stands for {shorthand: value} (linear_solver: cg)
  // A map whose keys depend on the value of one of them (bodies: `type: soft | rigid`):
  // the variant named by the node's `variant_key` (a scalar), else the first one.
  // validate() and apply_override() use the variant that resolve() picks.
  std::string variant_key;
  std::vector<std::pair<std::string, SpecPtr>> variants;

  const Field* field(std::string_view name) const;
  std::vector<std::string> field_names() const;
};

// Builders for schema tables.
struct Range {
  std::optional<double> min, max;
  bool min_open = false, max_open = false;
};
Range gt(double v);                  // > v
Range ge(double v);                  // >= v
Range half_open(double lo, double hi);  // [lo, hi)
SpecPtr number(Range range = {});
SpecPtr integer(Range range = {}, long long int_max = INT_MAX);
SpecPtr boolean();
SpecPtr text(bool nonempty = false);
SpecPtr name();
SpecPtr choice(std::vector<std::string> choices, std::string hint = {},
               std::vector<std::pair<std::string, std::string>> planned_choices = {});
SpecPtr numbers(std::size_t count, std::string expected);  // fixed-length list of numbers
SpecPtr vec3();                                             // [x, y, z]
// A list of `item`s; `expected` names it in messages ("a list of node indices");
// item_noun: the items are maps with a unique `name` that --set can use ("body").
SpecPtr list(SpecPtr item, std::string expected = "a list", std::size_t min_items = 0, bool unique = false,
             std::string item_noun = {});
SpecPtr map(std::vector<Field> fields, std::string shorthand = {});
// A map of one of several kinds, chosen by the value of `key` (the first kind when the
// key is absent or names none of them; its own `key` field then reports a bad value).
SpecPtr variants(std::string key, std::vector<std::pair<std::string, SpecPtr>> kinds);
// The Spec that applies to `node`: spec itself, or the variant the node names.
const Spec& resolve(const Spec& spec, const yaml::Node& node);

// Fields of a map.
Field key(std::string name, SpecPtr spec);       // optional
Field required(std::string name, SpecPtr spec);  // must be present
// `field` is part of the format but its feature is not implemented: an error
// "not supported yet (planned: <feature>)" unless accepted(value); hint is appended.
Field planned(Field field, std::string feature, bool (*accepted)(const yaml::Node&) = nullptr, std::string hint = {});
// --set: giving `field` removes `other` (and, declared on both, the reverse).
Field excludes(Field field, std::string other);

// Where errors point: the scene file (or "--set" for values given by --set).
struct Context {
  std::string file;  // the scene file as the user named it
  Where where(const yaml::Mark& mark, std::string path) const;
  [[noreturn]] void fail(const yaml::Mark& mark, std::string path, std::string_view message) const;
};

// Validates `node` against `spec`; throws InputError. `at` is where to point for
// the node as a whole (its key, for a map value), `path` its tree path.
void validate(const yaml::Node& node, const Spec& spec, const Context& ctx, const yaml::Mark& at,
              const std::string& path);

// "must be > 0" / "must be in [0, 0.5)" for a number or integer Spec.
std::string range_text(const Spec& spec);

// Applies one --set KEY=VALUE to the tree (before validation). KEY is a dotted
// path (bodies.beam.material.young, bodies.0.mesh, also bodies[0].mesh); VALUE is
// YAML. A key absent from the tree but known to the schema is created; VALUE null
// (or ~, or empty) removes the key. Throws InputError "--set KEY: message".
void apply_override(yaml::Node& root, const Spec& root_spec, std::string_view assignment);

}  // namespace softdiff::io::schema
