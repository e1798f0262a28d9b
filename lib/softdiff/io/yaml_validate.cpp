#include <softdiff/io/yaml_validate.hpp>

#include <softdiff/io/input_error.hpp>

#include <algorithm>
#include <cctype>
#include <cmath>

namespace softdiff::io::schema {

using yaml::Node;

// ---------------------------------------------------------------------------
// Spec

const Field* Spec::field(std::string_view field_name) const {
  for (const Field& f : fields)
    if (f.name == field_name) return &f;
  return nullptr;
}

std::vector<std::string> Spec::field_names() const {
  std::vector<std::string> names;
  for (const Field& f : fields) names.push_back(f.name);
  return names;
}

Range gt(double v) { return {v, std::nullopt, true, false}; }
Range ge(double v) { return {v, std::nullopt, false, false}; }
Range half_open(double lo, double hi) { return {lo, hi, false, true}; }

namespace {

std::shared_ptr<Spec> make(Kind kind, std::string expected) {
  auto s = std::make_shared<Spec>();
  s->kind = kind;
  s->expected = std::move(expected);
  return s;
}

void set_range(Spec& s, const Range& r) {
  s.min = r.min;
  s.max = r.max;
  s.min_open = r.min_open;
  s.max_open = r.max_open;
}

}  // namespace

SpecPtr number(Range range) {
  auto s = make(Kind::number, "a number");
  set_range(*s, range);
  return s;
}

SpecPtr integer(Range range, long long int_max) {
  auto s = make(Kind::integer, "an integer");
  set_range(*s, range);
  s->int_max = int_max;
  return s;
}

SpecPtr boolean() { return make(Kind::boolean, "true or false"); }

SpecPtr text(bool nonempty) {
  auto s = make(Kind::text, "a string");
  s->nonempty = nonempty;
  return s;
}

SpecPtr name() { return make(Kind::name, "a name ([A-Za-z0-9_-]+)"); }

SpecPtr choice(std::vector<std::string> choices, std::string hint,
               std::vector<std::pair<std::string, std::string>> planned_choices) {
  auto s = make(Kind::choice, "");
  s->choices = std::move(choices);
  s->planned_choices = std::move(planned_choices);
  std::vector<std::string> all = s->choices;
  for (const auto& p : s->planned_choices) all.push_back(p.first);
  s->expected = "one of: " + join(all);
  s->hint = std::move(hint);
  return s;
}

SpecPtr numbers(std::size_t count, std::string expected) {
  auto s = make(Kind::list, std::move(expected));
  s->item = number();
  s->min_items = s->max_items = count;
  return s;
}

SpecPtr vec3() { return numbers(3, "a list of 3 numbers [x, y, z]"); }

SpecPtr list(SpecPtr item, std::string expected, std::size_t min_items, bool unique, std::string item_noun) {
  auto s = make(Kind::list, std::move(expected));
  s->item = std::move(item);
  s->min_items = min_items;
  s->unique = unique;
  s->item_noun = std::move(item_noun);
  return s;
}

SpecPtr map(std::vector<Field> fields, std::string shorthand) {
  auto s = make(Kind::map, "a map");
  s->fields = std::move(fields);
  s->shorthand = std::move(shorthand);
  return s;
}

SpecPtr variants(std::string key, std::vector<std::pair<std::string, SpecPtr>> kinds) {
  auto s = make(Kind::map, "a map");
  s->variant_key = std::move(key);
  s->variants = std::move(kinds);
  return s;
}

const Spec& resolve(const Spec& spec, const yaml::Node& node) {
  if (spec.variants.empty()) return spec;
  const yaml::Node* k = node.is_map() ? node.get(spec.variant_key) : nullptr;
  if (k && k->is_scalar())
    for (const auto& [value, variant] : spec.variants)
      if (value == k->scalar) return *variant;
  return *spec.variants.front().second;
}

Field key(std::string field_name, SpecPtr spec) {
  Field f;
  f.name = std::move(field_name);
  f.spec = std::move(spec);
  return f;
}

Field required(std::string field_name, SpecPtr spec) {
  Field f = key(std::move(field_name), std::move(spec));
  f.required = true;
  return f;
}

Field planned(Field field, std::string feature, bool (*accepted)(const yaml::Node&), std::string hint) {
  field.planned = std::move(feature);
  field.accepted = accepted;
  field.planned_hint = std::move(hint);
  return field;
}

Field excludes(Field field, std::string other) {
  field.excludes = std::move(other);
  return field;
}

// ---------------------------------------------------------------------------
// Context

Where Context::where(const yaml::Mark& mark, std::string path) const {
  Where w;
  w.file = mark.from_set ? "--set" : file;
  w.line = mark.line;
  w.column = mark.column;
  w.path = std::move(path);
  return w;
}

void Context::fail(const yaml::Mark& mark, std::string path, std::string_view message) const {
  throw_input_error(where(mark, std::move(path)), message);
}

// ---------------------------------------------------------------------------
// validate

std::string range_text(const Spec& spec) {
  if (spec.min && spec.max)
    return "must be in " + std::string(spec.min_open ? "(" : "[") + format_number(*spec.min) + ", " +
           format_number(*spec.max) + (spec.max_open ? ")" : "]");
  if (spec.min) return std::string("must be ") + (spec.min_open ? "> " : ">= ") + format_number(*spec.min);
  if (spec.max) return std::string("must be ") + (spec.max_open ? "< " : "<= ") + format_number(*spec.max);
  return {};
}

namespace {

bool in_range(const Spec& spec, double v) {
  if (spec.min && (spec.min_open ? !(v > *spec.min) : !(v >= *spec.min))) return false;
  if (spec.max && (spec.max_open ? !(v < *spec.max) : !(v <= *spec.max))) return false;
  return true;
}

bool is_name(std::string_view s) {
  return !s.empty() && std::all_of(s.begin(), s.end(), [](char c) {
    return std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == '-';
  });
}

std::string expected_got(const Spec& spec, const Node& node) {
  return "expected " + spec.expected + ", got " + yaml::describe(node);
}

std::string suggestion(std::string_view word, const std::vector<std::string>& candidates) {
  const std::optional<std::string> best = closest_match(word, candidates);
  return best ? "; did you mean '" + *best + "'?" : std::string();
}

void validate_choice(const Node& node, const Spec& spec, const Context& ctx, const yaml::Mark& at,
                     const std::string& path) {
  if (!node.is_scalar()) ctx.fail(at, path, expected_got(spec, node));
  if (std::find(spec.choices.begin(), spec.choices.end(), node.scalar) != spec.choices.end()) return;
  for (const auto& [value, feature] : spec.planned_choices)
    if (value == node.scalar) ctx.fail(at, path, "'" + value + "' is not supported yet (planned: " + feature + ")");
  std::vector<std::string> all = spec.choices;
  for (const auto& p : spec.planned_choices) all.push_back(p.first);
  std::string message = "must be one of: " + join(all) + "; got " + yaml::describe(node);
  if (const auto best = closest_match(node.scalar, all)) message += " (did you mean '" + *best + "'?)";
  if (!spec.hint.empty()) message += " (" + spec.hint + ")";
  ctx.fail(at, path, message);
}

void validate_list(const Node& node, const Spec& spec, const Context& ctx, const yaml::Mark& at,
                   const std::string& path) {
  const bool fixed_length = spec.min_items == spec.max_items;
  if (node.is_null() && !fixed_length) {
    if (spec.min_items > 0) ctx.fail(at, path, "must not be empty");
    return;
  }
  if (!node.is_sequence()) ctx.fail(at, path, expected_got(spec, node));
  const std::size_t n = node.items.size();
  if (fixed_length && n != spec.min_items) ctx.fail(at, path, expected_got(spec, node));
  if (n < spec.min_items) ctx.fail(at, path, spec.min_items == 1 ? std::string("must not be empty") : expected_got(spec, node));
  if (n > spec.max_items) ctx.fail(at, path, expected_got(spec, node));
  for (std::size_t i = 0; i < n; ++i) {
    const Node& item = node.items[i];
    const std::string item_path = yaml::index_path(path, i);
    validate(item, *spec.item, ctx, item.mark, item_path);
    if (spec.unique && item.is_scalar())
      for (std::size_t j = 0; j < i; ++j)
        if (node.items[j].is_scalar() && node.items[j].scalar == item.scalar)
          ctx.fail(item.mark, item_path, "duplicate entry '" + item.scalar + "' (also at index " + std::to_string(j) + ")");
  }
}

void validate_map(const Node& node, const Spec& spec, const Context& ctx, const yaml::Mark& at,
                  const std::string& path) {
  if (node.is_scalar() && !spec.shorthand.empty()) {
    const Field* f = spec.field(spec.shorthand);
    validate(node, *f->spec, ctx, at, path);
    return;
  }
  if (node.is_null()) {
    for (const Field& f : spec.fields)
      if (f.required) ctx.fail(at, path, "missing required key '" + f.name + "'");
    return;
  }
  if (!node.is_map()) {
    std::string expected = "expected a map";
    if (!spec.shorthand.empty()) expected += " or " + spec.field(spec.shorthand)->spec->expected;
    ctx.fail(at, path, expected + ", got " + yaml::describe(node));
  }
  for (const yaml::Entry& e : node.entries) {
    const std::string entry_path = yaml::join_path(path, e.key);
    const Field* f = spec.field(e.key);
    if (!f) {
      std::string message = "unknown key";
      const std::string hint = suggestion(e.key, spec.field_names());
      message += hint.empty() ? " (valid keys: " + join(spec.field_names()) + ")" : hint;
      ctx.fail(e.key_mark, entry_path, message);
    }
    if (!f->planned.empty() && !(f->accepted && f->accepted(e.value))) {
      std::string message = "not supported yet (planned: " + f->planned + ")";
      if (!f->planned_hint.empty()) message += "; " + f->planned_hint;
      ctx.fail(e.key_mark, entry_path, message);
    }
    validate(e.value, *f->spec, ctx, e.key_mark, entry_path);
  }
  for (const Field& f : spec.fields)
    if (f.required && !node.find(f.name)) ctx.fail(at, path, "missing required key '" + f.name + "'");
}

}  // namespace

void validate(const Node& node, const Spec& given, const Context& ctx, const yaml::Mark& at, const std::string& path) {
  const Spec& spec = resolve(given, node);
  switch (spec.kind) {
    case Kind::map: validate_map(node, spec, ctx, at, path); return;
    case Kind::list: validate_list(node, spec, ctx, at, path); return;
    case Kind::number: {
      if (spec.or_sequence && node.is_sequence()) {
        validate(node, *spec.or_sequence, ctx, at, path);
        return;
      }
      if (node.is_scalar() && !node.quoted && !yaml::to_number(node)) {
        std::string lower = node.scalar;
        for (char& c : lower) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
        if (lower.find("inf") != std::string::npos || lower.find("nan") != std::string::npos)
          ctx.fail(at, path, "expected a finite number, got " + yaml::describe(node));
      }
      const std::optional<double> v = yaml::to_number(node);
      if (!v) ctx.fail(at, path, expected_got(spec, node));
      if (!in_range(spec, *v)) ctx.fail(at, path, range_text(spec) + ", got " + node.scalar);
      return;
    }
    case Kind::integer: {
      const std::optional<long long> v = yaml::to_integer(node);
      if (!v) {
        const std::optional<double> d = yaml::to_number(node);
        if (d && *d == std::floor(*d))  // an integer too large for a long long
          ctx.fail(at, path,
                   (*d > 0                    ? "must be <= " + std::to_string(spec.int_max)
                    : range_text(spec).empty() ? "must be >= " + std::to_string(LLONG_MIN)
                                               : range_text(spec)) +
                       ", got " + node.scalar);
        ctx.fail(at, path, expected_got(spec, node));
      }
      if (!in_range(spec, static_cast<double>(*v))) ctx.fail(at, path, range_text(spec) + ", got " + node.scalar);
      if (*v > spec.int_max) ctx.fail(at, path, "must be <= " + std::to_string(spec.int_max) + ", got " + node.scalar);
      return;
    }
    case Kind::boolean:
      if (!yaml::to_bool(node)) ctx.fail(at, path, expected_got(spec, node));
      return;
    case Kind::text:
      if (!node.is_scalar()) ctx.fail(at, path, expected_got(spec, node));
      if (spec.nonempty && node.scalar.empty()) ctx.fail(at, path, "must not be empty");
      return;
    case Kind::name:
      if (!node.is_scalar()) ctx.fail(at, path, expected_got(spec, node));
      if (!is_name(node.scalar))
        ctx.fail(at, path, "must be a name of letters, digits, '_' and '-' ([A-Za-z0-9_-]+), got " + yaml::describe(node));
      return;
    case Kind::choice: validate_choice(node, spec, ctx, at, path); return;
  }
}

// ---------------------------------------------------------------------------
// --set

namespace {

bool is_index(std::string_view s) {
  return !s.empty() && s.size() < 10 && std::all_of(s.begin(), s.end(), [](char c) { return c >= '0' && c <= '9'; });
}

std::string trim(std::string_view s) {
  while (!s.empty() && std::isspace(static_cast<unsigned char>(s.front()))) s.remove_prefix(1);
  while (!s.empty() && std::isspace(static_cast<unsigned char>(s.back()))) s.remove_suffix(1);
  return std::string(s);
}

// "bodies[0].material.young" -> {bodies, 0, material, young}; empty components are kept (an error).
std::vector<std::string> split_key(std::string_view key) {
  std::vector<std::string> parts(1);
  for (std::size_t i = 0; i < key.size(); ++i) {
    const char c = key[i];
    if (c == '.') {
      parts.emplace_back();
    } else if (c == '[') {
      if (!parts.back().empty() || i == 0) parts.emplace_back();
    } else if (c == ']') {
      // "[0]" closes an index; "[0]." continues with a '.'
      if (i + 1 < key.size() && key[i + 1] == '.') ++i, parts.emplace_back();
      else if (i + 1 < key.size() && key[i + 1] != '[') parts.emplace_back();
    } else {
      parts.back() += c;
    }
  }
  return parts;
}

[[noreturn]] void set_error(const std::string& prefix, const std::string& message) {
  throw InputError(one_line(prefix + message));
}

std::string item_name(const Node& item) {
  const Node* n = item.is_map() ? item.get("name") : nullptr;
  return n && n->is_scalar() ? n->scalar : std::string();
}

}  // namespace

void apply_override(Node& root, const Spec& root_spec, std::string_view assignment) {
  const std::size_t eq = assignment.find('=');
  if (eq == std::string_view::npos)
    throw InputError(one_line("--set " + std::string(assignment) + ": expected KEY=VALUE (e.g. bodies.beam.material.young=2e5)"));
  const std::string key = trim(assignment.substr(0, eq));
  const std::string value_text(assignment.substr(eq + 1));
  const std::string prefix = "--set " + key + ": ";
  const auto fail = [&prefix](const std::string& message) { set_error(prefix, message); };

  const std::vector<std::string> parts = split_key(key);
  for (const std::string& p : parts)
    if (p.empty()) fail("empty key component (KEY is a dotted path, e.g. simulation.dt)");

  Node value;
  try {
    value = yaml::parse(value_text, true);
  } catch (const yaml::ParseError& e) {
    fail("invalid YAML value '" + value_text + "': " + e.message);
  }
  const yaml::Mark set_mark{0, 0, true};

  Node* node = &root;
  const Spec* spec = &root_spec;
  std::string walked;  // the dotted key so far, for messages
  for (std::size_t i = 0; i < parts.size(); ++i) {
    const std::string& part = parts[i];
    const bool last = i + 1 == parts.size();
    const std::string here = walked.empty() ? std::string("the scene") : "'" + walked + "'";
    spec = &resolve(*spec, *node);
    if (spec->kind == Kind::map) {
      if (node->is_scalar() && !spec->shorthand.empty()) {  // linear_solver: cg -> {type: cg}
        Node expanded;
        expanded.type = Node::Type::map;
        expanded.mark = node->mark;
        expanded.entries.push_back(yaml::Entry{spec->shorthand, node->mark, *node});
        *node = std::move(expanded);
      }
      if (node->is_null()) {
        node->type = Node::Type::map;
        node->mark = set_mark;
      }
      if (!node->is_map()) fail("cannot set '" + part + "': " + here + " is " + yaml::describe(*node) + " in the scene, not a map");
      const Field* f = spec->field(part);
      if (!f) {
        const std::vector<std::string> names = spec->field_names();
        const std::string hint = suggestion(part, names);
        fail("unknown key '" + part + "'" + (hint.empty() ? " (valid keys" + (walked.empty() ? "" : " of " + here) + ": " + join(names) + ")" : hint));
      }
      yaml::Entry* e = node->find(part);
      if (last) {
        if (value.is_null()) {
          if (e) node->entries.erase(node->entries.begin() + (e - node->entries.data()));
          return;
        }
        if (!e) {
          node->entries.push_back(yaml::Entry{part, set_mark, Node{}});
          e = &node->entries.back();
        }
        e->key_mark = set_mark;
        e->value = std::move(value);
        if (!f->excludes.empty())
          if (const yaml::Entry* other = node->find(f->excludes))
            node->entries.erase(node->entries.begin() + (other - node->entries.data()));
        return;
      }
      if (!e) {
        Node empty;
        empty.mark = set_mark;
        node->entries.push_back(yaml::Entry{part, set_mark, std::move(empty)});
        e = &node->entries.back();
      }
      node = &e->value;
      spec = f->spec.get();
    } else if (spec->kind == Kind::list) {
      if (node->is_null())
        fail(here + " is not in the scene; set the whole list (" + walked + "=[...])");
      if (!node->is_sequence())
        fail("cannot set '" + part + "': " + here + " is " + yaml::describe(*node) + " in the scene, not a list");
      const std::size_t size = node->items.size();
      Node* item = nullptr;
      if (!spec->item_noun.empty()) {
        for (Node& candidate : node->items)
          if (item_name(candidate) == part) item = &candidate;
        if (!item && !is_index(part)) {
          std::vector<std::string> names;
          for (const Node& candidate : node->items) names.push_back(item_name(candidate));
          std::string message = "no " + spec->item_noun + " named '" + part + "' (" + walked + ": " +
                                (names.empty() ? std::string("none") : join(names)) + ")";
          fail(message);
        }
      }
      if (!item) {
        if (!is_index(part)) fail("'" + part + "' is not an index into " + here + " (a list)");
        const std::size_t index = std::stoul(part);
        if (index >= size)
          fail("index " + part + " out of range (" + here + " has " + std::to_string(size) + (size == 1 ? " item)" : " items)"));
        item = &node->items[index];
      }
      if (last) {
        if (value.is_null()) fail("cannot remove a list item (null); set the whole list instead");
        *item = std::move(value);
        return;
      }
      node = item;
      spec = spec->item.get();
    } else {
      fail("cannot set '" + part + "': " + here + " is " + spec->expected + ", not a map or a list");
    }
    walked = walked.empty() ? part : walked + "." + part;
  }
}

}  // namespace softdiff::io::schema
