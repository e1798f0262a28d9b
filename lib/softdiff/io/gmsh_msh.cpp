// Reader for Gmsh MSH 2.2 and 4.1 files, ASCII and binary (see gmsh_msh.hpp).
//
// The whole file is read into memory. A Parser walks it once and fills a
// RawMesh: nodes in file order, the elements we keep (tets, triangles, and the
// nodes of points and lines) with their nodes as *file indices*, and which
// physical tag (MSH 2) or entity (MSH 4) each run of elements belongs to.
// build_mesh() then turns that into a cleaned TetMesh.
//
// Robustness: the input may be malformed or hostile. Every read is bounds
// checked, every count is checked against the bytes left in the file before
// anything is allocated for it, and every problem is an InputError that says
// where (`FILE:LINE:` in text, `FILE: byte N:` in binary data), what was
// expected and what was found. Positions are byte offsets; line numbers are
// only computed when an error is reported, so the hot loops do not track them.
// Numbers are parsed with std::from_chars straight from the buffer.
#include <softdiff/io/gmsh_msh.hpp>
#include <softdiff/core/format.hpp>

#include <softdiff/core/error.hpp>
#include <softdiff/fem/tet10.hpp>

#include <Eigen/Geometry>

#include <algorithm>
#include <array>
#include <cerrno>
#include <charconv>
#include <cctype>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <map>
#include <memory>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

namespace softdiff::io {
namespace {

using mesh::PhysicalGroup;
using mesh::TetMesh;

constexpr std::size_t kNoPos = std::numeric_limits<std::size_t>::max();
constexpr long kMaxTag = std::numeric_limits<long>::max();
constexpr std::uint64_t kMaxCount = static_cast<std::uint64_t>(std::numeric_limits<int>::max());

// ---------------------------------------------------------------------------
// Gmsh element types (numbering of Gmsh's GmshDefines.h).

enum class Family : unsigned char {
  point, line, triangle, quadrangle, polygon,                                  // 0D-2D
  tetrahedron, hexahedron, prism, pyramid, trihedron, polyhedron               // 3D
};

struct TypeInfo {
  int dim = -1;    // -1: not a Gmsh element type
  int nodes = 0;   // 0: no fixed node count (polygons, sub-elements, ...): cannot be read
  Family family = Family::point;
};

constexpr int kMaxType = 140;

const std::array<TypeInfo, kMaxType + 1>& type_table() {
  static const std::array<TypeInfo, kMaxType + 1> table = [] {
    using F = Family;
    struct Row {
      int type;
      F family;
      int nodes;
    };
    static constexpr Row rows[] = {
        {1, F::line, 2},           {2, F::triangle, 3},       {3, F::quadrangle, 4},     {4, F::tetrahedron, 4},
        {5, F::hexahedron, 8},     {6, F::prism, 6},          {7, F::pyramid, 5},        {8, F::line, 3},
        {9, F::triangle, 6},       {10, F::quadrangle, 9},    {11, F::tetrahedron, 10},  {12, F::hexahedron, 27},
        {13, F::prism, 18},        {14, F::pyramid, 14},      {15, F::point, 1},         {16, F::quadrangle, 8},
        {17, F::hexahedron, 20},   {18, F::prism, 15},        {19, F::pyramid, 13},      {20, F::triangle, 9},
        {21, F::triangle, 10},     {22, F::triangle, 12},     {23, F::triangle, 15},     {24, F::triangle, 15},
        {25, F::triangle, 21},     {26, F::line, 4},          {27, F::line, 5},          {28, F::line, 6},
        {29, F::tetrahedron, 20},  {30, F::tetrahedron, 35},  {31, F::tetrahedron, 56},  {32, F::tetrahedron, 22},
        {33, F::tetrahedron, 28},  {34, F::polygon, 0},       {35, F::polyhedron, 0},    {36, F::quadrangle, 16},
        {37, F::quadrangle, 25},   {38, F::quadrangle, 36},   {39, F::quadrangle, 12},   {40, F::quadrangle, 16},
        {41, F::quadrangle, 20},   {42, F::triangle, 28},     {43, F::triangle, 36},     {44, F::triangle, 45},
        {45, F::triangle, 55},     {46, F::triangle, 66},     {47, F::quadrangle, 49},   {48, F::quadrangle, 64},
        {49, F::quadrangle, 81},   {50, F::quadrangle, 100},  {51, F::quadrangle, 121},  {52, F::triangle, 18},
        {53, F::triangle, 21},     {54, F::triangle, 24},     {55, F::triangle, 27},     {56, F::triangle, 30},
        {57, F::quadrangle, 24},   {58, F::quadrangle, 28},   {59, F::quadrangle, 32},   {60, F::quadrangle, 36},
        {61, F::quadrangle, 40},   {62, F::line, 7},          {63, F::line, 8},          {64, F::line, 9},
        {65, F::line, 10},         {66, F::line, 11},         {67, F::line, 0},          {68, F::triangle, 0},
        {69, F::polygon, 0},       {70, F::line, 0},          {71, F::tetrahedron, 84},  {72, F::tetrahedron, 120},
        {73, F::tetrahedron, 165}, {74, F::tetrahedron, 220}, {75, F::tetrahedron, 286}, {79, F::tetrahedron, 34},
        {80, F::tetrahedron, 40},  {81, F::tetrahedron, 46},  {82, F::tetrahedron, 52},  {83, F::tetrahedron, 58},
        {84, F::line, 1},          {85, F::triangle, 1},      {86, F::quadrangle, 1},    {87, F::tetrahedron, 1},
        {88, F::hexahedron, 1},    {89, F::prism, 1},         {90, F::prism, 40},        {91, F::prism, 75},
        {92, F::hexahedron, 64},   {93, F::hexahedron, 125},  {94, F::hexahedron, 216},  {95, F::hexahedron, 343},
        {96, F::hexahedron, 512},  {97, F::hexahedron, 729},  {98, F::hexahedron, 1000}, {99, F::hexahedron, 32},
        {100, F::hexahedron, 44},  {101, F::hexahedron, 56},  {102, F::hexahedron, 68},  {103, F::hexahedron, 80},
        {104, F::hexahedron, 92},  {105, F::hexahedron, 104}, {106, F::prism, 126},      {107, F::prism, 196},
        {108, F::prism, 288},      {109, F::prism, 405},      {110, F::prism, 550},      {111, F::prism, 24},
        {112, F::prism, 33},       {113, F::prism, 42},       {114, F::prism, 51},       {115, F::prism, 60},
        {116, F::prism, 69},       {117, F::prism, 78},       {118, F::pyramid, 30},     {119, F::pyramid, 55},
        {120, F::pyramid, 91},     {121, F::pyramid, 140},    {122, F::pyramid, 204},    {123, F::pyramid, 285},
        {124, F::pyramid, 385},    {125, F::pyramid, 21},     {126, F::pyramid, 29},     {127, F::pyramid, 37},
        {128, F::pyramid, 45},     {129, F::pyramid, 53},     {130, F::pyramid, 61},     {131, F::pyramid, 69},
        {132, F::pyramid, 1},      {133, F::point, 0},        {134, F::line, 0},         {135, F::triangle, 0},
        {136, F::tetrahedron, 0},  {137, F::tetrahedron, 16}, {138, F::triangle, 0},     {139, F::tetrahedron, 0},
        {140, F::trihedron, 4},
    };
    std::array<TypeInfo, kMaxType + 1> t{};
    for (const Row& r : rows) {
      int dim = 3;
      if (r.family == F::point) dim = 0;
      else if (r.family == F::line) dim = 1;
      else if (r.family == F::triangle || r.family == F::quadrangle || r.family == F::polygon) dim = 2;
      t[r.type] = {dim, r.nodes, r.family};
    }
    return t;
  }();
  return table;
}

TypeInfo type_info(long long type) {
  if (type < 0 || type > kMaxType) return {};
  return type_table()[static_cast<std::size_t>(type)];
}

const char* family_name(Family f) {
  switch (f) {
    case Family::point: return "point";
    case Family::line: return "line";
    case Family::triangle: return "triangle";
    case Family::quadrangle: return "quadrangle";
    case Family::polygon: return "polygon";
    case Family::tetrahedron: return "tetrahedron";
    case Family::hexahedron: return "hexahedron";
    case Family::prism: return "prism";
    case Family::pyramid: return "pyramid";
    case Family::trihedron: return "trihedron";
    case Family::polyhedron: return "polyhedron";
  }
  return "?";
}

// "type 11 (10-node tetrahedron)"
std::string type_name(long long type) {
  const TypeInfo t = type_info(type);
  std::string s = "type " + std::to_string(type);
  if (t.dim < 0) return s + " (not a Gmsh element type)";
  if (t.nodes == 0) return s + " (" + family_name(t.family) + " without a fixed node count)";
  return s + " (" + std::to_string(t.nodes) + "-node " + family_name(t.family) + ")";
}

// What we do with an element of a given type.
enum class Kind : unsigned char {
  tet,          // type 4 or 11: the simulation mesh
  tri,          // type 2 or 9: kept for physical groups
  aux,          // points (15) and lines (1, 8): only their nodes, for physical groups
  skipped,      // other 0D-2D types: counted and ignored
  unsupported,  // other 3D types: an error (after counting them all)
};

Kind classify(long long type, const TypeInfo& t) {
  if (type == 4 || type == 11) return Kind::tet;
  if (type == 2 || type == 9) return Kind::tri;
  if (type == 15 || type == 1 || type == 8) return Kind::aux;
  return t.dim == 3 ? Kind::unsupported : Kind::skipped;
}

// ---------------------------------------------------------------------------
// What the parser extracts.

// A run of consecutive kept elements of one kind with the same physical tag
// (MSH 2) or entity (MSH 4).
struct Span {
  Kind kind;
  int dim;           // dimension of the elements (= of the physical group / entity)
  int key;           // MSH 2: physical tag; MSH 4: entity tag
  std::size_t begin, end;  // element range (tet / tri), or aux_nodes range (aux)
  std::size_t pos;   // file offset of the first element or block, for messages
};

struct EntityInfo {
  std::vector<int> physicals;  // sorted, unique
  // $PartitionedEntities: an entity whose parent has another dimension is a
  // boundary between partitions (e.g. triangles between two partitions of a
  // volume). Gmsh gives it its parent's physical tags, but its elements are an
  // artifact of the partitioning, not part of those groups: they are ignored.
  bool partition_interface = false;
};

struct RawMesh {
  std::vector<long> node_tag;    // file order
  std::vector<double> node_xyz;  // 3 per node
  int tet_type = 0;              // 4 or 11 (all tets of a file have one type), 0 before the first
  std::vector<int> tet_nodes;    // 4 (type 4) or 10 (type 11) file node indices per tet, file order
  std::vector<long> tet_tag;
  std::vector<std::size_t> tet_pos;  // file offset of each tet, for messages
  std::vector<int> tri_nodes;    // 3 per triangle (the vertices)
  std::vector<int> tri_mid;      // 3 per triangle: mid-edge nodes of a 6-node triangle, -1 for type 2
  std::vector<long> tri_tag;
  std::vector<int> aux_nodes;    // nodes of points and lines
  std::vector<Span> spans;
  bool v4 = false;
  bool has_entities = false, has_partitioned_entities = false;
  std::map<std::pair<int, int>, EntityInfo> entities;              // (dim, tag) -> physical tags
  std::map<std::pair<int, int>, EntityInfo> partitioned_entities;  // idem, $PartitionedEntities
  std::map<std::pair<int, int>, std::string> names;                              // (dim, physical tag) -> name
  std::map<int, long> skipped;                                                   // type -> count
};

inline bool is_blank(char c) { return c == ' ' || c == '\t' || c == '\r'; }
inline bool is_space(char c) { return is_blank(c) || c == '\n' || c == '\f' || c == '\v'; }

std::string num(double v) { return format_number(v, 6); }

// ---------------------------------------------------------------------------

class Parser {
 public:
  Parser(std::string path, std::string data) : path_(std::move(path)), buf_(std::move(data)) {
    d_ = buf_.data();
    size_ = buf_.size();
  }

