#include <softdiff/mesh/tet_mesh.hpp>

#include <softdiff/core/assert.hpp>

#include <Eigen/Geometry>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <string>
#include <unordered_map>

namespace softdiff::mesh {

const PhysicalGroup* TetMesh::find_group(const std::string& name) const {
  for (const PhysicalGroup& g : groups)
    if (g.name == name) return &g;
  return nullptr;
}

const PhysicalGroup* TetMesh::find_group(const std::string& name, int dim) const {
  for (const PhysicalGroup& g : groups)
    if (g.dim == dim && g.name == name) return &g;
  return nullptr;
}

namespace {

// Local face f of a tet is the face opposite vertex f. For a positively
// oriented tet (det[b-a, c-a, d-a] > 0) these orders give (q-p) x (r-p)
// pointing away from vertex f, i.e. out of the tet.
constexpr int kFace[4][3] = {{1, 2, 3}, {0, 3, 2}, {0, 1, 3}, {0, 2, 1}};

}  // namespace

Triangles boundary_triangles(const Tets& tets) {
  const Eigen::Index m = tets.cols();
  if (m == 0) return Triangles(3, 0);
  SOFTDIFF_DEMAND(m <= std::numeric_limits<int>::max() / 4, "too many tetrahedra (" + std::to_string(m) + ")");
  SOFTDIFF_DEMAND(tets.minCoeff() >= 0, "negative node index in tets");
  const int n = tets.maxCoeff() + 1;

  // Bucket the 4m faces by their smallest node (counting sort, O(m + n)); a
  // face's other two nodes (sorted) identify it within the bucket. Buckets are
  // small (about a dozen faces), so sorting each one is cheap and keeps the
  // whole thing near linear without hashing.
  struct Face {
    int mid, max, id;  // id = 4 * tet + local face
  };
  std::vector<int> start(static_cast<std::size_t>(n) + 1, 0);
  auto sorted_face = [&](Eigen::Index t, int f) {
    int a = tets(kFace[f][0], t), b = tets(kFace[f][1], t), c = tets(kFace[f][2], t);
    if (a > b) std::swap(a, b);
    if (b > c) std::swap(b, c);
    if (a > b) std::swap(a, b);
    return std::array<int, 3>{a, b, c};
  };
  for (Eigen::Index t = 0; t < m; ++t)
    for (int f = 0; f < 4; ++f) ++start[static_cast<std::size_t>(sorted_face(t, f)[0]) + 1];
  for (int v = 0; v < n; ++v) start[v + 1] += start[v];
  std::vector<Face> faces(static_cast<std::size_t>(4 * m));
  {
    std::vector<int> fill(start.begin(), start.end() - 1);
    for (Eigen::Index t = 0; t < m; ++t)
      for (int f = 0; f < 4; ++f) {
        const auto k = sorted_face(t, f);
        faces[fill[k[0]]++] = {k[1], k[2], static_cast<int>(4 * t + f)};
      }
  }

  std::vector<char> on_boundary(static_cast<std::size_t>(4 * m), 0);
  Eigen::Index count = 0;
  for (int v = 0; v < n; ++v) {
    const auto first = faces.begin() + start[v], last = faces.begin() + start[v + 1];
    std::sort(first, last, [](const Face& x, const Face& y) { return x.mid != y.mid ? x.mid < y.mid : x.max < y.max; });
    for (auto it = first; it != last;) {
      auto run_end = it + 1;
      while (run_end != last && run_end->mid == it->mid && run_end->max == it->max) ++run_end;
      // A face shared by exactly two tets is interior; more than two means a
      // non-manifold mesh, which is not boundary either.
      if (run_end - it == 1) {
        on_boundary[it->id] = 1;
        ++count;
      }
      it = run_end;
    }
  }

  Triangles out(3, count);
  Eigen::Index k = 0;
  for (Eigen::Index id = 0; id < 4 * m; ++id) {
    if (!on_boundary[id]) continue;
    const Eigen::Index t = id / 4;
    const int f = static_cast<int>(id % 4);
    for (int j = 0; j < 3; ++j) out(j, k) = tets(kFace[f][j], t);
    ++k;
  }
  return out;
}

Quality quality(const Mat3X& X, const Tets& tets) {
  Quality q;
  const Eigen::Index m = tets.cols();
  if (X.cols() > 0) {
    q.bbox_min = X.rowwise().minCoeff();
    q.bbox_max = X.rowwise().maxCoeff();
  }
  if (m == 0) return q;
  SOFTDIFF_DEMAND(tets.minCoeff() >= 0 && tets.maxCoeff() < X.cols(), "tet node index out of range");

  std::vector<double> aspect(static_cast<std::size_t>(m));
  q.min_volume = std::numeric_limits<double>::infinity();
  q.max_volume = -std::numeric_limits<double>::infinity();
  q.total_volume = 0;
  for (Eigen::Index t = 0; t < m; ++t) {
    const Vec3 a = X.col(tets(0, t)), b = X.col(tets(1, t)), c = X.col(tets(2, t)), d = X.col(tets(3, t));
    const Vec3 ab = b - a, ac = c - a, ad = d - a;
    const double volume = ab.dot(ac.cross(ad)) / 6.0;
    q.min_volume = std::min(q.min_volume, volume);
    q.max_volume = std::max(q.max_volume, volume);
    q.total_volume += volume;

    const double longest2 = std::max({ab.squaredNorm(), ac.squaredNorm(), ad.squaredNorm(), (c - b).squaredNorm(),
                                      (d - b).squaredNorm(), (d - c).squaredNorm()});
    const double area = 0.5 * (ab.cross(ac).norm() + ab.cross(ad).norm() + ac.cross(ad).norm() +
                               (c - b).cross(d - b).norm());
    // inradius r = 3 |V| / (total face area); aspect = L / (2 sqrt(6) r).
    const double abs_volume = std::abs(volume);
    aspect[t] = abs_volume > 0 ? std::sqrt(longest2) * area / (6.0 * std::sqrt(6.0) * abs_volume)
                               : std::numeric_limits<double>::infinity();
  }

  const auto worst = std::max_element(aspect.begin(), aspect.end());  // first of equal maxima
  q.worst_tet = static_cast<int>(worst - aspect.begin());
  q.max_aspect = *worst;
  q.min_aspect = *std::min_element(aspect.begin(), aspect.end());
  const std::size_t mid = aspect.size() / 2;
  std::nth_element(aspect.begin(), aspect.begin() + mid, aspect.end());
  q.median_aspect = aspect[mid];
  if (aspect.size() % 2 == 0) {
    const double lower = *std::max_element(aspect.begin(), aspect.begin() + mid);
    q.median_aspect = 0.5 * (lower + q.median_aspect);
  }
  return q;
}

namespace {

std::uint64_t edge_key(int a, int b) {
  if (a > b) std::swap(a, b);
  return (static_cast<std::uint64_t>(static_cast<std::uint32_t>(a)) << 32) | static_cast<std::uint32_t>(b);
}

// Vertex pair -> mid-edge node of an order-2 mesh.
std::unordered_map<std::uint64_t, int> mid_edge_map(const TetMesh& mesh) {
  std::unordered_map<std::uint64_t, int> mid;
  mid.reserve(static_cast<std::size_t>(mesh.num_tets()) * 2);
  for (int t = 0; t < mesh.num_tets(); ++t)
    for (int k = 0; k < 6; ++k)
      mid.emplace(edge_key(mesh.tets10(kTet10Edge[k][0], t), mesh.tets10(kTet10Edge[k][1], t)), mesh.tets10(4 + k, t));
  return mid;
}

}  // namespace

Triangles6 quadratic_triangles(const TetMesh& mesh, const Triangles& tris) {
  SOFTDIFF_DEMAND(mesh.order == 2, "quadratic_triangles: the mesh is not quadratic");
  const auto mid = mid_edge_map(mesh);
  Triangles6 out(6, tris.cols());
  for (Eigen::Index t = 0; t < tris.cols(); ++t) {
    for (int k = 0; k < 3; ++k) {
      out(k, t) = tris(k, t);
      const auto it = mid.find(edge_key(tris(k, t), tris((k + 1) % 3, t)));
      out(3 + k, t) = it == mid.end() ? -1 : it->second;
    }
  }
  return out;
}

Triangles split_quadratic_triangles(const Triangles6& tris) {
  static constexpr int kSub[4][3] = {{0, 3, 5}, {3, 1, 4}, {5, 4, 2}, {3, 4, 5}};
  Triangles out(3, 4 * tris.cols());
  for (Eigen::Index t = 0; t < tris.cols(); ++t)
    for (int s = 0; s < 4; ++s)
      for (int j = 0; j < 3; ++j) out(j, 4 * t + s) = tris(kSub[s][j], t);
  return out;
}

void elevate_to_quadratic(TetMesh& mesh) {
  SOFTDIFF_DEMAND(mesh.order == 1, "elevate_to_quadratic: the mesh is already quadratic");
  const int m = mesh.num_tets(), n = mesh.num_nodes();
  std::unordered_map<std::uint64_t, int> mid;
  mid.reserve(static_cast<std::size_t>(m) * 2);
  mesh.tets10.resize(10, m);
  mesh.tets10.topRows(4) = mesh.tets;
  std::vector<std::array<int, 2>> added;
  for (int t = 0; t < m; ++t)
    for (int k = 0; k < 6; ++k) {
      const int a = mesh.tets(kTet10Edge[k][0], t), b = mesh.tets(kTet10Edge[k][1], t);
      const auto [it, inserted] = mid.emplace(edge_key(a, b), n + static_cast<int>(added.size()));
      if (inserted) added.push_back({a, b});
      mesh.tets10(4 + k, t) = it->second;
    }
  const int n2 = n + static_cast<int>(added.size());
  mesh.X.conservativeResize(3, n2);
  for (std::size_t i = 0; i < added.size(); ++i)
    mesh.X.col(n + static_cast<Eigen::Index>(i)) = 0.5 * (mesh.X.col(added[i][0]) + mesh.X.col(added[i][1]));
  mesh.file_index.resize(static_cast<std::size_t>(n2), -1);
  mesh.file_tag.resize(static_cast<std::size_t>(n2), -1);
  mesh.added_nodes = static_cast<long>(added.size());
  mesh.order = 2;
  for (PhysicalGroup& g : mesh.groups) {
    if (g.tets.empty() && g.triangles.empty()) continue;
    std::vector<int> nodes = g.nodes;
    for (int t : g.tets)
      for (int k = 0; k < 6; ++k) nodes.push_back(mesh.tets10(4 + k, t));
    for (int tri : g.triangles)
      for (int k = 0; k < 3; ++k) {
        const auto it = mid.find(edge_key(mesh.triangles(k, tri), mesh.triangles((k + 1) % 3, tri)));
        if (it != mid.end()) nodes.push_back(it->second);
      }
    std::sort(nodes.begin(), nodes.end());
    nodes.erase(std::unique(nodes.begin(), nodes.end()), nodes.end());
    g.nodes = std::move(nodes);
  }
}

}  // namespace softdiff::mesh
