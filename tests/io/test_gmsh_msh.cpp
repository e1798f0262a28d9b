// Tests of the Gmsh MSH reader (lib/softdiff/io/gmsh_msh.cpp).
//
// Three sources of files:
//  - the real gmsh meshes tests/data/cube_groups.geo once per test process and
//    re-saves that mesh in the other encodings (and partitioned, parametric);
//  - a small spec-driven writer below produces a hand-made mesh (sparse tags,
//    an orphan node, a negative tet, off-body triangles, duplicate groups) in
//    every encoding, including ones gmsh cannot be asked for (size_t = 4);
//  - malformed files written inline, each expecting a precise InputError.
#include <softdiff/core/error.hpp>
#include <softdiff/io/gmsh_msh.hpp>
#include <softdiff/mesh/tet_mesh.hpp>

#include <Eigen/Geometry>
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <random>
#include <sstream>
#include <string>
#include <vector>

namespace {

namespace fs = std::filesystem;
using softdiff::InputError;
using softdiff::io::read_gmsh;
using softdiff::mesh::PhysicalGroup;
using softdiff::mesh::TetMesh;

// ---------------------------------------------------------------------------
// Scratch files: one directory per test process (ctest runs tests in parallel
// processes), removed when the process exits.

struct Scratch {
  fs::path dir = fs::path(SOFTDIFF_TEST_DATA_DIR) / ("gmsh_msh_" + std::to_string(::getpid()));
  Scratch() {
    fs::remove_all(dir);
    fs::create_directories(dir);
  }
  ~Scratch() {
    std::error_code ec;
    fs::remove_all(dir, ec);
  }
};
const fs::path& scratch() {
  static Scratch s;
  return s.dir;
}

fs::path write_file(const std::string& name, const std::string& content) {
  const fs::path p = scratch() / name;
  std::ofstream(p, std::ios::binary) << content;
  return p;
}

std::string read_bytes(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

// The InputError message for reading `p` ("" and a test failure if it reads).
std::string error_of(const fs::path& p) {
  try {
    read_gmsh(p);
  } catch (const InputError& e) {
    return e.what();
  }
  ADD_FAILURE() << p << " was read without error";
  return "";
}

// ---------------------------------------------------------------------------
// The real gmsh: mesh once, save in every encoding. ctest runs every test in
// its own process, so the files are generated once into a private directory
// and then renamed (atomically) to a cache directory named after the .geo
// contents and the gmsh binary; later processes reuse it.

struct GmshFiles {
  fs::path a41, b41, a22, b22, part_a41, part_b41, param_a41, param_b41;
  std::string failure;  // non-empty if gmsh failed
};

GmshFiles gmsh_files_in(const fs::path& dir) {
  GmshFiles f;
  f.a41 = dir / "a41.msh";
  f.b41 = dir / "b41.msh";
  f.a22 = dir / "a22.msh";
  f.b22 = dir / "b22.msh";
  f.part_a41 = dir / "part_a41.msh";
  f.part_b41 = dir / "part_b41.msh";
  f.param_a41 = dir / "param_a41.msh";
  f.param_b41 = dir / "param_b41.msh";
  return f;
}

const GmshFiles& gmsh_files() {
  static const GmshFiles files = [] {
    const fs::path geo = fs::path(SOFTDIFF_SOURCE_DIR) / "tests/data/cube_groups.geo";
    std::error_code ec;
    const auto gmsh_stamp = fs::last_write_time(GMSH_EXECUTABLE, ec).time_since_epoch().count();
    const std::size_t key = std::hash<std::string>{}(read_bytes(geo) + GMSH_EXECUTABLE + std::to_string(gmsh_stamp));
    const fs::path cache = fs::path(SOFTDIFF_TEST_DATA_DIR) / ("gmsh_cube_" + std::to_string(key));
    if (fs::exists(cache / "complete")) return gmsh_files_in(cache);

    const fs::path dir = scratch() / "gmsh_cube";
    fs::create_directories(dir);
    GmshFiles f = gmsh_files_in(dir);
    const fs::path log = dir / "gmsh.log";
    auto run = [&](const std::string& args, const fs::path& out) {
      if (!f.failure.empty()) return;
      const std::string cmd = std::string("\"") + GMSH_EXECUTABLE + "\" " + args + " -o \"" + out.string() +
                              "\" >> \"" + log.string() + "\" 2>&1";
      if (std::system(cmd.c_str()) != 0 || !fs::exists(out))
        f.failure = "command failed: " + cmd + "\n" + read_bytes(log);
    };
    run("-3 \"" + geo.string() + "\" -format msh41", f.a41);  // the only meshing
    const std::string src = "\"" + f.a41.string() + "\" -save ";
    run(src + "-format msh41 -bin", f.b41);
    run(src + "-format msh22", f.a22);
    run(src + "-format msh22 -bin", f.b22);
    run(src + "-part 2 -format msh41", f.part_a41);
    run(src + "-part 2 -format msh41 -bin", f.part_b41);
    run(src + "-save_parametric -format msh41", f.param_a41);
    run(src + "-save_parametric -format msh41 -bin", f.param_b41);
    if (!f.failure.empty()) return f;
    std::ofstream(dir / "complete") << "ok\n";
    fs::rename(dir, cache, ec);  // fails harmlessly if another process was first
    if (fs::exists(cache / "complete")) return gmsh_files_in(cache);
    return f;
  }();
  return files;
}

#define REQUIRE_GMSH() \
  if (!gmsh_files().failure.empty()) FAIL() << gmsh_files().failure

bool same_bits(const softdiff::Mat3X& a, const softdiff::Mat3X& b) {
  return a.cols() == b.cols() && std::memcmp(a.data(), b.data(), sizeof(double) * 3 * a.cols()) == 0;
}

void expect_same_groups(const TetMesh& a, const TetMesh& b) {
  ASSERT_EQ(a.groups.size(), b.groups.size());
  for (std::size_t i = 0; i < a.groups.size(); ++i) {
    const PhysicalGroup &ga = a.groups[i], &gb = b.groups[i];
    SCOPED_TRACE("group " + ga.name);
    EXPECT_EQ(ga.dim, gb.dim);
    EXPECT_EQ(ga.tag, gb.tag);
    EXPECT_EQ(ga.name, gb.name);
    EXPECT_EQ(ga.nodes, gb.nodes);
    EXPECT_EQ(ga.triangles, gb.triangles);
    EXPECT_EQ(ga.tets, gb.tets);
    EXPECT_EQ(ga.dropped_nodes, gb.dropped_nodes);
    EXPECT_EQ(ga.dropped_triangles, gb.dropped_triangles);
  }
}

// Same mesh, same numbering, bit for bit. Element tags are not compared: MSH 2
// renumbers elements.
void expect_same_mesh(const TetMesh& a, const TetMesh& b) {
  EXPECT_TRUE(same_bits(a.X, b.X));
  ASSERT_EQ(a.tets.cols(), b.tets.cols());
  EXPECT_TRUE(a.tets == b.tets);
  ASSERT_EQ(a.triangles.cols(), b.triangles.cols());
  EXPECT_TRUE(a.triangles == b.triangles);
  EXPECT_EQ(a.file_index, b.file_index);
  EXPECT_EQ(a.file_tag, b.file_tag);
  EXPECT_EQ(a.orphan_nodes, b.orphan_nodes);
  EXPECT_EQ(a.reoriented_tets, b.reoriented_tets);
  EXPECT_EQ(a.dropped_triangles, b.dropped_triangles);
  EXPECT_EQ(a.skipped_elements, b.skipped_elements);
  expect_same_groups(a, b);
}

// Sum over outward boundary triangles of (centroid . normal) * area / 3 =
// volume (divergence theorem with div x = 3).
double enclosed_volume(const TetMesh& mesh, const softdiff::Triangles& tris) {
  double v = 0;
  for (Eigen::Index k = 0; k < tris.cols(); ++k) {
    const softdiff::Vec3 a = mesh.X.col(tris(0, k)), b = mesh.X.col(tris(1, k)), c = mesh.X.col(tris(2, k));
    v += (a + b + c).dot((b - a).cross(c - a)) / 18.0;  // (centroid . n |A|) / 3, |n A| = |(b-a)x(c-a)|/2
  }
  return v;
}

TEST(GmshFiles, FourEncodingsGiveIdenticalMeshes) {
  REQUIRE_GMSH();
  const GmshFiles& f = gmsh_files();
  const TetMesh a41 = read_gmsh(f.a41);
  EXPECT_EQ(a41.source, f.a41.string());
  ASSERT_GT(a41.num_tets(), 100);
  for (const fs::path& p : {f.b41, f.a22, f.b22, f.param_a41, f.param_b41}) {
    SCOPED_TRACE(p.filename().string());
    expect_same_mesh(a41, read_gmsh(p));
  }
  EXPECT_EQ(a41.tet_file_tag, read_gmsh(f.b41).tet_file_tag);
  EXPECT_EQ(read_gmsh(f.a22).tet_file_tag, read_gmsh(f.b22).tet_file_tag);
}

TEST(GmshFiles, CubeGroupsAndGeometry) {
  REQUIRE_GMSH();
  const TetMesh mesh = read_gmsh(gmsh_files().a41);
  EXPECT_EQ(mesh.orphan_nodes, 0);
  EXPECT_EQ(mesh.dropped_triangles, 0);
  EXPECT_EQ(static_cast<std::size_t>(mesh.num_nodes()), mesh.file_index.size());

  ASSERT_EQ(mesh.groups.size(), 5u);
  const char* names[] = {"tip", "edge", "clamp", "top", "solid"};  // sorted by (dim, tag)
  for (std::size_t i = 0; i < 5; ++i) EXPECT_EQ(mesh.groups[i].name, names[i]);

  const PhysicalGroup* clamp = mesh.find_group("clamp");
  const PhysicalGroup* top = mesh.find_group("top", 2);
  const PhysicalGroup* solid = mesh.find_group("solid");
  const PhysicalGroup* tip = mesh.find_group("tip");
  const PhysicalGroup* edge = mesh.find_group("edge");
  ASSERT_TRUE(clamp && top && solid && tip && edge);
  EXPECT_EQ(mesh.find_group("clamp", 3), nullptr);
  EXPECT_EQ(mesh.find_group("nope"), nullptr);
  EXPECT_EQ(clamp->dim, 2);
  EXPECT_EQ(clamp->tag, 11);

  // Every node of a group lies on its geometric entity.
  ASSERT_FALSE(clamp->nodes.empty());
  for (int i : clamp->nodes) EXPECT_EQ(mesh.X(0, i), 0.0);
  for (int i : top->nodes) EXPECT_EQ(mesh.X(2, i), 0.25);
  for (int i : edge->nodes) EXPECT_TRUE(mesh.X(0, i) == 0.0 && mesh.X(1, i) == 0.0);
  ASSERT_EQ(tip->nodes.size(), 1u);
  EXPECT_TRUE(mesh.X.col(tip->nodes[0]).isApprox(softdiff::Vec3(1, 0.5, 0.25)));
  EXPECT_GE(edge->nodes.size(), 3u);
  for (int t : clamp->triangles)
    for (int j = 0; j < 3; ++j) EXPECT_EQ(mesh.X(0, mesh.triangles(j, t)), 0.0);
  EXPECT_TRUE(std::is_sorted(clamp->nodes.begin(), clamp->nodes.end()));
  EXPECT_EQ(solid->tets.size(), static_cast<std::size_t>(mesh.num_tets()));
  EXPECT_EQ(solid->nodes.size(), static_cast<std::size_t>(mesh.num_nodes()));
  EXPECT_EQ(static_cast<Eigen::Index>(clamp->triangles.size() + top->triangles.size()), mesh.triangles.cols());

  // Group triangles are boundary faces; the boundary is closed and outward.
  const softdiff::Triangles boundary = softdiff::mesh::boundary_triangles(mesh.tets);
  auto key = [](int a, int b, int c) {
    std::array<int, 3> k{a, b, c};
    std::sort(k.begin(), k.end());
    return k;
  };
  std::vector<std::array<int, 3>> faces;
  for (Eigen::Index k = 0; k < boundary.cols(); ++k) faces.push_back(key(boundary(0, k), boundary(1, k), boundary(2, k)));
  std::sort(faces.begin(), faces.end());
  for (int t : clamp->triangles)
    EXPECT_TRUE(std::binary_search(faces.begin(), faces.end(),
                                   key(mesh.triangles(0, t), mesh.triangles(1, t), mesh.triangles(2, t))));
  EXPECT_NEAR(enclosed_volume(mesh, boundary), 0.125, 1e-12);

  const auto q = softdiff::mesh::quality(mesh.X, mesh.tets);
  EXPECT_NEAR(q.total_volume, 0.125, 1e-12);
  EXPECT_GT(q.min_volume, 0);
  EXPECT_TRUE(q.bbox_min.isApprox(softdiff::Vec3(0, 0, 0)));
  EXPECT_TRUE(q.bbox_max.isApprox(softdiff::Vec3(1, 0.5, 0.25)));
  EXPECT_GE(q.min_aspect, 1.0 - 1e-12);
  EXPECT_LT(q.median_aspect, 3.0);
}

// Partitioned files (MSH 4.1 $PartitionedEntities) renumber nodes: compare the
// geometry of every group instead of indices.
TEST(GmshFiles, PartitionedMeshHasTheSameGroups) {
  REQUIRE_GMSH();
  const TetMesh ref = read_gmsh(gmsh_files().a41);
  auto points = [](const TetMesh& m, const PhysicalGroup& g) {
    std::vector<std::array<double, 3>> p;
    for (int i : g.nodes) p.push_back({m.X(0, i), m.X(1, i), m.X(2, i)});
    std::sort(p.begin(), p.end());
    return p;
  };
  for (const fs::path& path : {gmsh_files().part_a41, gmsh_files().part_b41}) {
    SCOPED_TRACE(path.filename().string());
    const TetMesh part = read_gmsh(path);
    EXPECT_EQ(part.num_tets(), ref.num_tets());
    // Triangles on partition interfaces are not part of the model: ignored.
    EXPECT_EQ(part.triangles.cols(), ref.triangles.cols());
    EXPECT_EQ(part.num_nodes(), ref.num_nodes());
    ASSERT_EQ(part.groups.size(), ref.groups.size());
    for (std::size_t i = 0; i < ref.groups.size(); ++i) {
      EXPECT_EQ(part.groups[i].name, ref.groups[i].name);
      EXPECT_EQ(part.groups[i].tets.size(), ref.groups[i].tets.size());
      EXPECT_EQ(part.groups[i].triangles.size(), ref.groups[i].triangles.size());
      EXPECT_EQ(points(part, part.groups[i]), points(ref, ref.groups[i]));
    }
    EXPECT_NEAR(softdiff::mesh::quality(part.X, part.tets).total_volume, 0.125, 1e-12);
  }
}

// Cut and corrupt real files: every outcome must be a clean read or an
// InputError naming the file (never a crash, hang or other exception).
TEST(GmshFiles, TruncatedAndCorruptedFilesFailCleanly) {
  REQUIRE_GMSH();
  const GmshFiles& f = gmsh_files();
  std::mt19937 rng(12345);
  int errors = 0;
  for (const fs::path& src : {f.a41, f.b41, f.a22, f.b22, f.part_b41, f.param_b41}) {
    const std::string bytes = read_bytes(src);
    const fs::path p = scratch() / ("fuzz_" + src.filename().string());
    auto attempt = [&](const std::string& content, const std::string& what) {
      std::ofstream(p, std::ios::binary | std::ios::trunc) << content;
      try {
        read_gmsh(p);
      } catch (const InputError& e) {
        ++errors;
        EXPECT_EQ(std::string(e.what()).rfind(p.string() + ":", 0), 0u) << what << ": " << e.what();
      } catch (const std::exception& e) {
        ADD_FAILURE() << what << ": unexpected exception " << e.what();
      }
    };
    for (int k = 1; k < 60; ++k) {
      const std::size_t cut = bytes.size() * k / 60;
      attempt(bytes.substr(0, cut), src.filename().string() + " cut at " + std::to_string(cut));
    }
    for (int k = 0; k < 150; ++k) {
      std::string mutated = bytes;
      const std::size_t at = std::uniform_int_distribution<std::size_t>(0, bytes.size() - 1)(rng);
      mutated[at] = static_cast<char>(std::uniform_int_distribution<int>(0, 255)(rng));
      attempt(mutated, src.filename().string() + " byte " + std::to_string(at) + " changed");
    }
  }
  EXPECT_GT(errors, 300);
}

TEST(GmshFiles, BinaryWithOtherByteOrderIsAnError) {
  REQUIRE_GMSH();
  for (const fs::path& src : {gmsh_files().b41, gmsh_files().b22}) {
    std::string bytes = read_bytes(src);
    const std::size_t one = bytes.find("\n", bytes.find("$MeshFormat\n") + 12) + 1;  // after the version line
    ASSERT_EQ(std::memcmp(bytes.data() + one, "\x01\x00\x00\x00", 4), 0);
    std::memcpy(bytes.data() + one, "\x00\x00\x00\x01", 4);
    const fs::path p = write_file("swapped_" + src.filename().string(), bytes);
    const std::string msg = error_of(p);
    EXPECT_EQ(msg.rfind(p.string() + ": byte " + std::to_string(one) + ": ", 0), 0u) << msg;
    EXPECT_NE(msg.find("opposite byte order"), std::string::npos) << msg;
  }
}

TEST(GmshFiles, TruncatedBinaryNamesTheProblem) {
  REQUIRE_GMSH();
  const std::string bytes = read_bytes(gmsh_files().b22);
  const std::size_t nodes = bytes.find("$Nodes\n");
  const fs::path p = write_file("cut_b22.msh", bytes.substr(0, nodes + 200));
  const std::string msg = error_of(p);
  EXPECT_EQ(msg.rfind(p.string() + ":", 0), 0u) << msg;
  EXPECT_NE(msg.find("cannot fit"), std::string::npos) << msg;
}

// ---------------------------------------------------------------------------
// A hand-made mesh written by a small writer, in every encoding.

struct SpecNode {
  long tag;
  double x, y, z;
  int entity_dim, entity_tag;
};
struct SpecElement {
  long tag;
  int type;
  std::vector<long> nodes;
  int entity_dim, entity_tag;
};
struct Spec {
  std::vector<std::tuple<int, int, std::string>> names;
  std::vector<SpecNode> nodes;
  std::vector<SpecElement> elements;
  std::map<std::pair<int, int>, std::vector<int>> physicals;  // entity -> physical tags
};

template <class T>
void put(std::string& s, T v) {
  s.append(reinterpret_cast<const char*>(&v), sizeof v);
}

std::string names_section(const Spec& spec) {
  std::ostringstream o;
  o << "$PhysicalNames\n" << spec.names.size() << "\n";
  for (const auto& [dim, tag, name] : spec.names) o << dim << " " << tag << " \"" << name << "\"\n";
  o << "$EndPhysicalNames\n";
  return o.str();
}

// MSH 2.2: an element is written once per physical group of its entity (as
// gmsh does); copies get the tag + 1000.
std::string to_msh22(const Spec& spec, bool binary) {
  std::ostringstream o;
  o.precision(17);
  o << "$MeshFormat\n2.2 " << (binary ? 1 : 0) << " 8\n";
  std::string s = o.str();
  if (binary) put<std::int32_t>(s, 1), s += "\n";
  s += "$EndMeshFormat\n" + names_section(spec);
  std::ostringstream nodes;
  nodes.precision(17);
  nodes << "$Nodes\n" << spec.nodes.size() << "\n";
  s += nodes.str();
  for (const SpecNode& n : spec.nodes) {
    if (binary) {
      put<std::int32_t>(s, static_cast<std::int32_t>(n.tag));
      put(s, n.x), put(s, n.y), put(s, n.z);
    } else {
      std::ostringstream l;
      l.precision(17);
      l << n.tag << " " << n.x << " " << n.y << " " << n.z << "\n";
      s += l.str();
    }
  }
  s += binary ? "\n$EndNodes\n" : "$EndNodes\n";
  struct Out {
    long tag;
    int type, physical, entity;
    const std::vector<long>* nodes;
  };
  std::vector<Out> out;
  for (const SpecElement& e : spec.elements) {
    const auto it = spec.physicals.find({e.entity_dim, e.entity_tag});
    const std::vector<int> phys = it == spec.physicals.end() || it->second.empty() ? std::vector<int>{0} : it->second;
    for (std::size_t k = 0; k < phys.size(); ++k)
      out.push_back({e.tag + 1000 * static_cast<long>(k), e.type, phys[k], e.entity_tag, &e.nodes});
  }
  s += "$Elements\n" + std::to_string(out.size()) + "\n";
  for (const Out& e : out) {
    if (binary) {  // one block per element: simple and legal
      put<std::int32_t>(s, e.type), put<std::int32_t>(s, 1), put<std::int32_t>(s, 2);
      put<std::int32_t>(s, static_cast<std::int32_t>(e.tag)), put<std::int32_t>(s, e.physical), put<std::int32_t>(s, e.entity);
      for (long n : *e.nodes) put<std::int32_t>(s, static_cast<std::int32_t>(n));
    } else {
      // (Appending piecewise: GCC 12 gives a false -Wrestrict on `" " + to_string(..)`.)
      std::ostringstream l;
      l << e.tag << " " << e.type << " 2 " << e.physical << " " << e.entity;
      for (long n : *e.nodes) l << " " << n;
      s += l.str() + "\n";
    }
  }
  s += binary ? "\n$EndElements\n" : "$EndElements\n";
  return s;
}

// MSH 4.1: consecutive nodes on one entity form a block, as do consecutive
// elements of one type on one entity. `parametric` adds dim parametric
// coordinates to every node (even on volumes, which gmsh does not write).
std::string to_msh41(const Spec& spec, bool binary, int size_t_bytes = 8, bool parametric = false) {
  std::string s = "$MeshFormat\n4.1 " + std::string(binary ? "1 " : "0 ") + std::to_string(size_t_bytes) + "\n";
  if (binary) put<std::int32_t>(s, 1), s += "\n";
  s += "$EndMeshFormat\n" + names_section(spec);
  auto num = [](double v) {
    std::ostringstream o;
    o.precision(17);
    o << v;
    return o.str();
  };
  auto size = [&](std::uint64_t v) {
    if (!binary) s += std::to_string(v) + " ";
    else if (size_t_bytes == 8) put<std::uint64_t>(s, v);
    else put<std::uint32_t>(s, static_cast<std::uint32_t>(v));
  };
  auto integer = [&](int v) {
    if (binary) put<std::int32_t>(s, v);
    else s += std::to_string(v) + " ";
  };
  auto real = [&](double v) {
    if (binary) put(s, v);
    else s += num(v) + " ";
  };
  auto eol = [&] {
    if (!binary) s += "\n";
  };

  s += "$Entities\n";
  std::array<std::vector<int>, 4> entities;
  for (const auto& [key, phys] : spec.physicals) entities[key.first].push_back(key.second);
  for (int d = 0; d < 4; ++d) size(entities[d].size());
  eol();
  for (int d = 0; d < 4; ++d)
    for (int tag : entities[d]) {
      integer(tag);
      for (int k = 0; k < (d == 0 ? 3 : 6); ++k) real(0.0);
      const auto& phys = spec.physicals.at({d, tag});
      size(phys.size());
      for (int p : phys) integer(p);
      if (d > 0) size(0);
      eol();
    }
  s += binary ? "\n$EndEntities\n" : "$EndEntities\n";

  auto runs = [](const auto& items, auto same) {
    std::vector<std::pair<std::size_t, std::size_t>> r;
    for (std::size_t i = 0; i < items.size(); ++i)
      if (i == 0 || !same(items[i - 1], items[i])) r.push_back({i, i + 1});
      else r.back().second = i + 1;
    return r;
  };
  long min_tag = spec.nodes.front().tag, max_tag = min_tag;
  for (const SpecNode& n : spec.nodes) min_tag = std::min(min_tag, n.tag), max_tag = std::max(max_tag, n.tag);
  const auto node_blocks =
      runs(spec.nodes, [](const SpecNode& a, const SpecNode& b) { return a.entity_dim == b.entity_dim && a.entity_tag == b.entity_tag; });
  s += "$Nodes\n";
  size(node_blocks.size()), size(spec.nodes.size()), size(static_cast<std::uint64_t>(min_tag)), size(static_cast<std::uint64_t>(max_tag));
  eol();
  for (const auto& [b, e] : node_blocks) {
    const SpecNode& first = spec.nodes[b];
    integer(first.entity_dim), integer(first.entity_tag), integer(parametric ? 1 : 0), size(e - b);
    eol();
    for (std::size_t i = b; i < e; ++i) size(static_cast<std::uint64_t>(spec.nodes[i].tag)), eol();
    for (std::size_t i = b; i < e; ++i) {
      real(spec.nodes[i].x), real(spec.nodes[i].y), real(spec.nodes[i].z);
      if (parametric)
        for (int k = 0; k < first.entity_dim; ++k) real(0.5);
      eol();
    }
  }
  s += binary ? "\n$EndNodes\n" : "$EndNodes\n";

  const auto element_blocks = runs(spec.elements, [](const SpecElement& a, const SpecElement& b) {
    return a.type == b.type && a.entity_dim == b.entity_dim && a.entity_tag == b.entity_tag;
  });
  s += "$Elements\n";
  size(element_blocks.size()), size(spec.elements.size()), size(1), size(1000);
  eol();
  for (const auto& [b, e] : element_blocks) {
    const SpecElement& first = spec.elements[b];
    integer(first.entity_dim), integer(first.entity_tag), integer(first.type), size(e - b);
    eol();
    for (std::size_t i = b; i < e; ++i) {
      size(static_cast<std::uint64_t>(spec.elements[i].tag));
      for (long n : spec.elements[i].nodes) size(static_cast<std::uint64_t>(n));
      eol();
    }
  }
  s += binary ? "\n$EndElements\n" : "$EndElements\n";
  return s;
}

// Nodes listed out of tag order, with a node (99) in no tet, a negatively
// oriented tet, a triangle off the body, a point group off the body, tets in
// two volume groups, a skipped quadrangle and a named group without elements.
Spec hand_spec(long tag50) {
  Spec s;
  s.names = {{0, 8, "off_point"}, {1, 5, "edge"}, {2, 7, "bottom"}, {2, 9, "unused"}, {3, 1, "body"}, {3, 2, "all"}};
  s.nodes = {{40, 0, 0, 1, 3, 1}, {10, 0, 0, 0, 3, 1},    {99, 5, 5, 5, 0, 1},
             {30, 0, 1, 0, 3, 1}, {20, 1, 0, 0, 3, 1}, {tag50, 1, 1, 1, 3, 1}};
  s.elements = {{1, 15, {99}, 0, 1},
                {2, 1, {10, 20}, 1, 1},
                {3, 2, {10, 20, 30}, 2, 1},
                {4, 2, {10, 20, 99}, 2, 1},
                {5, 3, {10, 20, tag50, 30}, 2, 2},
                {6, 4, {10, 20, 30, 40}, 3, 1},
                {7, 4, {30, 20, 40, tag50}, 3, 1}};
  s.physicals = {{{0, 1}, {8}}, {{1, 1}, {5}}, {{2, 1}, {7}}, {{2, 2}, {}}, {{3, 1}, {1, 2}}};
  return s;
}

void check_hand_mesh(const TetMesh& mesh, long tag50) {
  // File node order kept, node 99 dropped.
  EXPECT_EQ(mesh.file_tag, (std::vector<long>{40, 10, 30, 20, tag50}));
  EXPECT_EQ(mesh.file_index, (std::vector<long>{0, 1, 3, 4, 5}));
  EXPECT_EQ(mesh.orphan_nodes, 1);
  ASSERT_EQ(mesh.num_nodes(), 5);
  EXPECT_EQ(mesh.X.col(0), softdiff::Vec3(0, 0, 1));
  EXPECT_EQ(mesh.X.col(4), softdiff::Vec3(1, 1, 1));
  // Tet 7 (30 20 40 50) is negative: its last two nodes are swapped.
  ASSERT_EQ(mesh.num_tets(), 2);
  EXPECT_EQ(mesh.tets.col(0), Eigen::Vector4i(1, 3, 2, 0));
  EXPECT_EQ(mesh.tets.col(1), Eigen::Vector4i(2, 3, 4, 0));
  EXPECT_EQ(mesh.reoriented_tets, 1);
  EXPECT_EQ(mesh.tet_file_tag, (std::vector<long>{6, 7}));
  EXPECT_GT(softdiff::mesh::quality(mesh.X, mesh.tets).min_volume, 0);
  // Triangle 4 touches node 99: off the body.
  ASSERT_EQ(mesh.triangles.cols(), 1);
  EXPECT_EQ(mesh.triangles.col(0), Eigen::Vector3i(1, 3, 2));
  EXPECT_EQ(mesh.dropped_triangles, 1);
  EXPECT_EQ(mesh.skipped_elements, (std::map<int, long>{{3, 1}}));

  ASSERT_EQ(mesh.groups.size(), 6u);
  auto expect_group = [&](std::size_t i, int dim, int tag, const char* name, std::vector<int> nodes,
                          std::vector<int> tris, std::vector<int> tets, long dropped_nodes, long dropped_tris) {
    const PhysicalGroup& g = mesh.groups[i];
    SCOPED_TRACE(name);
    EXPECT_EQ(g.dim, dim);
    EXPECT_EQ(g.tag, tag);
    EXPECT_EQ(g.name, name);
    EXPECT_EQ(g.nodes, nodes);
    EXPECT_EQ(g.triangles, tris);
    EXPECT_EQ(g.tets, tets);
    EXPECT_EQ(g.dropped_nodes, dropped_nodes);
    EXPECT_EQ(g.dropped_triangles, dropped_tris);
  };
  expect_group(0, 0, 8, "off_point", {}, {}, {}, 1, 0);
  expect_group(1, 1, 5, "edge", {1, 3}, {}, {}, 0, 0);
  expect_group(2, 2, 7, "bottom", {1, 2, 3}, {0}, {}, 1, 1);
  expect_group(3, 2, 9, "unused", {}, {}, {}, 0, 0);
  expect_group(4, 3, 1, "body", {0, 1, 2, 3, 4}, {}, {0, 1}, 0, 0);
  expect_group(5, 3, 2, "all", {0, 1, 2, 3, 4}, {}, {0, 1}, 0, 0);
}

TEST(GmshHandMade, EveryEncodingWithDenseTags) {
  const Spec spec = hand_spec(50);
  const std::vector<std::pair<std::string, std::string>> files = {
      {"hand_a22.msh", to_msh22(spec, false)},        {"hand_b22.msh", to_msh22(spec, true)},
      {"hand_a41.msh", to_msh41(spec, false)},        {"hand_b41.msh", to_msh41(spec, true)},
      {"hand_b41_4.msh", to_msh41(spec, true, 4)},    {"hand_a41_param.msh", to_msh41(spec, false, 8, true)},
      {"hand_b41_param.msh", to_msh41(spec, true, 8, true)}};
  for (const auto& [name, content] : files) {
    SCOPED_TRACE(name);
    check_hand_mesh(read_gmsh(write_file(name, content)), 50);
  }
}

TEST(GmshHandMade, SparseTagsUseTheSortedLookup) {
  const long big = 1000000000000L;  // far beyond 4 x the node count
  const Spec spec = hand_spec(big);
  check_hand_mesh(read_gmsh(write_file("sparse_a41.msh", to_msh41(spec, false))), big);
  check_hand_mesh(read_gmsh(write_file("sparse_b41.msh", to_msh41(spec, true))), big);
  check_hand_mesh(read_gmsh(write_file("sparse_a22.msh", to_msh22(spec, false))), big);
}

// Binary data follows its header line directly; values whose first byte is
// 0x09-0x0d or 0x20 must not be taken for whitespace. Here: node tag 9 first
// (MSH 2.2), 13 node blocks and 9 element blocks (MSH 4.1).
TEST(GmshHandMade, BinaryDataStartingWithWhitespaceBytes) {
  Spec spec;
  const long tags[13] = {9, 10, 11, 12, 13, 32, 1, 2, 3, 4, 5, 6, 7};
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(0, 1);
  for (int i = 0; i < 13; ++i) {
    spec.nodes.push_back({tags[i], u(rng), u(rng), u(rng), 3, i + 1});
    spec.physicals[{3, i + 1}] = {};
  }
  for (int k = 0; k < 9; ++k)
    spec.elements.push_back({100 + k, 4, {tags[k], tags[k + 1], tags[k + 2], tags[k + 3]}, 3, k + 1});
  for (const auto& [name, content] : {std::pair{"ws_b22.msh", to_msh22(spec, true)}, {"ws_b41.msh", to_msh41(spec, true)},
                                      {"ws_a41.msh", to_msh41(spec, false)}}) {
    SCOPED_TRACE(name);
    const TetMesh mesh = read_gmsh(write_file(name, content));
    EXPECT_EQ(mesh.num_tets(), 9);
    EXPECT_EQ(mesh.file_tag, std::vector<long>(tags, tags + 12));
  }
}

TEST(GmshHandMade, WindowsLineEndingsAndBlankLines) {
  std::string text = to_msh22(hand_spec(50), false);
  std::string crlf;
  for (char c : text) crlf += c == '\n' ? std::string("\r\n") : std::string(1, c);
  check_hand_mesh(read_gmsh(write_file("crlf.msh", crlf)), 50);
  // Blank lines between records and an unknown section are tolerated.
  text.insert(text.find("$Nodes"), "\n$Comments\nanything $EndNodes here\n$EndComments\n\n");
  text.insert(text.find("$EndElements"), "\n\n");
  check_hand_mesh(read_gmsh(write_file("blank.msh", text)), 50);
}

TEST(GmshHandMade, DegenerateRelTolOption) {
  // A sliver (volume 1e-6) next to a unit tet: fine by default, an error with a
  // tolerance above its relative volume.
  const std::string text =
      "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n5\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n5 1 1 0.000006\n$EndNodes\n"
      "$Elements\n2\n11 4 0 1 2 3 4\n12 4 0 2 3 5 1\n$EndElements\n";
  const fs::path p = write_file("sliver.msh", text);
  EXPECT_EQ(read_gmsh(p).num_tets(), 2);
  try {
    read_gmsh(p, {.degenerate_rel_tol = 1e-3});
    ADD_FAILURE() << "no error";
  } catch (const InputError& e) {
    const std::string msg = e.what();
    EXPECT_EQ(msg.rfind(p.string() + ":15: 1 degenerate tetrahedra", 0), 0u) << msg;
    EXPECT_NE(msg.find("element 12 (line 15, volume "), std::string::npos) << msg;
  }
}

TEST(GmshHandMade, PlusSignsAndDenormals) {
  const TetMesh mesh = read_gmsh(write_file(
      "plus.msh", "$MeshFormat\n2.2 +0 8\n$EndMeshFormat\n$Nodes\n+4\n+1 1e-320 0 0\n2 +1 0 0\n3 0 +.5e1 0\n4 0 0 1\n"
                  "$EndNodes\n$Elements\n1\n1 4 0 1 2 3 4\n$EndElements\n"));
  EXPECT_EQ(mesh.X(0, 0), 1e-320);
  EXPECT_EQ(mesh.X(1, 2), 5.0);
}

TEST(GmshHandMade, DegenerateListShowsTheFirstTen) {
  // One good tet and 12 flat ones (all nodes in the plane z = 0).
  std::string text = "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n17\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n";
  for (int i = 0; i < 13; ++i) text += std::to_string(5 + i) + " " + std::to_string(i) + " " + std::to_string(i * i) + " 0\n";
  text += "$EndNodes\n$Elements\n13\n1 4 0 1 2 3 4\n";
  for (int k = 0; k < 12; ++k)
    text += std::to_string(100 + k) + " 4 0 " + std::to_string(5 + k) + " 2 3 " + std::to_string(6 + k) + "\n";
  text += "$EndElements\n";
  const fs::path p = write_file("many_degenerate.msh", text);
  const std::string msg = error_of(p);
  EXPECT_EQ(msg.rfind(p.string() + ":27: 12 degenerate tetrahedra", 0), 0u) << msg;
  EXPECT_NE(msg.find("element 100 (line 27, volume 0), element 101 (line 28, volume 0)"), std::string::npos) << msg;
  EXPECT_NE(msg.find("element 109 (line 36, volume 0) and 2 more"), std::string::npos) << msg;
  EXPECT_EQ(msg.find("element 110"), std::string::npos) << msg;
}

// ---------------------------------------------------------------------------
// Malformed files. Each case: file content, the `:LINE: ` (or `: byte N: `, or
// just `: `) that must follow the file name, and substrings of the message.

const std::string kFormat22 = "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n";
const std::string kNodes22 = "$Nodes\n4\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n$EndNodes\n";  // lines 4-10
const std::string kTet22 = "$Elements\n1\n1 4 2 1 1 1 2 3 4\n$EndElements\n";               // lines 11-14

struct BadCase {
  const char* name;
  std::string content;
  std::string where;  // what follows the path
  std::vector<std::string> says;
};

class GmshMalformed : public ::testing::TestWithParam<BadCase> {};

TEST_P(GmshMalformed, IsAnInputErrorSayingWhereAndWhat) {
  const BadCase& c = GetParam();
  const fs::path p = write_file(std::string(c.name) + ".msh", c.content);
  const std::string msg = error_of(p);
  EXPECT_EQ(msg.rfind(p.string() + c.where, 0), 0u) << msg;
  for (const std::string& s : c.says) EXPECT_NE(msg.find(s), std::string::npos) << "missing '" << s << "' in: " << msg;
}

std::vector<BadCase> bad_cases() {
  const std::string f = kFormat22, n = kNodes22, e = kTet22;
  const std::string f41 = "$MeshFormat\n4.1 0 8\n$EndMeshFormat\n";
  const std::string n41 = "$Nodes\n1 4 1 4\n3 1 0 4\n1\n2\n3\n4\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n$EndNodes\n";  // lines 4-15
  const std::string e41 = "$Elements\n1 1 1 1\n3 1 4 1\n1 1 2 3 4\n$EndElements\n";
  return {
      {"valid_then_empty", "", ": ", {"empty file"}},
      {"not_gmsh", "solid cube\nfacet normal 0 0 1\n", ":1: ", {"not a Gmsh MSH file", "$MeshFormat", "'solid'"}},
      {"msh1", "$NOD\n1\n1 0 0 0\n$ENDNOD\n", ":1: ", {"MSH version 1", "2.2 and 4.1"}},
      {"version_3", "$MeshFormat\n3.0 0 8\n$EndMeshFormat\n", ":2: ", {"unsupported MSH format version 3.0", "2.2 and 4.1"}},
      {"version_40", "$MeshFormat\n4.0 0 8\n$EndMeshFormat\n", ":2: ", {"version 4.0", "2.2 and 4.1", "gmsh"}},
      {"version_garbage", "$MeshFormat\nabc 0 8\n$EndMeshFormat\n", ":2: ", {"expected the MSH format version", "'abc'"}},
      {"file_type", "$MeshFormat\n2.2 2 8\n$EndMeshFormat\n", ":2: ", {"file type 0 (ASCII) or 1 (binary)", "found 2"}},
      {"binary_data_size", "$MeshFormat\n2.2 1 4\n", ":2: ", {"data size 8", "found 4"}},
      {"no_end_format", "$MeshFormat\n2.2 0 8\n", ":3: ", {"expected $EndMeshFormat", "end of file"}},
      {"only_format", f, ": ", {"no $Nodes section"}},
      {"no_elements", f + n, ": ", {"no $Elements section"}},
      {"nodes_truncated", f + "$Nodes\n4\n1 0 0 0\n2 1 0 0\n", ":5: ", {"4 nodes cannot fit", "truncated file"}},
      {"nodes_misspelled_end", f + "$Nodes\n4\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n$EndNode\n", ":10: ",
       {"expected $EndNodes", "found '$EndNode'"}},
      {"node_count_too_small", f + "$Nodes\n3\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n$EndNodes\n", ":9: ",
       {"expected $EndNodes", "node count", "found '4'"}},
      {"bad_number", f + "$Nodes\n4\n1 0 0 0\n2 1 0 abc\n3 0 1 0\n4 0 0 1\n$EndNodes\n", ":7: ", {"expected node z coordinate (a number)", "'abc'"}},
      {"short_node_line", f + "$Nodes\n4\n1 0 0 0\n2 1 0\n3 0 1 0\n4 0 0 1\n$EndNodes\n", ":7: ", {"expected node z coordinate", "end of line"}},
      {"extra_value", f + "$Nodes\n4\n1 0 0 0 7\n2 1 0 0\n3 0 1 0\n4 0 0 1\n$EndNodes\n", ":6: ", {"unexpected '7'", "expected end of line"}},
      {"nan_coordinate", f + "$Nodes\n4\n1 0 0 nan\n2 1 0 0\n3 0 1 0\n4 0 0 1\n$EndNodes\n", ":6: ", {"finite", "'nan'"}},
      {"negative_node_tag", f + "$Nodes\n4\n-1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n$EndNodes\n", ":6: ", {"expected node tag (a non-negative integer)", "'-1'"}},
      {"plus_minus", f + "$Nodes\n4\n1 +-1 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n$EndNodes\n", ":6: ",
       {"expected node x coordinate (a number)", "'+-1'"}},
      {"coordinate_overflow", f + "$Nodes\n4\n1 1e400 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n$EndNodes\n", ":6: ",
       {"node x coordinate '1e400' is out of range"}},
      {"zero_node_tag", f + "$Nodes\n4\n0 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n$EndNodes\n", ":6: ", {"node tag 0 is out of range"}},
      {"duplicate_node_tag", f + "$Nodes\n4\n1 0 0 0\n2 1 0 0\n2 0 1 0\n4 0 0 1\n$EndNodes\n" + e, ":4: ",
       {"node tag 2 is defined twice", "#2 and #3"}},
      {"huge_node_count", f + "$Nodes\n1000000000000\n1 0 0 0\n", ":5: ", {"1000000000000 nodes cannot fit"}},
      {"missing_end_nodes", f + "$Nodes\n4\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n$Elements\n", ":10: ",
       {"expected $EndNodes", "'$Elements'"}},
      {"elements_first", f + e + n, ":4: ", {"$Elements section before any $Nodes"}},
      {"undefined_node", f + n + "$Elements\n1\n7 4 2 1 1 1 2 3 9\n$EndElements\n", ":13: ",
       {"element 7 (type 4 (4-node tetrahedron)) refers to node 9, which is not defined in $Nodes"}},
      {"element_short", f + n + "$Elements\n1\n7 4 2 1 1 1 2 3\n$EndElements\n", ":13: ",
       {"expected node tag of the element", "end of line"}},
      {"element_long", f + n + "$Elements\n1\n7 4 2 1 1 1 2 3 4 4\n$EndElements\n", ":13: ", {"unexpected '4' after"}},
      {"element_count_too_big", f + n + "$Elements\n2\n1 4 2 1 1 1 2 3 4\n$EndElements\n", ":14: ",
       {"expected element tag", "'$EndElements'"}},
      {"no_tets", f + n + "$Elements\n1\n1 2 2 1 1 1 2 3\n$EndElements\n", ": ",
       {"no tetrahedra", "found 1 triangles", "Physical Volume", "gmsh -3"}},
      {"second_order_tets",
       f + n + "$Elements\n3\n1 4 2 1 1 1 2 3 4\n2 11 2 1 1 1 2 3 4 1 2 3 4 1 2\n3 11 2 1 1 1 2 3 4 1 2 3 4 1 2\n$EndElements\n",
       ":14: ", {"element 2 is a type 11 (10-node tetrahedron)", "(line 13) is a type 4", "one element order"}},
      {"hexahedra", f + n + "$Elements\n2\n1 4 2 1 1 1 2 3 4\n2 5 2 1 1 1 2 3 4 1 2 3 4\n$EndElements\n", ":14: ",
       {"1 elements of type 5 (8-node hexahedron)"}},
      {"unknown_type", f + n + "$Elements\n1\n1 999 2 1 1 1 2 3 4\n$EndElements\n", ":13: ", {"unknown element type 999"}},
      {"polygon", f + n + "$Elements\n1\n1 34 2 1 1 1 2 3\n$EndElements\n", ":13: ", {"type 34", "no fixed node count"}},
      {"degenerate",
       f + "$Nodes\n5\n1 0 0 0\n2 1 0 0\n3 0 1 0\n4 0 0 1\n5 1 1 0\n$EndNodes\n$Elements\n2\n1 4 0 1 2 3 4\n2 4 0 1 2 3 5\n$EndElements\n",
       ":15: ", {"1 degenerate tetrahedra", "element 2 (line 15, volume 0)"}},
      {"unclosed_section", f + n + "$Comments\nhello\n", ":11: ", {"section $Comments is not closed", "$EndComments"}},
      {"stray_end", f + "$EndNodes\n", ":4: ", {"unexpected '$EndNodes'", "no section $Nodes is open"}},
      {"garbage_between_sections", f + n + "hello\n" + e, ":11: ", {"expected a section header", "'hello'"}},
      {"second_nodes", f + n + n + e, ":11: ", {"second $Nodes section"}},
      {"name_unquoted", f + "$PhysicalNames\n1\n3 1 solid\n$EndPhysicalNames\n", ":6: ", {"quoted physical name", "'solid'"}},
      {"name_unterminated", f + "$PhysicalNames\n1\n3 1 \"solid\n$EndPhysicalNames\n", ":6: ", {"closing quote"}},
      {"name_conflict", f + "$PhysicalNames\n2\n3 1 \"a\"\n3 1 \"b\"\n$EndPhysicalNames\n", ":7: ", {"named twice", "'a' and 'b'"}},
      {"name_bad_dim", f + "$PhysicalNames\n1\n4 1 \"a\"\n$EndPhysicalNames\n", ":6: ", {"dimension 0 to 3", "found 4"}},
      {"v41_node_count", f41 + "$Nodes\n1 5 1 4\n3 1 0 4\n1\n2\n3\n4\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n$EndNodes\n", ":5: ",
       {"declares 5 nodes but its blocks hold 4"}},
      {"v41_block_too_big", f41 + "$Nodes\n1 3 1 4\n3 1 0 4\n1\n2\n3\n4\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n$EndNodes\n", ":6: ", {"more nodes than the 3 declared"}},
      {"v41_parametric_flag", f41 + "$Nodes\n1 4 1 4\n3 1 2 4\n1\n2\n3\n4\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n$EndNodes\n", ":6: ", {"parametric flag 0 or 1", "found 2"}},
      {"v41_missing_parametric", f41 + "$Nodes\n1 1 1 1\n2 1 1 1\n1\n0 0 0\n", ":8: ",
       {"expected parametric node coordinate", "end of line"}},
      {"v41_dim_mismatch", f41 + n41 + "$Elements\n1 1 1 1\n2 1 4 1\n1 1 2 3 4\n$EndElements\n", ":18: ",
       {"has dimension 3 but its block is on an entity of dimension 2"}},
      {"v41_unknown_entity",
       f41 + "$Entities\n0 0 0 1\n5 0 0 0 1 1 1 1 21 0\n$EndEntities\n" + n41 + e41, ":22: ",
       {"entity (dim 3, tag 1), which is not in $Entities"}},
      {"v41_element_count", f41 + n41 + "$Elements\n1 2 1 1\n3 1 4 1\n1 1 2 3 4\n$EndElements\n", ":17: ",
       {"declares 2 elements but its blocks hold 1"}},
      {"v41_entities_truncated", f41 + "$Entities\n0 0 0 1\n1 0 0 0 1 1 1\n", ":7: ",
       {"expected number of physical tags", "end of file"}},
      {"v41_second_order", f41 + n41 + "$Elements\n2 2 1 2\n3 1 4 1\n1 1 2 3 4\n3 1 11 1\n2 1 2 3 4 1 2 3 4 1 2\n$EndElements\n",
       ":21: ", {"element 2 is a type 11 (10-node tetrahedron)", "one element order"}},
  };
}

INSTANTIATE_TEST_SUITE_P(Cases, GmshMalformed, ::testing::ValuesIn(bad_cases()),
                         [](const ::testing::TestParamInfo<BadCase>& p) { return std::string(p.param.name); });

TEST(GmshErrors, MissingFileAndDirectory) {
  const fs::path missing = scratch() / "does_not_exist.msh";
  std::string msg = error_of(missing);
  EXPECT_EQ(msg.rfind(missing.string() + ": cannot open mesh file", 0), 0u) << msg;
  msg = error_of(scratch());
  EXPECT_EQ(msg.rfind(scratch().string() + ": ", 0), 0u) << msg;
  EXPECT_NE(msg.find("directory"), std::string::npos) << msg;
}

TEST(GmshErrors, ValidBaseCaseReads) {
  // The malformed cases are variations of this file.
  const TetMesh mesh = read_gmsh(write_file("base.msh", kFormat22 + kNodes22 + kTet22));
  EXPECT_EQ(mesh.num_tets(), 1);
  ASSERT_EQ(mesh.groups.size(), 1u);
  EXPECT_EQ(mesh.groups[0].name, "");
  EXPECT_EQ(mesh.groups[0].tag, 1);
}

TEST(GmshErrors, BinaryErrorsGiveByteOffsets) {
  Spec spec = hand_spec(50);
  std::string bin = to_msh41(spec, true);
  // Reference an undefined node in the binary element data.
  spec.elements.back().nodes[0] = 77;
  const std::string bad = to_msh41(spec, true);
  const fs::path p = write_file("bad_node_b41.msh", bad);
  const std::string msg = error_of(p);
  EXPECT_NE(msg.find(": byte "), std::string::npos) << msg;
  EXPECT_NE(msg.find("element 7 (type 4 (4-node tetrahedron)) refers to node 77"), std::string::npos) << msg;
  // Data size 4 with 8-byte data: caught as a bad count or bad structure, not a crash.
  bin.replace(bin.find("4.1 1 8"), 7, "4.1 1 4");
  const fs::path q = write_file("wrong_size_b41.msh", bin);
  EXPECT_EQ(error_of(q).rfind(q.string() + ":", 0), 0u);
}

}  // namespace