  RawMesh parse();
  [[noreturn]] void fail(std::size_t pos, const std::string& msg) const { throw InputError(where(pos) + msg); }
  [[noreturn]] void fail_file(const std::string& msg) const { throw InputError(path_ + ": " + msg); }
  // "line 12" (text) or "byte 345" (binary data), for lists in messages.
  std::string location(std::size_t pos) const {
    if (binary_ && pos >= binary_from_) return "byte " + std::to_string(pos);
    return "line " + std::to_string(1 + std::count(d_, d_ + std::min(pos, size_), '\n'));
  }

 private:
  // --- positions and messages
  std::string where(std::size_t pos) const {
    if (binary_ && pos >= binary_from_) return path_ + ": byte " + std::to_string(pos) + ": ";
    const std::size_t end = std::min(pos, size_);
    const long line = 1 + static_cast<long>(std::count(d_, d_ + end, '\n'));
    return path_ + ":" + std::to_string(line) + ": ";
  }
  // The token at `p`, quoted and made printable, for "found ..." messages.
  std::string describe(std::size_t p) const {
    if (p >= size_) return "end of file";
    if (d_[p] == '\n') return "end of line";
    std::string s = "'";
    std::size_t e = p;
    for (; e < size_ && !is_space(d_[e]) && e - p < 40; ++e) {
      const auto c = static_cast<unsigned char>(d_[e]);
      if (c >= 0x20 && c < 0x7f) {
        s += static_cast<char>(c);
      } else {
        char hex[8];
        std::snprintf(hex, sizeof hex, "\\x%02x", c);
        s += hex;
      }
    }
    if (e < size_ && !is_space(d_[e])) s += "...";
    return s + "'";
  }

  // --- text
  void skip_blanks() {
    while (pos_ < size_ && is_blank(d_[pos_])) ++pos_;
  }
  void skip_space() {
    while (pos_ < size_ && is_space(d_[pos_])) ++pos_;
  }
  // Within a record, values are on one line (better messages than a stream of
  // tokens: a short line is reported where it is). In $Entities, whose layout
  // writers vary, values may cross lines.
  void skip_to_value() {
    if (cross_lines_) skip_space();
    else skip_blanks();
  }
  // A leading '+' is accepted (from_chars does not), but only before a digit
  // or '.': "+-1" stays an error.
  const char* skip_plus(std::size_t start) const {
    const char* first = d_ + start;
    if (*first == '+' && start + 1 < size_ && (std::isdigit(static_cast<unsigned char>(first[1])) || first[1] == '.'))
      ++first;
    return first;
  }
  [[noreturn]] void fail_expected(std::size_t p, const char* what, const char* kind) const {
    fail(p, std::string("expected ") + what + kind + ", found " + describe(p));
  }
  unsigned long long read_unsigned(const char* what) {
    skip_to_value();
    const std::size_t start = pos_;
    if (start >= size_ || d_[start] == '\n') fail_expected(start, what, "");
    const char* first = skip_plus(start);
    unsigned long long v = 0;
    const auto [p, ec] = std::from_chars(first, d_ + size_, v);
    if (ec == std::errc::result_out_of_range) fail(start, std::string(what) + " " + describe(start) + " is out of range");
    if (ec != std::errc() || (p != d_ + size_ && !is_space(*p))) fail_expected(start, what, " (a non-negative integer)");
    pos_ = static_cast<std::size_t>(p - d_);
    return v;
  }
  long long read_signed(const char* what) {
    skip_to_value();
    const std::size_t start = pos_;
    if (start >= size_ || d_[start] == '\n') fail_expected(start, what, "");
    const char* first = skip_plus(start);
    long long v = 0;
    const auto [p, ec] = std::from_chars(first, d_ + size_, v);
    if (ec == std::errc::result_out_of_range) fail(start, std::string(what) + " " + describe(start) + " is out of range");
    if (ec != std::errc() || (p != d_ + size_ && !is_space(*p))) fail_expected(start, what, " (an integer)");
    pos_ = static_cast<std::size_t>(p - d_);
    return v;
  }
  int read_int(const char* what) {
    skip_to_value();
    const std::size_t start = pos_;
    const long long v = read_signed(what);
    if (v < std::numeric_limits<int>::min() || v > std::numeric_limits<int>::max())
      fail(start, std::string(what) + " " + std::to_string(v) + " is out of range");
    return static_cast<int>(v);
  }
  // Node and element tags: 1 .. LONG_MAX.
  long read_tag(const char* what) {
    skip_to_value();
    const std::size_t start = pos_;
    const unsigned long long v = read_unsigned(what);
    if (v == 0 || v > static_cast<unsigned long long>(kMaxTag))
      fail(start, std::string(what) + " " + std::to_string(v) + " is out of range (tags are 1 to 2^63-1)");
    return static_cast<long>(v);
  }
  double read_double(const char* what, bool finite = true) {
    skip_to_value();
    const std::size_t start = pos_;
    if (start >= size_ || d_[start] == '\n') fail_expected(start, what, "");
    const char* first = skip_plus(start);
    double v = 0;
    auto [p, ec] = std::from_chars(first, d_ + size_, v);
    if (ec == std::errc::result_out_of_range) {
      // libstdc++ reports underflow (e.g. 1e-320) as out of range too; strtod
      // gives the denormal or zero. Overflow stays an error.
      const std::string token(first, static_cast<std::size_t>(p - first));
      v = std::strtod(token.c_str(), nullptr);
      if (!std::isfinite(v)) fail(start, std::string(what) + " " + describe(start) + " is out of range");
      ec = std::errc();
    }
    if (ec != std::errc() || (p != d_ + size_ && !is_space(*p))) fail_expected(start, what, " (a number)");
    if (finite && !std::isfinite(v)) fail_expected(start, what, " (a finite number)");
    pos_ = static_cast<std::size_t>(p - d_);
    return v;
  }
  // Consumes the rest of the line, which must be blank.
  void end_line(const char* after) {
    skip_blanks();
    if (pos_ >= size_) return;
    if (d_[pos_] == '\n') {
      ++pos_;
      return;
    }
    fail(pos_, std::string("unexpected ") + describe(pos_) + " after " + after + " (expected end of line)");
  }
  void skip_line() {
    const void* nl = std::memchr(d_ + pos_, '\n', size_ - pos_);
    pos_ = nl ? static_cast<std::size_t>(static_cast<const char*>(nl) - d_) + 1 : size_;
  }
  std::string_view word() {
    const std::size_t start = pos_;
    while (pos_ < size_ && !is_space(d_[pos_])) ++pos_;
    return {d_ + start, pos_ - start};
  }
  void expect_end(std::string_view end_name, const char* after) {
    skip_space();
    const std::size_t start = pos_;
    if (word() != end_name) {
      if (start >= size_)
        fail(start, "expected " + std::string(end_name) + " after " + after + ", found end of file (truncated file?)");
      fail(start, "expected " + std::string(end_name) + " after " + after + ", found " + describe(start));
    }
    end_line(end_name.data());
  }

  // --- binary
  // Fails unless `count` items of at least `bytes_each` bytes fit in the rest
  // of the file: this bounds every allocation by the file size.
  void check_count(std::uint64_t count, std::size_t bytes_each, std::size_t at, const char* what) const {
    const std::size_t left = size_ - std::min(pos_, size_);
    if (count > left / bytes_each)
      fail(at, std::to_string(count) + " " + what + " cannot fit in the " + std::to_string(left) +
                   " bytes left in the file (truncated file or corrupt count)");
    if (count > kMaxCount) fail(at, "too many " + std::string(what) + " (" + std::to_string(count) + ")");
  }
  void need(std::size_t bytes, const char* what) const {
    if (bytes > size_ - pos_)
      fail(pos_, std::string("truncated file: expected ") + what + " (" + std::to_string(bytes) + " bytes), found " +
                     (size_ == pos_ ? std::string("end of file") : "only " + std::to_string(size_ - pos_) + " bytes"));
  }
  template <class T>
  T get() {  // after need()
    T v;
    std::memcpy(&v, d_ + pos_, sizeof(T));
    pos_ += sizeof(T);
    return v;
  }
  std::uint64_t get_size() { return size_t_bytes_ == 8 ? get<std::uint64_t>() : get<std::uint32_t>(); }
  std::int32_t read_bin_int(const char* what) {
    need(4, what);
    return get<std::int32_t>();
  }
  std::uint64_t read_bin_size(const char* what) {
    need(size_t_bytes_, what);
    return get_size();
  }
  // A size_t value (MSH 4) in either encoding.
  std::uint64_t read_size(const char* what) { return binary_ ? read_bin_size(what) : read_unsigned(what); }
  int read_int4(const char* what) { return binary_ ? read_bin_int(what) : read_int(what); }
  // Tags stored as size_t in binary MSH 4.
  long tag_from_size(std::uint64_t v, std::size_t at, const char* what) const {
    if (v == 0 || v > static_cast<std::uint64_t>(kMaxTag))
      fail(at, std::string(what) + " " + std::to_string(v) + " is out of range (tags are 1 to 2^63-1)");
    return static_cast<long>(v);
  }

  // --- sections
  void read_mesh_format();
  void read_physical_names();
  void read_entities(bool partitioned);
  void read_nodes_v2();
  struct V4Header {
    std::size_t start = 0;
    std::uint64_t blocks = 0, count = 0;
  };
  V4Header read_v4_header(const std::string& item);
  void read_nodes_v4();
  void read_elements_v2();
  void read_elements_v4();
  void skip_section(std::string_view name, std::size_t header_pos);
  void build_node_lookup(std::size_t section_pos);
  void report_unsupported() const;

  int node_index(long tag) const {
    if (dense_lookup_) return (tag >= 0 && static_cast<std::size_t>(tag) < dense_.size()) ? dense_[tag] : -1;
    const auto it = std::lower_bound(sorted_.begin(), sorted_.end(), std::pair<long, int>(tag, -1));
    return (it != sorted_.end() && it->first == tag) ? it->second : -1;
  }
  // File index of the node with this tag (a long, int32 or size_t as read).
  template <class TagT>
  int resolve(TagT tag, std::size_t element_pos, long element_tag, long long type) const {
    const bool in_range = tag >= 1 && static_cast<std::uint64_t>(tag) <= static_cast<std::uint64_t>(kMaxTag);
    const int i = in_range ? node_index(static_cast<long>(tag)) : -1;
    if (i < 0)
      fail(element_pos, "element " + std::to_string(element_tag) + " (" + type_name(type) + ") refers to node " +
                            std::to_string(tag) + ", which is not defined in $Nodes");
    return i;
  }
  void add_member(Kind kind, int dim, int key, std::size_t begin, std::size_t end, std::size_t pos) {
    if (!raw_.spans.empty()) {
      Span& s = raw_.spans.back();
      if (s.kind == kind && s.dim == dim && s.key == key && s.end == begin) {
        s.end = end;
        return;
      }
    }
    raw_.spans.push_back({kind, dim, key, begin, end, pos});
  }
  // Element bookkeeping shared by all encodings. `nodes` are node *tags*.
  template <class TagT>
  void add_element(Kind kind, long long type, int dim, long tag, const TagT* nodes, int num_nodes, bool member,
                   int key, std::size_t pos) {
    switch (kind) {
      case Kind::tet: {
        const std::size_t i = raw_.tet_tag.size();
        if (raw_.tet_type == 0) {
          raw_.tet_type = static_cast<int>(type);
          first_tet_pos_ = pos;
        } else if (raw_.tet_type != type) {
          fail(pos, "element " + std::to_string(tag) + " is a " + type_name(type) + " but the mesh's first " +
                        "tetrahedron (" + location(first_tet_pos_) + ") is a " + type_name(raw_.tet_type) +
                        ": a mesh has one element order (mesh with one Mesh.ElementOrder, or ask for "
                        "`elements: quadratic` on a linear mesh)");
        }
        for (int j = 0; j < num_nodes; ++j) raw_.tet_nodes.push_back(resolve(nodes[j], pos, tag, type));
        raw_.tet_tag.push_back(tag);
        raw_.tet_pos.push_back(pos);
        if (member) add_member(kind, dim, key, i, i + 1, pos);
        break;
      }
      case Kind::tri: {
        const std::size_t i = raw_.tri_tag.size();
        for (int j = 0; j < 3; ++j) raw_.tri_nodes.push_back(resolve(nodes[j], pos, tag, type));
        for (int j = 3; j < 6; ++j) raw_.tri_mid.push_back(j < num_nodes ? resolve(nodes[j], pos, tag, type) : -1);
        raw_.tri_tag.push_back(tag);
        if (member) add_member(kind, dim, key, i, i + 1, pos);
        break;
      }
      case Kind::aux: {
        const std::size_t i = raw_.aux_nodes.size();
        for (int j = 0; j < num_nodes; ++j) raw_.aux_nodes.push_back(resolve(nodes[j], pos, tag, type));
        if (member) add_member(kind, dim, key, i, i + static_cast<std::size_t>(num_nodes), pos);
        break;
      }
      case Kind::skipped: ++raw_.skipped[static_cast<int>(type)]; break;
      case Kind::unsupported: note_unsupported(type, 1, pos); break;
    }
  }
  void note_unsupported(long long type, std::uint64_t count, std::size_t pos) {
    unsupported_[static_cast<int>(type)] += static_cast<long>(count);
    if (first_unsupported_ == kNoPos) first_unsupported_ = pos;
  }
  // Validates an element type read at `pos`; returns its info.
  TypeInfo checked_type(long long type, std::size_t pos) const {
    const TypeInfo t = type_info(type);
    if (t.dim < 0) fail(pos, "unknown element type " + std::to_string(type) + " (Gmsh element types are 1 to 140)");
    if (t.nodes == 0)
      fail(pos, "element " + type_name(type) + " is not supported: it has no fixed node count, so it cannot be read");
    return t;
  }

  std::string path_;
  std::string buf_;
  const char* d_ = nullptr;
  std::size_t size_ = 0;
  std::size_t pos_ = 0;
  bool binary_ = false;
  std::size_t binary_from_ = kNoPos;  // binary data (and byte offsets in messages) start here
  int version_ = 0;                   // 2 or 4
  int size_t_bytes_ = 8;              // MSH 4 binary: sizeof(size_t) of the writer
  bool cross_lines_ = false;
  RawMesh raw_;
  // node tag -> file index
  bool dense_lookup_ = true;
  std::vector<int> dense_;
  std::vector<std::pair<long, int>> sorted_;
  std::map<int, long> unsupported_;
  std::size_t first_unsupported_ = kNoPos;
  std::size_t first_tet_pos_ = kNoPos;
};

RawMesh Parser::parse() {
  if (size_ == 0) fail_file("empty file; expected a Gmsh mesh file starting with $MeshFormat");
  if (size_ >= 3 && std::memcmp(d_, "\xEF\xBB\xBF", 3) == 0) pos_ = 3;  // UTF-8 byte order mark
  read_mesh_format();
  raw_.v4 = version_ == 4;

  bool have_nodes = false, have_elements = false;
  for (;;) {
    skip_space();
    if (pos_ >= size_) break;
    const std::size_t start = pos_;
    const std::string_view name = word();
    if (name.size() < 2 || name[0] != '$')
      fail(start, "expected a section header such as $Nodes or $Elements, found " + describe(start));
    if (name.starts_with("$End"))
      fail(start, "unexpected " + describe(start) + ": no section $" + std::string(name.substr(4)) + " is open");
    end_line(std::string(name).c_str());
    if (name == "$PhysicalNames") {
      read_physical_names();
    } else if (name == "$Nodes") {
      if (have_nodes) fail(start, "second $Nodes section; only one is supported");
      if (version_ == 2) read_nodes_v2();
      else read_nodes_v4();
      build_node_lookup(start);
      have_nodes = true;
    } else if (name == "$Elements") {
      if (!have_nodes) fail(start, "$Elements section before any $Nodes section (nodes must come first)");
      if (have_elements) fail(start, "second $Elements section; only one is supported");
      if (version_ == 2) read_elements_v2();
      else read_elements_v4();
      report_unsupported();
      have_elements = true;
    } else if (version_ == 4 && (name == "$Entities" || name == "$PartitionedEntities")) {
      const bool partitioned = name == "$PartitionedEntities";
      if (partitioned ? raw_.has_partitioned_entities : raw_.has_entities)
        fail(start, "second " + std::string(name) + " section");
      read_entities(partitioned);
    } else {
      skip_section(name, start);  // $Comments, $Periodic, $NodeData, ...: not needed here
    }
  }
  if (!have_nodes) fail_file("no $Nodes section in the file (truncated file?)");
  if (!have_elements) fail_file("no $Elements section in the file (truncated file?)");
  return std::move(raw_);
}

void Parser::read_mesh_format() {
  skip_space();
  std::size_t start = pos_;
  const std::string_view first = word();
  if (first != "$MeshFormat") {
    if (first == "$NOD" || first == "$NOE")
      fail(start, "MSH version 1 files are not supported (supported: 2.2 and 4.1); convert with "
                  "`gmsh FILE -save -format msh41 -o OUT.msh`");
    fail(start, "not a Gmsh MSH file: expected $MeshFormat at the start, found " + describe(start));
  }
  end_line("$MeshFormat");
  skip_space();
  start = pos_;
  const std::string_view version = word();
  double v = 0;
  const auto [p, ec] = std::from_chars(version.data(), version.data() + version.size(), v);
  if (version.empty() || ec != std::errc() || p != version.data() + version.size())
    fail(start, "expected the MSH format version (e.g. 4.1), found " + describe(start));
  if (std::abs(v - 2.2) < 1e-9) version_ = 2;
  else if (std::abs(v - 4.1) < 1e-9) version_ = 4;
  else
    fail(start, "unsupported MSH format version " + std::string(version) +
                    "; supported versions are 2.2 and 4.1 (convert with `gmsh FILE -save -format msh41 -o OUT.msh`)");
  start = pos_;
  const long long file_type = read_signed("file type (0 = ASCII, 1 = binary)");
  if (file_type != 0 && file_type != 1) {
    skip_blanks();
    fail(start, "expected file type 0 (ASCII) or 1 (binary), found " + std::to_string(file_type));
  }
  skip_blanks();
  start = pos_;
  const long long data_size = read_signed("data size");
  end_line("the format version line");
  binary_ = file_type == 1;
  if (!binary_) return expect_end("$EndMeshFormat", "the format version line");

  if (version_ == 2 && data_size != 8)
    fail(start, "MSH 2.2 binary files must have data size 8 (sizeof(double)), found " + std::to_string(data_size));
  if (version_ == 4 && data_size != 4 && data_size != 8)
    fail(start, "expected data size (sizeof(size_t)) 4 or 8, found " + std::to_string(data_size));
  size_t_bytes_ = static_cast<int>(data_size);
  binary_from_ = pos_;
  const std::int32_t one = read_bin_int("the integer 1 that marks the byte order");
  if (one != 1) {
    const auto u = static_cast<std::uint32_t>(one);
    if (((u >> 24) | ((u >> 8) & 0xff00u) | ((u << 8) & 0xff0000u) | (u << 24)) == 1u)
      fail(binary_from_, "binary file has the opposite byte order (endianness) from this machine; convert it "
                         "to ASCII or re-save it with gmsh on a machine of this byte order");
    fail(binary_from_, "expected the binary integer 1 (byte order mark) after the format line, found " +
                           std::to_string(one) + " (corrupt binary header)");
  }
  expect_end("$EndMeshFormat", "the byte order mark");
}

void Parser::skip_section(std::string_view name, std::size_t header_pos) {
  // The end marker must start a line and be a whole word. Binary data inside
  // the section could in principle contain it; Gmsh's own reader makes the
  // same assumption for sections it does not know.
  const std::string marker = "\n$End" + std::string(name.substr(1));
  std::size_t p = pos_ > 0 ? pos_ - 1 : 0;
  const std::string_view all(d_, size_);
  for (;;) {
    p = all.find(marker, p);
    if (p == std::string_view::npos)
      fail(header_pos, "section " + std::string(name) + " is not closed: no $End" + std::string(name.substr(1)) +
                           " before the end of the file (truncated file?)");
    const std::size_t after = p + marker.size();
    if (after == size_ || is_space(d_[after])) break;
    p = after;
  }
  pos_ = p + 1;
  word();
  end_line("the end of a section");
}

void Parser::read_physical_names() {
  skip_space();
  const std::size_t start = pos_;
  const unsigned long long count = read_unsigned("number of physical names");
  end_line("the number of physical names");
  check_count(count, 6, start, "physical names");
  for (unsigned long long i = 0; i < count; ++i) {
    skip_space();
    const std::size_t rec = pos_;
    const int dim = read_int("physical group dimension");
    if (dim < 0 || dim > 3) fail(rec, "expected a physical group dimension 0 to 3, found " + std::to_string(dim));
    const int tag = read_int("physical tag");
    skip_blanks();
    if (pos_ >= size_ || d_[pos_] != '"') fail_expected(pos_, "a quoted physical name", "");
    const std::size_t name_start = ++pos_;
    while (pos_ < size_ && d_[pos_] != '"' && d_[pos_] != '\n') ++pos_;
    if (pos_ >= size_ || d_[pos_] != '"') fail(name_start - 1, "physical name is missing its closing quote");
    std::string name(d_ + name_start, pos_ - name_start);
    ++pos_;
    end_line("the physical name");
    const auto [it, inserted] = raw_.names.emplace(std::make_pair(dim, tag), name);
    if (!inserted && it->second != name)
      fail(rec, "physical group (dim " + std::to_string(dim) + ", tag " + std::to_string(tag) + ") is named twice: '" +
                    it->second + "' and '" + name + "'");
  }
  expect_end("$EndPhysicalNames", "the physical names");
}

void Parser::read_entities(bool partitioned) {
  // Layout (MSH 4.1):
  //   [partitioned: numPartitions numGhostEntities {ghostTag partition}]
  //   numPoints numCurves numSurfaces numVolumes
  //   per entity: tag [partitioned: parentDim parentTag numPartitions {partition}]
  //               X Y Z (points) | minX minY minZ maxX maxY maxZ (others)
  //               numPhysicalTags {physicalTag}  [dim > 0: numBounding {boundingTag}]
  // Only the physical tags matter here.
  cross_lines_ = true;
  auto& map = partitioned ? raw_.partitioned_entities : raw_.entities;
  (partitioned ? raw_.has_partitioned_entities : raw_.has_entities) = true;
  const std::size_t int_bytes = binary_ ? 4 : 2;  // a value takes at least this many bytes
  auto skip_ints = [&](const char* count_what, const char* what) {
    const std::size_t at = pos_;
    const std::uint64_t n = read_size(count_what);
    check_count(n, int_bytes, at, what);
    if (binary_) pos_ += 4 * n;
    else
      for (std::uint64_t k = 0; k < n; ++k) read_int(what);
  };
  auto skip_doubles = [&](int n) {
    if (binary_) {
      need(8 * static_cast<std::size_t>(n), "entity coordinates");
      pos_ += 8 * static_cast<std::size_t>(n);
    } else {
      for (int k = 0; k < n; ++k) read_double("entity coordinate", false);
    }
  };
  // Binary data starts right after the header line, and its first byte may
  // look like whitespace (9 blocks = '\t'): only text may be skipped.
  if (!binary_) skip_space();
  if (partitioned) {
    read_size("number of partitions");
    const std::size_t at = pos_;
    const std::uint64_t ghosts = read_size("number of ghost entities");
    check_count(ghosts, 2 * int_bytes, at, "ghost entities");
    for (std::uint64_t k = 0; k < 2 * ghosts; ++k) read_int4("ghost entity tag or partition");
  }
  std::uint64_t counts[4];
  for (std::uint64_t& c : counts) {
    const std::size_t at = pos_;
    c = read_size("number of entities");
    check_count(c, 3 * int_bytes, at, "entities");
  }
  for (int dim = 0; dim < 4; ++dim) {
    for (std::uint64_t i = 0; i < counts[dim]; ++i) {
      if (!binary_) skip_space();
      const std::size_t rec = pos_;
      const int tag = read_int4("entity tag");
      EntityInfo info;
      if (partitioned) {
        info.partition_interface = read_int4("parent entity dimension") != dim;
        read_int4("parent entity tag");
        skip_ints("number of partitions", "partition tag");
      }
      skip_doubles(dim == 0 ? 3 : 6);
      const std::size_t at = pos_;
      const std::uint64_t nphys = read_size("number of physical tags");
      check_count(nphys, int_bytes, at, "physical tags");
      std::vector<int>& phys = info.physicals;
      phys.resize(static_cast<std::size_t>(nphys));
      for (int& p : phys) p = read_int4("physical tag");
      if (dim > 0) skip_ints("number of bounding entities", "bounding entity tag");
      std::sort(phys.begin(), phys.end());
      phys.erase(std::unique(phys.begin(), phys.end()), phys.end());
      if (!map.emplace(std::make_pair(dim, tag), std::move(info)).second)
        fail(rec, "entity (dim " + std::to_string(dim) + ", tag " + std::to_string(tag) + ") is listed twice");
    }
  }
  cross_lines_ = false;
  expect_end(partitioned ? "$EndPartitionedEntities" : "$EndEntities", "the entities");
}

void Parser::read_nodes_v2() {
  // count, then per node: tag x y z (binary: int32 tag, 3 doubles).
  skip_space();
  const std::size_t start = pos_;
  const unsigned long long count = read_unsigned("number of nodes");
  end_line("the number of nodes");
  check_count(count, binary_ ? 28 : 8, start, "nodes");
  const std::size_t n = static_cast<std::size_t>(count);
  raw_.node_tag.resize(n);
  raw_.node_xyz.resize(3 * n);
  if (binary_) {
    need(28 * n, "node data");
    for (std::size_t i = 0; i < n; ++i) {
      const std::size_t at = pos_;
      const std::int32_t tag = get<std::int32_t>();
      if (tag <= 0) fail(at, "node tag " + std::to_string(tag) + " is out of range (tags are positive)");
      raw_.node_tag[i] = tag;
      for (int k = 0; k < 3; ++k) {
        const double x = get<double>();
        if (!std::isfinite(x)) fail(at, "node " + std::to_string(tag) + " has a non-finite coordinate");
        raw_.node_xyz[3 * i + k] = x;
      }
    }
  } else {
    for (std::size_t i = 0; i < n; ++i) {
      skip_space();
      raw_.node_tag[i] = read_tag("node tag");
      raw_.node_xyz[3 * i + 0] = read_double("node x coordinate");
      raw_.node_xyz[3 * i + 1] = read_double("node y coordinate");
      raw_.node_xyz[3 * i + 2] = read_double("node z coordinate");
      end_line("the node coordinates");
    }
  }
  expect_end("$EndNodes", "the nodes (is the node count right?)");
}

// MSH 4 $Nodes / $Elements header: numEntityBlocks numItems minTag maxTag.
Parser::V4Header Parser::read_v4_header(const std::string& item) {
  if (!binary_) skip_space();  // binary: the first byte may look like whitespace
  V4Header h;
  h.start = pos_;
  h.blocks = read_size(("number of " + item + " blocks").c_str());
  h.count = read_size(("number of " + item + "s").c_str());
  read_size(("minimum " + item + " tag").c_str());
  read_size(("maximum " + item + " tag").c_str());
  if (!binary_) end_line(("the " + item + " section header").c_str());
  return h;
}

void Parser::read_nodes_v4() {
  // numEntityBlocks numNodes minNodeTag maxNodeTag; per block: entityDim
  // entityTag parametric numNodesInBlock, the block's tags, then its
  // coordinates x y z [u [v [w]]] (parametric nodes: one more per entity dim).
  const V4Header header = read_v4_header("node");
  const std::size_t start = header.start;
  const std::uint64_t blocks = header.blocks, count = header.count;
  const std::size_t tag_bytes = binary_ ? static_cast<std::size_t>(size_t_bytes_) : 2;
  check_count(blocks, binary_ ? 12 + tag_bytes : 8, start, "node blocks");
  check_count(count, binary_ ? tag_bytes + 24 : 8, start, "nodes");
  const std::size_t n = static_cast<std::size_t>(count);
  raw_.node_tag.resize(n);
  raw_.node_xyz.resize(3 * n);
  std::size_t done = 0;
  for (std::uint64_t b = 0; b < blocks; ++b) {
    if (!binary_) skip_space();
    const std::size_t block_pos = pos_;
    const int entity_dim = read_int4("entity dimension");
    read_int4("entity tag");
    const int parametric = read_int4("parametric flag");
    const std::uint64_t in_block = read_size("number of nodes in the block");
    if (!binary_) end_line("the node block header");
    if (entity_dim < 0 || entity_dim > 3)
      fail(block_pos, "expected an entity dimension 0 to 3, found " + std::to_string(entity_dim));
    if (parametric != 0 && parametric != 1)
      fail(block_pos, "expected a parametric flag 0 or 1, found " + std::to_string(parametric));
    if (in_block > n - done)
      fail(block_pos, "node blocks hold more nodes than the " + std::to_string(n) + " declared in the header");
    const std::size_t m = static_cast<std::size_t>(in_block);
    const int extra = parametric ? entity_dim : 0;
    if (binary_) {
      const std::size_t bytes_each = tag_bytes + 8 * static_cast<std::size_t>(3 + extra);
      check_count(m, bytes_each, block_pos, "nodes");
      for (std::size_t i = 0; i < m; ++i) {
        const std::size_t at = pos_;
        raw_.node_tag[done + i] = tag_from_size(get_size(), at, "node tag");
      }
      for (std::size_t i = 0; i < m; ++i) {
        const std::size_t at = pos_;
        for (int k = 0; k < 3; ++k) {
          const double x = get<double>();
          if (!std::isfinite(x))
            fail(at, "node " + std::to_string(raw_.node_tag[done + i]) + " has a non-finite coordinate");
          raw_.node_xyz[3 * (done + i) + k] = x;
        }
        pos_ += 8 * static_cast<std::size_t>(extra);
      }
    } else {
      for (std::size_t i = 0; i < m; ++i) {
        skip_space();
        raw_.node_tag[done + i] = read_tag("node tag");
        end_line("the node tag (MSH 4.1 lists one tag per line, then the coordinates)");
      }
      for (std::size_t i = 0; i < m; ++i) {
        skip_space();
        for (int k = 0; k < 3; ++k) raw_.node_xyz[3 * (done + i) + k] = read_double("node coordinate");
        for (int k = 0; k < extra; ++k) read_double("parametric node coordinate", false);
        end_line(parametric ? "the node coordinates and parametric coordinates" : "the node coordinates");
      }
    }
    done += m;
  }
  if (done != n)
    fail(start, "the node section header declares " + std::to_string(n) + " nodes but its blocks hold " +
                    std::to_string(done));
  expect_end("$EndNodes", "the node blocks");
}

void Parser::build_node_lookup(std::size_t section_pos) {
  const std::size_t n = raw_.node_tag.size();
  long max_tag = 0;
  for (long t : raw_.node_tag) max_tag = std::max(max_tag, t);
  auto duplicate = [&](long tag, std::size_t i, std::size_t j) {
    fail(section_pos, "node tag " + std::to_string(tag) + " is defined twice in $Nodes (nodes #" +
                          std::to_string(std::min(i, j) + 1) + " and #" + std::to_string(std::max(i, j) + 1) +
                          " of the section)");
  };
  // Gmsh tags are usually dense: a direct table is fastest. Sparse tags (a
  // table would be mostly empty) use a sorted array instead.
  dense_lookup_ = static_cast<std::uint64_t>(max_tag) <= 4 * static_cast<std::uint64_t>(n) + 1024;
  if (dense_lookup_) {
    dense_.assign(static_cast<std::size_t>(max_tag) + 1, -1);
    for (std::size_t i = 0; i < n; ++i) {
      int& slot = dense_[static_cast<std::size_t>(raw_.node_tag[i])];
      if (slot >= 0) duplicate(raw_.node_tag[i], static_cast<std::size_t>(slot), i);
      slot = static_cast<int>(i);
    }
  } else {
    sorted_.resize(n);
    for (std::size_t i = 0; i < n; ++i) sorted_[i] = {raw_.node_tag[i], static_cast<int>(i)};
    std::sort(sorted_.begin(), sorted_.end());
    for (std::size_t i = 1; i < n; ++i)
      if (sorted_[i].first == sorted_[i - 1].first)
        duplicate(sorted_[i].first, static_cast<std::size_t>(sorted_[i - 1].second),
                  static_cast<std::size_t>(sorted_[i].second));
  }
}

void Parser::read_elements_v2() {
  // count, then per element: tag type numTags tags... nodes...; the first tag is
  // the physical group (0: none). Binary: blocks of (type, count, numTags)
  // followed by count records of int32 (tag, tags..., nodes...).
  skip_space();
  const std::size_t start = pos_;
  const unsigned long long count = read_unsigned("number of elements");
  end_line("the number of elements");
  check_count(count, 8, start, "elements");
  long node_tags[10];
  if (!binary_) {
    for (unsigned long long e = 0; e < count; ++e) {
      skip_space();
      const std::size_t at = pos_;
      const long tag = read_tag("element tag");
      const long long type = read_signed("element type");
      const TypeInfo t = checked_type(type, at);
      const long long num_tags = read_signed("number of element tags");
      if (num_tags < 0 || static_cast<unsigned long long>(num_tags) > size_ - pos_)
        fail(at, "expected a number of element tags >= 0, found " + std::to_string(num_tags));
      int physical = 0;
      for (long long k = 0; k < num_tags; ++k) {
        const int v = read_int("element tag value");
        if (k == 0) physical = v;
      }
      const Kind kind = classify(type, t);
      if (kind == Kind::skipped || kind == Kind::unsupported) {
        skip_line();  // nodes of ignored elements are not needed
        add_element<long>(kind, type, t.dim, tag, nullptr, 0, false, 0, at);
        continue;
      }
      for (int j = 0; j < t.nodes; ++j) node_tags[j] = read_tag("node tag of the element");
      end_line("the element's node tags");
      add_element(kind, type, t.dim, tag, node_tags, t.nodes, physical != 0, physical, at);
    }
  } else {
    std::uint64_t done = 0;
    std::vector<std::int32_t> rec;
    while (done < count) {
      const std::size_t at = pos_;
      need(12, "an element block header (type, count, number of tags)");
      const std::int32_t type = get<std::int32_t>();
      const std::int32_t in_block = get<std::int32_t>();
      const std::int32_t num_tags = get<std::int32_t>();
      const TypeInfo t = checked_type(type, at);
      if (in_block <= 0 || static_cast<std::uint64_t>(in_block) > count - done)
        fail(at, "element block of " + std::to_string(in_block) + " elements does not fit the " +
                     std::to_string(count - done) + " elements left of the declared total");
      if (num_tags < 0) fail(at, "expected a number of element tags >= 0, found " + std::to_string(num_tags));
      const std::size_t per = 1 + static_cast<std::size_t>(num_tags) + static_cast<std::size_t>(t.nodes);
      check_count(static_cast<std::uint64_t>(in_block), 4 * per, at, "elements");
      const Kind kind = classify(type, t);
      if (kind == Kind::skipped || kind == Kind::unsupported) {
        if (kind == Kind::skipped) raw_.skipped[type] += in_block;
        else note_unsupported(type, static_cast<std::uint64_t>(in_block), at);
        pos_ += 4 * per * static_cast<std::size_t>(in_block);
      } else {
        rec.resize(per);
        for (std::int32_t e = 0; e < in_block; ++e) {
          const std::size_t rec_pos = pos_;
          std::memcpy(rec.data(), d_ + pos_, 4 * per);
          pos_ += 4 * per;
          if (rec[0] <= 0) fail(rec_pos, "element tag " + std::to_string(rec[0]) + " is out of range (tags are positive)");
          const int physical = num_tags > 0 ? rec[1] : 0;
          add_element(kind, type, t.dim, rec[0], rec.data() + 1 + num_tags, t.nodes, physical != 0, physical, rec_pos);
        }
      }
      done += static_cast<std::uint64_t>(in_block);
    }
  }
  expect_end("$EndElements", "the elements (is the element count right?)");
}

void Parser::read_elements_v4() {
  // numEntityBlocks numElements minTag maxTag; per block: entityDim entityTag
  // elementType numElementsInBlock, then one record per element: tag nodes...
  const V4Header header = read_v4_header("element");
  const std::size_t start = header.start;
  const std::uint64_t blocks = header.blocks, count = header.count;
  const std::size_t sz = binary_ ? static_cast<std::size_t>(size_t_bytes_) : 2;
  check_count(blocks, binary_ ? 12 + sz : 8, start, "element blocks");
  check_count(count, binary_ ? 2 * sz : 4, start, "elements");
  std::uint64_t done = 0;
  std::vector<std::uint64_t> rec;
  for (std::uint64_t b = 0; b < blocks; ++b) {
    if (!binary_) skip_space();
    const std::size_t block_pos = pos_;
    const int entity_dim = read_int4("entity dimension");
    const int entity_tag = read_int4("entity tag");
    const int type = read_int4("element type");
    const std::uint64_t in_block = read_size("number of elements in the block");
    if (!binary_) end_line("the element block header");
    const TypeInfo t = checked_type(type, block_pos);
    if (entity_dim != t.dim)
      fail(block_pos, "element " + type_name(type) + " has dimension " + std::to_string(t.dim) +
                          " but its block is on an entity of dimension " + std::to_string(entity_dim));
    if (in_block > count - done)
      fail(block_pos, "element blocks hold more elements than the " + std::to_string(count) +
                          " declared in the header");
    const std::size_t per = 1 + static_cast<std::size_t>(t.nodes);
    check_count(in_block, binary_ ? per * sz : per * 2, block_pos, "elements");
    const std::size_t m = static_cast<std::size_t>(in_block);
    const Kind kind = classify(type, t);
    if (kind == Kind::skipped || kind == Kind::unsupported) {
      if (kind == Kind::skipped) raw_.skipped[type] += static_cast<long>(m);
      else if (m > 0) note_unsupported(type, m, block_pos);
      if (binary_) {
        pos_ += per * sz * m;
      } else {
        for (std::size_t e = 0; e < m; ++e) {
          skip_space();
          if (pos_ >= size_)
            fail(pos_, "expected " + std::to_string(m - e) + " more elements in this block, found end of file");
          skip_line();
        }
      }
    } else {
      const std::size_t begin = kind == Kind::tet ? raw_.tet_tag.size()
                                : kind == Kind::tri ? raw_.tri_tag.size()
                                                    : raw_.aux_nodes.size();
      rec.resize(per);
      for (std::size_t e = 0; e < m; ++e) {
        std::size_t at;
        if (binary_) {
          at = pos_;
          for (std::size_t k = 0; k < per; ++k) rec[k] = get_size();
        } else {
          skip_space();
          at = pos_;
          for (std::size_t k = 0; k < per; ++k)
            rec[k] = static_cast<std::uint64_t>(read_tag(k == 0 ? "element tag" : "node tag of the element"));
          end_line("the element's node tags");
        }
        const long tag = tag_from_size(rec[0], at, "element tag");
        add_element(kind, type, t.dim, tag, rec.data() + 1, t.nodes, false, 0, at);
      }
      const std::size_t end = kind == Kind::tet ? raw_.tet_tag.size()
                              : kind == Kind::tri ? raw_.tri_tag.size()
                                                  : raw_.aux_nodes.size();
      if (end > begin) add_member(kind, entity_dim, entity_tag, begin, end, block_pos);
    }
    done += in_block;
  }
  if (done != count)
    fail(start, "the element section header declares " + std::to_string(count) + " elements but its blocks hold " +
                    std::to_string(done));
  expect_end("$EndElements", "the element blocks");
}

void Parser::report_unsupported() const {
  if (unsupported_.empty()) return;
  std::string list;
  for (const auto& [type, n] : unsupported_) {
    if (!list.empty()) list += ", ";
    list += std::to_string(n) + " elements of " + type_name(type);
  }
  fail(first_unsupported_, "only linear and quadratic tetrahedra are supported (types 4 and 11; mesh with "
                           "Mesh.ElementOrder = 1 or 2, no recombination, no incomplete elements), found " + list +
                           " (the first one is here)");
}

// ---------------------------------------------------------------------------
// Cleaning

// Sorts and uniques `v` (values in [0, universe)). Large inputs are marked in a
// table instead, which is linear and keeps big groups (a whole volume) cheap.
void sort_unique(std::vector<int>& v, std::size_t universe) {
  if (v.size() > universe / 8 && universe > 0) {
    std::vector<char> mark(universe, 0);
    for (int x : v) mark[static_cast<std::size_t>(x)] = 1;
    v.clear();
    for (std::size_t i = 0; i < universe; ++i)
      if (mark[i]) v.push_back(static_cast<int>(i));
  } else {
    std::sort(v.begin(), v.end());
    v.erase(std::unique(v.begin(), v.end()), v.end());
  }
}

// For elements with K nodes each (in `nodes`, K per element): maps each
// element to the index of the first element with the same node set, so
// `first[i] == i` marks first occurrences. Elements with ignore[i] set (if
// given) are left out: first[i] = i. O(m log m).
template <int K>
std::vector<int> first_occurrence(const std::vector<int>& nodes, const std::vector<char>* ignore = nullptr,
                                  std::size_t stride = K) {
  const std::size_t m = nodes.size() / stride;
  struct Key {
    std::array<int, K> v;
    int i;
  };
  std::vector<Key> keys;
  keys.reserve(m);
  std::vector<int> first(m);
  for (std::size_t i = 0; i < m; ++i) {
    first[i] = static_cast<int>(i);
    if (ignore && (*ignore)[i]) continue;
    Key& k = keys.emplace_back();
    std::copy_n(nodes.begin() + static_cast<std::ptrdiff_t>(stride * i), K, k.v.begin());
    std::sort(k.v.begin(), k.v.end());
    k.i = static_cast<int>(i);
  }
  std::sort(keys.begin(), keys.end(), [](const Key& a, const Key& b) { return a.v != b.v ? a.v < b.v : a.i < b.i; });
  for (std::size_t j = 0; j < keys.size();) {
    std::size_t r = j;
    while (r < keys.size() && keys[r].v == keys[j].v) first[static_cast<std::size_t>(keys[r++].i)] = keys[j].i;
    j = r;
  }
  return first;
}

TetMesh build_mesh(RawMesh&& raw, const GmshReadOptions& options, const Parser& parser, const std::string& path) {
  const std::size_t raw_tets = raw.tet_tag.size();
  if (raw_tets == 0) {
    std::string found = std::to_string(raw.tri_tag.size()) + " triangles";
    for (const auto& [type, n] : raw.skipped) found += ", " + std::to_string(n) + " elements of " + type_name(type);
    parser.fail_file("no tetrahedra (element type 4 or 11) in the file (found " + found +
                     "); a simulation mesh needs a 3D mesh (`gmsh -3`), and if the .geo defines physical groups the "
                     "volume must be in a Physical Volume (Gmsh saves only elements of physical groups unless "
                     "Mesh.SaveAll = 1)");
  }
  if (raw_tets > kMaxCount) parser.fail_file("too many tetrahedra (" + std::to_string(raw_tets) + ")");

  TetMesh mesh;
  mesh.source = path;
  const bool quadratic = raw.tet_type == 11;
  const std::size_t K = quadratic ? 10 : 4;  // nodes per raw tet
  mesh.order = quadratic ? 2 : 1;

  // Distinct tets in file order (MSH 2 lists an element once per physical group); the
  // vertices identify a tet.
  const std::vector<int> tet_first = first_occurrence<4>(raw.tet_nodes, nullptr, K);
  std::vector<int> tet_index(raw_tets);  // raw tet -> mesh tet
  std::vector<std::size_t> tet_raw;      // mesh tet -> raw tet (first occurrence)
  int m = 0;
  for (std::size_t i = 0; i < raw_tets; ++i)
    if (tet_first[i] == static_cast<int>(i)) {
      tet_index[i] = m++;
      tet_raw.push_back(i);
    } else {
      tet_index[i] = tet_index[static_cast<std::size_t>(tet_first[i])];
    }

  // Simulation nodes: those of a tet, in file order.
  const std::size_t file_nodes = raw.node_tag.size();
  std::vector<int> node_index(file_nodes, -1);
  for (std::size_t i = 0; i < raw_tets; ++i)
    if (tet_first[i] == static_cast<int>(i))
      for (std::size_t j = 0; j < K; ++j) node_index[static_cast<std::size_t>(raw.tet_nodes[K * i + j])] = 0;
  int n = 0;
  for (int& k : node_index)
    if (k == 0) k = n++;
  mesh.orphan_nodes = static_cast<long>(file_nodes) - n;
  mesh.X.resize(3, n);
  mesh.file_index.resize(static_cast<std::size_t>(n));
  mesh.file_tag.resize(static_cast<std::size_t>(n));
  for (std::size_t i = 0; i < file_nodes; ++i) {
    const int k = node_index[i];
    if (k < 0) continue;
    mesh.X.col(k) = Vec3(raw.node_xyz[3 * i], raw.node_xyz[3 * i + 1], raw.node_xyz[3 * i + 2]);
    mesh.file_index[static_cast<std::size_t>(k)] = static_cast<long>(i);
    mesh.file_tag[static_cast<std::size_t>(k)] = raw.node_tag[i];
  }

  // Tets: volumes, degeneracy, orientation.
  mesh.tets.resize(4, m);
  if (quadratic) mesh.tets10.resize(10, m);
  mesh.tet_file_tag.resize(static_cast<std::size_t>(m));
  std::vector<double> volume(static_cast<std::size_t>(m));
  double sum_abs = 0;
  for (std::size_t i = 0; i < raw_tets; ++i) {
    if (tet_first[i] != static_cast<int>(i)) continue;
    const int t = tet_index[i];
    for (int j = 0; j < 4; ++j) mesh.tets(j, t) = node_index[static_cast<std::size_t>(raw.tet_nodes[K * i + j])];
    if (quadratic)
      for (int j = 0; j < 10; ++j)
        mesh.tets10(j, t) = node_index[static_cast<std::size_t>(raw.tet_nodes[K * i + static_cast<std::size_t>(j)])];
    mesh.tet_file_tag[static_cast<std::size_t>(t)] = raw.tet_tag[i];
    const Vec3 a = mesh.X.col(mesh.tets(0, t)), b = mesh.X.col(mesh.tets(1, t)), c = mesh.X.col(mesh.tets(2, t)),
               d = mesh.X.col(mesh.tets(3, t));
    const double v = (b - a).dot((c - a).cross(d - a)) / 6.0;
    volume[static_cast<std::size_t>(t)] = v;
    sum_abs += std::abs(v);
  }
  const double mean_abs = sum_abs / m;
  const double threshold = options.degenerate_rel_tol * mean_abs;
  std::vector<int> degenerate;
  for (int t = 0; t < m; ++t)
    if (!(std::abs(volume[static_cast<std::size_t>(t)]) > threshold)) degenerate.push_back(t);
  if (!degenerate.empty()) {
    // Located at the first one; each listed one says where it is.
    auto pos = [&](int t) { return raw.tet_pos[tet_raw[static_cast<std::size_t>(t)]]; };
    std::string list;
    for (std::size_t k = 0; k < std::min<std::size_t>(degenerate.size(), 10); ++k) {
      const int t = degenerate[k];
      list += (k ? ", element " : "element ") + std::to_string(mesh.tet_file_tag[static_cast<std::size_t>(t)]) +
              " (" + parser.location(pos(t)) + ", volume " + num(volume[static_cast<std::size_t>(t)]) + ")";
    }
    if (degenerate.size() > 10) list += " and " + std::to_string(degenerate.size() - 10) + " more";
    parser.fail(pos(degenerate[0]), std::to_string(degenerate.size()) + " degenerate tetrahedra (|volume| <= " +
                                        num(options.degenerate_rel_tol) + " x mean |volume| " + num(mean_abs) +
                                        "): " + list);
  }
  for (int t = 0; t < m; ++t)
    if (volume[static_cast<std::size_t>(t)] < 0) {
      std::swap(mesh.tets(2, t), mesh.tets(3, t));
      if (quadratic) {
        // (a, b, c, d) -> (a, b, d, c) moves the mid-edge nodes too: edges 12 <-> 31 and
        // 20 <-> 30 (nodes 5 <-> 9, 6 <-> 7); 01 and 32 stay.
        std::swap(mesh.tets10(2, t), mesh.tets10(3, t));
        std::swap(mesh.tets10(5, t), mesh.tets10(9, t));
        std::swap(mesh.tets10(6, t), mesh.tets10(7, t));
      }
      ++mesh.reoriented_tets;
    }
  if (quadratic) {
    // Validity of a curved element: det J > 0 at every quadrature point (fem/tet10.hpp).
    // Reported relative to the straight element's det J (6 |volume|): 1 for straight edges.
    std::vector<std::pair<int, double>> invalid;
    for (int t = 0; t < m; ++t) {
      Eigen::Matrix<double, 3, 10> X_e;
      for (int a = 0; a < 10; ++a) X_e.col(a) = mesh.X.col(mesh.tets10(a, t));
      const double rel = fem::tet10::min_det_jacobian(X_e) / (6.0 * std::abs(volume[static_cast<std::size_t>(t)]));
      if (!(rel > 0)) invalid.emplace_back(t, rel);
    }
    if (!invalid.empty()) {
      auto pos = [&](int t) { return raw.tet_pos[tet_raw[static_cast<std::size_t>(t)]]; };
      std::string list;
      for (std::size_t k = 0; k < std::min<std::size_t>(invalid.size(), 10); ++k) {
        const int t = invalid[k].first;
        list += (k ? ", element " : "element ") + std::to_string(mesh.tet_file_tag[static_cast<std::size_t>(t)]) +
                " (" + parser.location(pos(t)) + ", min det J / det J of the straight element " +
                num(invalid[k].second) + ")";
      }
      if (invalid.size() > 10) list += " and " + std::to_string(invalid.size() - 10) + " more";
      parser.fail(pos(invalid[0].first),
                  std::to_string(invalid.size()) + " invalid quadratic tetrahedra (det J <= 0 at a quadrature point: "
                  "a mid-edge node too far from its edge's midpoint): " + list);
    }
  }

  // Physical tags of each span; spans on partition interfaces are ignored.
  const auto& entities = raw.has_partitioned_entities ? raw.partitioned_entities : raw.entities;
  const bool have_entities = raw.has_partitioned_entities || raw.has_entities;
  const std::size_t raw_tris = raw.tri_tag.size();
  std::vector<char> tri_ignored(raw_tris, 0);
  std::vector<std::vector<int>> span_physicals(raw.spans.size());
  for (std::size_t k = 0; k < raw.spans.size(); ++k) {
    const Span& s = raw.spans[k];
    if (!raw.v4) {
      span_physicals[k] = {s.key};
    } else if (have_entities) {
      const auto it = entities.find({s.dim, s.key});
      if (it == entities.end())
        parser.fail(s.pos, "element block refers to entity (dim " + std::to_string(s.dim) + ", tag " +
                               std::to_string(s.key) + "), which is not in $" +
                               (raw.has_partitioned_entities ? "PartitionedEntities" : "Entities"));
      if (it->second.partition_interface) {
        if (s.kind == Kind::tri) std::fill(tri_ignored.begin() + static_cast<std::ptrdiff_t>(s.begin),
                                           tri_ignored.begin() + static_cast<std::ptrdiff_t>(s.end), 1);
        continue;
      }
      span_physicals[k] = it->second.physicals;
    }
  }

  // Triangles: distinct ones, those on the body kept in file order.
  const std::vector<int> tri_first = first_occurrence<3>(raw.tri_nodes, &tri_ignored);
  std::vector<int> tri_index(raw_tris, -1);  // raw triangle -> mesh triangle, or -1 if dropped
  std::vector<int> tri_kept;                 // raw index of each mesh triangle
  for (std::size_t i = 0; i < raw_tris; ++i) {
    if (tri_ignored[i]) continue;
    if (tri_first[i] != static_cast<int>(i)) {
      tri_index[i] = tri_index[static_cast<std::size_t>(tri_first[i])];
      continue;
    }
    bool on_body = true;
    for (int j = 0; j < 3; ++j) on_body = on_body && node_index[static_cast<std::size_t>(raw.tri_nodes[3 * i + j])] >= 0;
    if (on_body) {
      tri_index[i] = static_cast<int>(tri_kept.size());
      tri_kept.push_back(static_cast<int>(i));
    } else {
      ++mesh.dropped_triangles;
    }
  }
  mesh.triangles.resize(3, static_cast<Eigen::Index>(tri_kept.size()));
  for (std::size_t k = 0; k < tri_kept.size(); ++k)
    for (int j = 0; j < 3; ++j)
      mesh.triangles(j, static_cast<Eigen::Index>(k)) =
          node_index[static_cast<std::size_t>(raw.tri_nodes[3 * static_cast<std::size_t>(tri_kept[k]) + j])];

  // Physical groups.
  struct Build {
    std::vector<int> tets, tris, dropped_tris, file_nodes;
  };
  std::map<std::pair<int, int>, Build> builds;
  for (std::size_t k = 0; k < raw.spans.size(); ++k) {
    const Span& s = raw.spans[k];
    for (int phys : span_physicals[k]) {
      Build& g = builds[{s.dim, phys}];
      for (std::size_t i = s.begin; i < s.end; ++i) {
        switch (s.kind) {
          case Kind::tet: g.tets.push_back(tet_index[i]); break;
          case Kind::tri:
            if (tri_index[i] >= 0) g.tris.push_back(tri_index[i]);
            else g.dropped_tris.push_back(tri_first[i]);
            for (int j = 0; j < 3; ++j) g.file_nodes.push_back(raw.tri_nodes[3 * i + j]);
            for (int j = 0; j < 3; ++j)
              if (raw.tri_mid[3 * i + j] >= 0) g.file_nodes.push_back(raw.tri_mid[3 * i + j]);
            break;
          case Kind::aux: g.file_nodes.push_back(raw.aux_nodes[i]); break;
          default: break;
        }
      }
    }
  }
  for (const auto& [key, name] : raw.names) builds[key];  // named groups without elements are listed too

  for (auto& [key, g] : builds) {
    PhysicalGroup group;
    group.dim = key.first;
    group.tag = key.second;
    if (const auto it = raw.names.find(key); it != raw.names.end()) group.name = it->second;
    sort_unique(g.tets, static_cast<std::size_t>(m));
    sort_unique(g.tris, tri_kept.size());
    sort_unique(g.dropped_tris, raw_tris);
    sort_unique(g.file_nodes, file_nodes);
    std::vector<int> nodes;
    nodes.reserve(K * g.tets.size() + g.file_nodes.size());
    for (int t : g.tets)
      for (int j = 0; j < static_cast<int>(K); ++j) nodes.push_back(quadratic ? mesh.tets10(j, t) : mesh.tets(j, t));
    for (int f : g.file_nodes) {
      const int k = node_index[static_cast<std::size_t>(f)];
      if (k >= 0) nodes.push_back(k);
      else ++group.dropped_nodes;
    }
    sort_unique(nodes, static_cast<std::size_t>(n));
    group.nodes = std::move(nodes);
    group.tets = std::move(g.tets);
    group.triangles = std::move(g.tris);
    group.dropped_triangles = static_cast<long>(g.dropped_tris.size());
    mesh.groups.push_back(std::move(group));
  }
  mesh.skipped_elements = std::move(raw.skipped);
  if (quadratic) {
    // Triangles of type 2 in a quadratic mesh: their groups gain the tets' mid-edge nodes.
    const mesh::Triangles6 tri6 = mesh::quadratic_triangles(mesh, mesh.triangles);
    for (PhysicalGroup& g : mesh.groups) {
      if (g.triangles.empty()) continue;
      const std::size_t before = g.nodes.size();
      for (int t : g.triangles)
        for (int j = 3; j < 6; ++j)
          if (tri6(j, t) >= 0) g.nodes.push_back(tri6(j, t));
      if (g.nodes.size() > before) sort_unique(g.nodes, static_cast<std::size_t>(n));
    }
  }
  return mesh;
}

std::string read_whole_file(const std::filesystem::path& file, const std::string& path) {
  std::error_code ec;
  const auto status = std::filesystem::status(file, ec);
  if (ec || !std::filesystem::exists(status)) throw InputError(path + ": cannot open mesh file: no such file");
  if (std::filesystem::is_directory(status))
    throw InputError(path + ": cannot read mesh file: it is a directory, expected a Gmsh .msh file");
  std::unique_ptr<std::FILE, int (*)(std::FILE*)> f(std::fopen(file.c_str(), "rb"), &std::fclose);
  if (!f) throw InputError(path + ": cannot open mesh file: " + std::strerror(errno));
  std::string data;
  char chunk[1 << 16];
  // Read in chunks rather than trusting a size from stat(): works for pipes
  // and files that change size.
  for (;;) {
    const std::size_t got = std::fread(chunk, 1, sizeof chunk, f.get());
    data.append(chunk, got);
    if (got < sizeof chunk) break;
  }
  if (std::ferror(f.get())) throw InputError(path + ": error while reading mesh file: " + std::strerror(errno));
  return data;
}

}  // namespace

mesh::TetMesh read_gmsh(const std::filesystem::path& file, const GmshReadOptions& options) {
  const std::string path = file.string();
  Parser parser(path, read_whole_file(file, path));
  RawMesh raw = parser.parse();
  return build_mesh(std::move(raw), options, parser, path);
}

GmshTriangles read_gmsh_triangles(const std::filesystem::path& file) {
  const std::string path = file.string();
  Parser parser(path, read_whole_file(file, path));
  const RawMesh raw = parser.parse();
  const std::size_t nt = raw.tri_tag.size();
  if (nt == 0) throw InputError(path + ": empty: no triangles (element type 2) in the file");
  std::vector<std::array<int, 3>> kept;
  std::map<std::array<int, 3>, int> seen;
  for (std::size_t t = 0; t < nt; ++t) {
    const std::array<int, 3> tri{raw.tri_nodes[3 * t], raw.tri_nodes[3 * t + 1], raw.tri_nodes[3 * t + 2]};
    std::array<int, 3> key = tri;
    std::sort(key.begin(), key.end());
    if (seen.emplace(key, 0).second) kept.push_back(tri);
  }
  std::vector<int> id(raw.node_tag.size(), -1);
  std::vector<int> order;
  GmshTriangles out;
  out.triangles.resize(3, static_cast<int>(kept.size()));
  for (std::size_t t = 0; t < kept.size(); ++t)
    for (int k = 0; k < 3; ++k) {
      int& i = id[static_cast<std::size_t>(kept[t][k])];
      if (i < 0) {
        i = static_cast<int>(order.size());
        order.push_back(kept[t][k]);
      }
      out.triangles(k, static_cast<int>(t)) = i;
    }
  out.points.resize(3, static_cast<int>(order.size()));
  for (std::size_t i = 0; i < order.size(); ++i)
    for (int d = 0; d < 3; ++d) out.points(d, static_cast<int>(i)) = raw.node_xyz[3 * static_cast<std::size_t>(order[i]) + d];
  return out;
}

}  // namespace softdiff::io
