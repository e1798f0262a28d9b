// Collision detection: surface vertices against obstacles, and vertex-triangle /
// edge-edge pairs between soft bodies and within one body (self-contact).
//
// Broad phase
//   - vertex-obstacle: the obstacle's bounding box inflated by the margin against
//     the body's current bounding box (one test per pair rule), then the obstacle's
//     own fast reject per vertex (closest_point with max_distance = margin).
//   - soft-soft and self: one FCL DynamicAABBTreeCollisionManager per body surface
//     that takes part in such a rule, one leaf per surface triangle. Every call sets
//     each leaf's box to the triangle's current box inflated by margin / 2 and refits
//     the tree (manager->update(): refit, and FCL's incremental / top-down rebalance
//     when the tree degrades, which may allocate inside FCL). FCL's collide calls back
//     with each overlapping triangle pair; the callback emits the vertex-triangle and
//     edge-edge candidates whose own boxes (vertex point, triangle box, edge boxes) are
//     within the margin, minus the self-contact exclusions (two triangles that share an
//     edge give none; two that share one vertex give at most their two opposite edges),
//     each from the pair of its features' lowest-index triangles only (add_candidates),
//     so once. Candidates are then sorted (by buckets) and de-duplicated, so that the
//     order does not depend on FCL's traversal. Two features closer than the margin
//     always have overlapping inflated triangle boxes, so no pair closer than the margin
//     is missed (Detection.BroadPhaseMissesNoPairWithinTheMargin checks it).
//     Cost: adjacent triangles always overlap, so a self-contact surface costs ~10-20
//     FCL pairs per triangle even without contacts (about 10 ms for 10k triangles).
// Narrow phase: exact closest points (distance.hpp). A soft-soft candidate becomes a
//   contact when its unsigned distance is < margin (deeper penetrations are not seen:
//   the margin and the time step must keep them shallow).
//
// Sign of the gap (soft-soft)
//   - vertex-triangle: sign of (p - q) . N, N the pseudo-normal of the triangle's
//     feature that holds q: the face normal, the edge's (sum of its two faces'
//     normals) or the vertex's angle-weighted normal (Baerentzen & Aanaes), i.e. the
//     inside / outside test of the closed surface B near q. n = sign (p - q)/|p - q|.
//   - edge-edge: d = p_a - p_b, sign of d . (N_b - N_a), N_a and N_b the edges'
//     pseudo-normals: separated and facing surfaces have d along N_b and against N_a;
//     crossed (penetrating) edges flip both. n = sign d/|d|. When |d| vanishes, n is the
//     unit cross product of the edge directions oriented along N_b - N_a.
//   In both cases gap = n . (point - point_b), and n points from B towards A.
//
// De-duplication (soft-soft, IPC-style: each primitive pair is reported once)
//   - edge-edge: only interior-interior closest points (1e-9 < s, t < 1 - 1e-9, so that
//     an endpoint case perturbed by round-off stays an endpoint case; parallel edges
//     give an endpoint). Endpoint cases are point-edge or point-point pairs, which the
//     vertex-triangle tests report.
//   - vertex-triangle with q in the face: kept.
//   - q on an edge e of the triangle: kept only for the lowest-index triangle of e
//     (among those that the self-contact rule does not skip for this vertex).
//   - q on a vertex w: kept only for the lowest-index triangle incident to w (same).
//   So a vertex near an edge or a vertex of the other surface gives one point-edge or
//   one point-point contact, whose weights are the triangle's barycentrics (one or two
//   of them zero). A point-point pair (v, w) found from both vertices (v against a
//   triangle of w, w against a triangle of v) is kept once: the first in the order.
//
// Self-contact (rule a == a): vertex v against triangle t is skipped when t contains v
//   or a one-ring neighbour of v; edges e1, e2 are skipped when they share a vertex or
//   an endpoint of one is a one-ring neighbour of an endpoint of the other. A flat or
//   smooth undeformed surface then has no self-contact as long as the margin is
//   smaller than the distance between features two rings apart (about an edge length),
//   and the body is thicker than the margin (a vertex facing the inside of its own
//   body's opposite wall would read as penetrating).
//
// Memory: the candidate and contact buffers are reused (clear() keeps capacity), so
//   nothing is allocated per call once they have grown, except inside FCL's update()
//   when it rebalances its tree.
//
// Order: pair rules in model order; within a rule, vertex-obstacle contacts by vertex;
//   vertex-triangle contacts with A's vertices first (by vertex, then triangle), then
//   B's vertices against A's triangles; then edge-edge by (edge of A, edge of B).
//   Serial code: the output does not depend on the thread count.
#include <softdiff/collision/detection.hpp>
#include <softdiff/collision/distance.hpp>
#include <softdiff/collision/fcl.hpp>  // FCL, with the layout check against libfcl
#include <softdiff/core/assert.hpp>
#include <softdiff/core/error.hpp>

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <tuple>

namespace softdiff::collision {

BodySurface make_surface(const std::string& name, const Triangles& local_triangles, int node_begin) {
  BodySurface s;
  s.name = name;
  s.triangles = local_triangles.array() + node_begin;
  prepare_surface(s);
  return s;
}

void prepare_surface(BodySurface& s) {
  const int nt = static_cast<int>(s.triangles.cols());
  s.vertices.assign(s.triangles.data(), s.triangles.data() + 3 * nt);
  std::sort(s.vertices.begin(), s.vertices.end());
  s.vertices.erase(std::unique(s.vertices.begin(), s.vertices.end()), s.vertices.end());
  std::vector<std::pair<int, int>> e;
  e.reserve(3 * static_cast<std::size_t>(nt));
  for (int t = 0; t < nt; ++t)
    for (int k = 0; k < 3; ++k) {
      const int a = s.triangles(k, t), b = s.triangles((k + 1) % 3, t);
      e.emplace_back(std::min(a, b), std::max(a, b));
    }
  std::sort(e.begin(), e.end());
  e.erase(std::unique(e.begin(), e.end()), e.end());
  s.edges.resize(2, static_cast<int>(e.size()));
  for (std::size_t i = 0; i < e.size(); ++i) {
    s.edges(0, static_cast<int>(i)) = e[i].first;
    s.edges(1, static_cast<int>(i)) = e[i].second;
  }
}

void mark_planar_edges(BodySurface& s, const Mat3X& local_vertices, int node_begin) {
  const int ne = static_cast<int>(s.edges.cols()), nt = static_cast<int>(s.triangles.cols());
  // The (first two) triangles of each edge: edges are sorted (lo, hi) pairs.
  std::vector<std::array<int, 2>> tris(static_cast<std::size_t>(ne), {-1, -1});
  auto edge_index = [&](int a, int b) {
    const int lo = std::min(a, b), hi = std::max(a, b);
    int first = 0, count = ne;  // lower bound on (lo, hi)
    while (count > 0) {
      const int step = count / 2, mid = first + step;
      if (s.edges(0, mid) < lo || (s.edges(0, mid) == lo && s.edges(1, mid) < hi)) {
        first = mid + 1;
        count -= step + 1;
      } else {
        count = step;
      }
    }
    return first < ne && s.edges(0, first) == lo && s.edges(1, first) == hi ? first : -1;
  };
  for (int t = 0; t < nt; ++t)
    for (int k = 0; k < 3; ++k) {
      const int e = edge_index(s.triangles(k, t), s.triangles((k + 1) % 3, t));
      SOFTDIFF_DEMAND(e >= 0, "mark_planar_edges: surface '" + s.name + "' is not prepared (prepare_surface)");
      auto& et = tris[static_cast<std::size_t>(e)];
      (et[0] < 0 ? et[0] : et[1]) = t;
    }
  auto normal = [&](int t) {
    const auto P = [&](int k) { return Vec3(local_vertices.col(s.triangles(k, t) - node_begin)); };
    return Vec3((P(1) - P(0)).cross(P(2) - P(0)).normalized());
  };
  s.planar_edge.assign(static_cast<std::size_t>(ne), 0);
  for (int e = 0; e < ne; ++e) {
    const auto& et = tris[static_cast<std::size_t>(e)];
    if (et[0] < 0 || et[1] < 0) continue;
    const Vec3 n0 = normal(et[0]), n1 = normal(et[1]);
    s.planar_edge[static_cast<std::size_t>(e)] = n0.dot(n1) > 0 && n0.cross(n1).squaredNorm() < 1e-20;
  }
}

namespace {

// Contact normals at tiny gaps (soft_soft, docs/method.md): a vertex closer than
// kFlatDistance times the triangle's longest edge to an edge or vertex of a flat region
// (the feature's pseudo-normal within kFlatAngle, 1 - cos, of the face normal: 1e-6 is
// 1.4e-3 rad, coplanar triangles to round-off pass, a 10-degree crease does not) takes
// the face normal. 1e-6 of the element size is 1e-8 m for 1 cm elements: far above the
// gaps of resting contacts (round-off, 1e-16-1e-12 m) and far below a gap whose
// d / |d| matters (at 1e-8 m its round-off tilt is ~1e-9 rad).
constexpr double kFlatDistance = 1e-6;
constexpr double kFlatAngle = 1e-6;

double triangle_scale(const Vec3& a, const Vec3& b, const Vec3& c) {
  return std::sqrt(std::max({(b - a).squaredNorm(), (c - b).squaredNorm(), (a - c).squaredNorm()}));
}

// A broad-phase leaf: FCL's CollisionObject with its world box set directly (the
// geometry is a shared dummy; FCL's manager reads only getAABB()).
class TriangleLeaf : public fcl::CollisionObjectd {
 public:
  explicit TriangleLeaf(const std::shared_ptr<fcl::CollisionGeometryd>& g) : fcl::CollisionObjectd(g) {}
  void set_box(const Vec3& lo, const Vec3& hi) {
    aabb.min_ = lo;
    aabb.max_ = hi;
  }
};

struct LeafId {
  int surface, triangle;
};

// Per surface: adjacency (built once), normals and broad phase (per call).
struct SurfaceData {
  const BodySurface* surface = nullptr;
  int num_tri = 0;
  std::vector<std::array<int, 3>> tri_edges;  // edge index of (t0 t1), (t1 t2), (t2 t0)
  std::vector<std::array<int, 2>> edge_tris;  // the (first two) triangles of each edge, ascending; -1 if none
  std::vector<int> local;                     // global node -> local vertex index, or -1
  std::vector<int> ring_begin, ring;          // CSR over local vertices: sorted global neighbours
  std::vector<int> vt_begin, vt;              // CSR over local vertices: incident triangles, ascending
  std::vector<Vec3> face_normal;              // (num_tri) unit, per call
  std::vector<Vec3> tri_lo, tri_hi;           // (num_tri) triangle boxes, per call
  std::vector<Vec3> edge_lo, edge_hi;         // (num_edges) edge boxes, per call
  bool broad = false;                         // takes part in a soft-soft or self rule
  std::vector<LeafId> ids;
  std::vector<std::unique_ptr<TriangleLeaf>> leaves;
  std::unique_ptr<fcl::DynamicAABBTreeCollisionManagerd> manager;
  bool registered = false;

  // The lowest-index triangle of vertex v (a global node of this surface) and of edge e:
  // the broad phase emits a candidate only from the overlapping pair of its features'
  // lowest-index triangles (add_candidates).
  int first_triangle_of_vertex(int v) const { return vt[static_cast<std::size_t>(vt_begin[local[v]])]; }
  int first_triangle_of_edge(int e) const { return edge_tris[static_cast<std::size_t>(e)][0]; }
  bool is_neighbor(int v, int w) const {
    const int lv = local[v];
    return std::binary_search(ring.begin() + ring_begin[lv], ring.begin() + ring_begin[lv + 1], w);
  }
  // Self-contact: skip v against t if t contains v or a neighbour of v.
  bool skip_vt(int v, int t) const {
    const auto& T = surface->triangles;
    for (int k = 0; k < 3; ++k)
      if (T(k, t) == v || is_neighbor(v, T(k, t))) return true;
    return false;
  }
  bool skip_ee(int e1, int e2) const {
    const auto& E = surface->edges;
    for (int i = 0; i < 2; ++i)
      for (int j = 0; j < 2; ++j)
        if (E(i, e1) == E(j, e2) || is_neighbor(E(i, e1), E(j, e2))) return true;
    return false;
  }
};

struct VtCandidate {
  int dir, v, t;  // dir 0: vertex of side a against a triangle of side b; 1: the reverse
  bool operator<(const VtCandidate& o) const { return std::tie(dir, v, t) < std::tie(o.dir, o.v, o.t); }
  bool operator==(const VtCandidate& o) const { return dir == o.dir && v == o.v && t == o.t; }
};
struct EeCandidate {
  int ea, eb;
  bool operator<(const EeCandidate& o) const { return std::tie(ea, eb) < std::tie(o.ea, o.eb); }
  bool operator==(const EeCandidate& o) const { return ea == o.ea && eb == o.eb; }
};

// Sorts v ascending and removes duplicates, as std::sort then std::unique, by a counting
// sort on key(c) in [0, nkeys) and a sort of each key's bucket (the rest of the order):
// O(n + nkeys + sum_b b log b) instead of O(n log n). On a gripper's self-contact surfaces
// the candidate lists sorted by std::sort took 30% of a configs/gripper_lift.yaml run (perf,
// 2026-12-04, when the broad phase still emitted a candidate once per overlapping triangle
// pair; add_candidates now emits each once, so the sort gives the order and the
// de-duplication is a safeguard). count and tmp are the caller's reused buffers (no
// allocation once they have grown).
template <typename T, typename Key>
void bucket_sort_unique(std::vector<T>& v, int nkeys, Key key, std::vector<int>& count, std::vector<T>& tmp) {
  if (v.size() < 2) return;
  count.assign(static_cast<std::size_t>(nkeys) + 1, 0);
  for (const T& c : v) ++count[static_cast<std::size_t>(key(c)) + 1];
  for (int k = 0; k < nkeys; ++k) count[static_cast<std::size_t>(k) + 1] += count[static_cast<std::size_t>(k)];
  tmp.resize(v.size());
  for (const T& c : v) tmp[static_cast<std::size_t>(count[static_cast<std::size_t>(key(c))]++)] = c;
  // count[k] is now the end of bucket k (the start of bucket k + 1).
  std::size_t kept = 0, begin = 0;
  for (int k = 0; k < nkeys; ++k) {
    const std::size_t end = static_cast<std::size_t>(count[static_cast<std::size_t>(k)]);
    if (end > begin) {
      std::sort(tmp.begin() + static_cast<std::ptrdiff_t>(begin), tmp.begin() + static_cast<std::ptrdiff_t>(end));
      for (std::size_t i = begin; i < end; ++i)
        if (i == begin || !(tmp[i] == tmp[i - 1])) v[kept++] = tmp[i];
    }
    begin = end;
  }
  v.resize(kept);
}

Vec3 unit_or(const Vec3& v, const Vec3& fallback) {
  const double n = v.norm();
  return n > 0 ? Vec3(v / n) : fallback;
}

}  // namespace

struct CollisionDetector::Impl {
  DetectionModel model;
  double margin = 0;  // of the current pair rule in run() (model.margin unless widened)
  int num_bodies = 0;
  int max_node = -1;  // largest node index on any surface (x must have 3 (max_node + 1) entries)
  std::vector<SurfaceData> surf;
  std::vector<double> surface_margin;  // (surfaces) per call; margin is the current pair's
  std::shared_ptr<fcl::CollisionGeometryd> dummy;
  // Reused buffers.
  std::vector<VtCandidate> vt;
  std::vector<EeCandidate> ee;
  std::vector<std::array<int, 3>> pp;  // point-point contacts: (min node, max node, contact index)
  std::vector<char> drop;
  std::vector<int> bucket_count;       // bucket_sort_unique's buffers
  std::vector<VtCandidate> vt_tmp;
  std::vector<EeCandidate> ee_tmp;

  explicit Impl(const DetectionModel& m);
  void update_surface(SurfaceData& s, const VecX& x, double inflate);
  DetectionStats run(const VecX& x, ContactSet& out);  // with surface_margin set
  Vec3 vertex_normal(const SurfaceData& s, const VecX& x, int w) const;
  Vec3 edge_normal(const SurfaceData& s, int e) const;
  bool is_flat(const SurfaceData& s, int e) const;  // the edge's two faces are (nearly) coplanar
  // Whether another triangle of the edge or vertex of t that holds r (p's closest point on
  // t) has its own closest point to p off that feature (soft_soft's vertex-triangle loop).
  bool off_feature(const SurfaceData& s, const VecX& x, const Vec3& p, int v, int t, const PointTriangleResult& r,
                   bool self) const;
  void vertex_obstacle(const PairRule& rule, const VecX& x, ContactSet& out, DetectionStats& stats);
  void soft_soft(const PairRule& rule, const VecX& x, ContactSet& out, DetectionStats& stats);
  void add_candidates(bool self, const SurfaceData& A, const SurfaceData& B, int ta, int tb, const VecX& x);

  // FCL's collide callback: the candidates of each overlapping triangle pair.
  struct PairCollect {
    Impl* impl;
    const SurfaceData *A, *B;
    int sa;  // A's body index
    bool self;
    const VecX* x;
  };
  static bool collect_pairs(fcl::CollisionObjectd* o1, fcl::CollisionObjectd* o2, void* data) {
    auto* c = static_cast<PairCollect*>(data);
    const auto* i1 = static_cast<const LeafId*>(o1->getUserData());
    const auto* i2 = static_cast<const LeafId*>(o2->getUserData());
    if (c->self || i1->surface == c->sa)
      c->impl->add_candidates(c->self, *c->A, *c->B, i1->triangle, i2->triangle, *c->x);
    else
      c->impl->add_candidates(c->self, *c->A, *c->B, i2->triangle, i1->triangle, *c->x);
    return false;  // never stop
  }
};


CollisionDetector::Impl::Impl(const DetectionModel& m) : model(m) {
  num_bodies = static_cast<int>(model.surfaces.size());
  const int num_obstacles = static_cast<int>(model.obstacles.size());
  for (auto& s : model.surfaces)
    if (s.vertices.empty() && s.triangles.cols() > 0) prepare_surface(s);
  for (const auto& r : model.pairs) {
    if (r.a < 0 || r.a >= num_bodies || r.b < 0 || r.b >= num_bodies + num_obstacles)
      throw InputError("contact pair rule (" + std::to_string(r.a) + ", " + std::to_string(r.b) +
                       "): side out of range (" + std::to_string(num_bodies) + " bodies, " +
                       std::to_string(num_obstacles) + " obstacles)");
  }
  for (const auto& o : model.obstacles)
    if (o.kind == ShapeKind::mesh && !o.accel)
      throw InputError("obstacle '" + o.name + "': not prepared (call collision::prepare)");
  dummy = std::make_shared<fcl::Sphered>(0.0);
  surf.resize(num_bodies);
  for (int b = 0; b < num_bodies; ++b) {
    SurfaceData& s = surf[b];
    const BodySurface& bs = model.surfaces[b];
    s.surface = &bs;
    const auto& T = bs.triangles;
    const auto& E = bs.edges;
    s.num_tri = static_cast<int>(T.cols());
    const int ne = static_cast<int>(E.cols());
    const int last = bs.vertices.empty() ? -1 : bs.vertices.back();
    max_node = std::max(max_node, last);
    s.local.assign(last + 1, -1);
    const int nv = static_cast<int>(bs.vertices.size());
    for (int i = 0; i < nv; ++i) s.local[bs.vertices[i]] = i;
    // Triangle -> edges, edge -> triangles (edges are sorted by (lo, hi)).
    s.tri_edges.resize(s.num_tri);
    s.edge_tris.assign(ne, {-1, -1});
    for (int t = 0; t < s.num_tri; ++t)
      for (int k = 0; k < 3; ++k) {
        const int a = T(k, t), c = T((k + 1) % 3, t);
        const std::pair<int, int> key(std::min(a, c), std::max(a, c));
        int lo = 0, hi = ne;
        while (lo < hi) {
          const int mid = (lo + hi) / 2;
          if (std::make_pair(E(0, mid), E(1, mid)) < key)
            lo = mid + 1;
          else
            hi = mid;
        }
        s.tri_edges[t][k] = lo;
        auto& et = s.edge_tris[lo];
        if (et[0] < 0)
          et[0] = t;
        else if (et[1] < 0)
          et[1] = t;
      }
    // Vertex -> neighbours, vertex -> triangles.
    std::vector<std::vector<int>> ring(nv), vts(nv);
    for (int e = 0; e < ne; ++e) {
      ring[s.local[E(0, e)]].push_back(E(1, e));
      ring[s.local[E(1, e)]].push_back(E(0, e));
    }
    for (int t = 0; t < s.num_tri; ++t)
      for (int k = 0; k < 3; ++k) vts[s.local[T(k, t)]].push_back(t);
    s.ring_begin.assign(1, 0);
    s.vt_begin.assign(1, 0);
    for (int i = 0; i < nv; ++i) {
      std::sort(ring[i].begin(), ring[i].end());
      s.ring.insert(s.ring.end(), ring[i].begin(), ring[i].end());
      s.ring_begin.push_back(static_cast<int>(s.ring.size()));
      s.vt.insert(s.vt.end(), vts[i].begin(), vts[i].end());  // ascending by construction
      s.vt_begin.push_back(static_cast<int>(s.vt.size()));
    }
    s.face_normal.assign(s.num_tri, Vec3::Zero());
    s.tri_lo.assign(s.num_tri, Vec3::Zero());
    s.tri_hi.assign(s.num_tri, Vec3::Zero());
    s.edge_lo.assign(ne, Vec3::Zero());
    s.edge_hi.assign(ne, Vec3::Zero());
  }
  for (const auto& r : model.pairs)
    if (r.b < num_bodies) surf[r.a].broad = surf[r.b].broad = true;
  for (int b = 0; b < num_bodies; ++b) {
    SurfaceData& s = surf[b];
    if (!s.broad) continue;
    s.ids.resize(s.num_tri);
    s.leaves.reserve(s.num_tri);
    for (int t = 0; t < s.num_tri; ++t) {
      s.ids[t] = {b, t};
      s.leaves.push_back(std::make_unique<TriangleLeaf>(dummy));
      s.leaves.back()->setUserData(&s.ids[t]);
    }
    s.manager = std::make_unique<fcl::DynamicAABBTreeCollisionManagerd>();
  }
}

void CollisionDetector::Impl::update_surface(SurfaceData& s, const VecX& x, double inflate) {
  const auto& T = s.surface->triangles;
  for (int t = 0; t < s.num_tri; ++t) {
    const Vec3 a = x.segment<3>(3 * T(0, t)), b = x.segment<3>(3 * T(1, t)), c = x.segment<3>(3 * T(2, t));
    s.face_normal[t] = unit_or((b - a).cross(c - a), Vec3::Zero());
    s.tri_lo[t] = a.cwiseMin(b).cwiseMin(c);
    s.tri_hi[t] = a.cwiseMax(b).cwiseMax(c);
    s.leaves[t]->set_box(s.tri_lo[t].array() - inflate, s.tri_hi[t].array() + inflate);
  }
  const auto& E = s.surface->edges;
  for (int e = 0; e < E.cols(); ++e) {
    const Vec3 a = x.segment<3>(3 * E(0, e)), b = x.segment<3>(3 * E(1, e));
    s.edge_lo[e] = a.cwiseMin(b);
    s.edge_hi[e] = a.cwiseMax(b);
  }
  if (!s.registered) {
    std::vector<fcl::CollisionObjectd*> objs;
    objs.reserve(s.leaves.size());
    for (auto& l : s.leaves) objs.push_back(l.get());
    s.manager->registerObjects(objs);
    s.manager->setup();
    s.registered = true;
  } else {
    s.manager->update();  // refit (reads every leaf's box)
  }
}

Vec3 CollisionDetector::Impl::vertex_normal(const SurfaceData& s, const VecX& x, int w) const {
  const auto& T = s.surface->triangles;
  const int lw = s.local[w];
  Vec3 n = Vec3::Zero();
  for (int i = s.vt_begin[lw]; i < s.vt_begin[lw + 1]; ++i) {
    const int t = s.vt[i];
    int k = 0;
    while (T(k, t) != w) ++k;
    const Vec3 p = x.segment<3>(3 * w);
    const Vec3 e1 = x.segment<3>(3 * T((k + 1) % 3, t)) - p, e2 = x.segment<3>(3 * T((k + 2) % 3, t)) - p;
    n += std::atan2(e1.cross(e2).norm(), e1.dot(e2)) * s.face_normal[t];
  }
  return unit_or(n, Vec3::Zero());
}

bool CollisionDetector::Impl::off_feature(const SurfaceData& s, const VecX& x, const Vec3& p, int v, int t,
                                          const PointTriangleResult& r, bool self) const {
  const auto& T = s.surface->triangles;
  const auto P = [&](int node) { return Vec3(x.segment<3>(3 * node)); };
  // Is the closest point r2 of triangle u on the feature (edge e = (a, b), or vertex a)?
  const auto on_feature = [&](int u, const PointTriangleResult& r2, int e, int a, int b) {
    if (r2.feature == Feature::face) return false;
    if (r2.feature == Feature::edge) return e >= 0 && s.tri_edges[u][r2.local] == e;
    const int w = T(r2.local, u);
    return w == a || w == b;
  };
  const auto other_off = [&](int u, int e, int a, int b) {
    if (u < 0 || u == t || (self && s.skip_vt(v, u))) return false;
    const PointTriangleResult r2 = point_triangle_closest(p, P(T(0, u)), P(T(1, u)), P(T(2, u)));
    return !on_feature(u, r2, e, a, b);
  };
  if (r.feature == Feature::edge) {
    const int e = s.tri_edges[t][r.local];
    const int a = s.surface->edges(0, e), b = s.surface->edges(1, e);
    for (int k = 0; k < 2; ++k)
      if (other_off(s.edge_tris[e][k], e, a, b)) return true;
    return false;
  }
  const int w = T(r.local, t);
  const int lw = s.local[w];
  for (int i = s.vt_begin[lw]; i < s.vt_begin[lw + 1]; ++i)
    if (other_off(s.vt[i], -1, w, w)) return true;
  return false;
}

bool CollisionDetector::Impl::is_flat(const SurfaceData& s, int e) const {
  const auto& et = s.edge_tris[e];
  return et[0] >= 0 && et[1] >= 0 && s.face_normal[et[0]].dot(s.face_normal[et[1]]) > 0.99;
}

Vec3 CollisionDetector::Impl::edge_normal(const SurfaceData& s, int e) const {
  const auto& et = s.edge_tris[e];
  Vec3 n = Vec3::Zero();
  if (et[0] >= 0) n += s.face_normal[et[0]];
  if (et[1] >= 0) n += s.face_normal[et[1]];
  return unit_or(n, et[0] >= 0 ? s.face_normal[et[0]] : Vec3::Zero());
}

void CollisionDetector::Impl::vertex_obstacle(const PairRule& rule, const VecX& x, ContactSet& out,
                                              DetectionStats& stats) {
  const Obstacle& o = model.obstacles[rule.b - num_bodies];
  const BodySurface& s = model.surfaces[rule.a];
  if (s.vertices.empty()) return;
  if (o.kind != ShapeKind::plane) {  // body box vs inflated obstacle box
    Eigen::AlignedBox3d body;
    body.setEmpty();
    for (int v : s.vertices) body.extend(Vec3(x.segment<3>(3 * v)));
    Eigen::AlignedBox3d ob = bounding_box(o);
    ob.min().array() -= margin;
    ob.max().array() += margin;
    if (!ob.intersects(body)) return;
  }
  ClosestPoint cp;
  for (int v : s.vertices) {
    const Vec3 p = x.segment<3>(3 * v);
    ++stats.candidates;
    if (!closest_point(o, p, margin, cp) || !(cp.distance < margin)) continue;
    Contact& c = out.contacts.emplace_back();
    c.kind = ContactKind::vertex_obstacle;
    c.side_a = rule.a;
    c.side_b = rule.b;
    c.count = 1;
    c.nodes = {v, -1, -1, -1};
    c.weights = {1, 0, 0, 0};
    c.frame = frame_from_normal(cp.normal);
    c.point = p;
    c.point_b = cp.point;
    c.gap = cp.distance;
    c.mu = rule.mu;
    c.feature_a = v;
    c.feature_b = cp.feature;
    c.kind_b = cp.feature_kind;
  }
}

// The candidates of one overlapping triangle pair (ta of A, tb of B): the features
// whose own boxes are within the margin (a necessary condition for a distance <
// margin), minus the self-contact exclusions. Called from FCL's collide callback.
// Each candidate once: from the overlapping pair of its features' lowest-index triangles
// (a vertex's, an edge's). That pair is always reported when the candidate's boxes are
// within the margin: each of those triangles' boxes contains the feature, and the
// inflations of the two surfaces' boxes add up to at least the pair's margin (run()). In
// self-contact, where that pair shares a vertex or an edge, the candidate is one the
// exclusions skip anyway (every vertex of one triangle is then the other's vertex or its
// neighbour; of two such triangles' edges only the two opposite the shared vertex can
// remain, and those are tried), so no candidate is lost. Before (2026-12-04) every
// overlapping pair emitted all its feature pairs, up to 4 copies of an edge pair and
// one copy of a vertex's per incident triangle, which soft_soft then de-duplicated.
void CollisionDetector::Impl::add_candidates(bool self, const SurfaceData& A, const SurfaceData& B, int ta, int tb,
                                             const VecX& x) {
  const auto& TA = A.surface->triangles;
  const auto& TB = B.surface->triangles;
  auto near_point = [m = margin](const Vec3& p, const Vec3& lo, const Vec3& hi) {
    return (p.array() >= lo.array() - m).all() && (p.array() <= hi.array() + m).all();
  };
  auto near_box = [m = margin](const Vec3& lo1, const Vec3& hi1, const Vec3& lo2, const Vec3& hi2) {
    return (lo1.array() <= hi2.array() + m).all() && (lo2.array() <= hi1.array() + m).all();
  };
  auto X = [&](int node) { return Vec3(x.segment<3>(3 * node)); };
  if (self) {
    if (ta == tb) return;
    int shared = 0, ka = -1, kb = -1;  // shared vertices; local index of the last one in ta, tb
    for (int k = 0; k < 3; ++k)
      for (int l = 0; l < 3; ++l)
        if (TA(k, ta) == TA(l, tb)) {
          ++shared;
          ka = k;
          kb = l;
        }
    if (shared >= 2) return;  // every feature pair of two adjacent triangles is skipped
    // e1 of ta, e2 of tb (FCL reports the pair once, in either order: both orders of the
    // two triangles' edges are tried below).
    auto try_ee = [&](int e1, int e2) {
      if (A.first_triangle_of_edge(e1) == ta && A.first_triangle_of_edge(e2) == tb &&
          near_box(A.edge_lo[e1], A.edge_hi[e1], A.edge_lo[e2], A.edge_hi[e2]) && !A.skip_ee(e1, e2))
        ee.push_back({std::min(e1, e2), std::max(e1, e2)});
    };
    if (shared == 1) {
      // Vertex-triangle pairs are all skipped (each vertex is the shared vertex or its
      // neighbour); of the edge pairs only the two edges opposite the shared vertex
      // can remain (local edge k + 1 is opposite vertex k).
      try_ee(A.tri_edges[ta][(ka + 1) % 3], A.tri_edges[tb][(kb + 1) % 3]);
      return;
    }
    for (int k = 0; k < 3; ++k) {
      const int va = TA(k, ta), vb = TA(k, tb);
      if (A.first_triangle_of_vertex(va) == ta && near_point(X(va), A.tri_lo[tb], A.tri_hi[tb]) && !A.skip_vt(va, tb))
        vt.push_back({0, va, tb});
      if (A.first_triangle_of_vertex(vb) == tb && near_point(X(vb), A.tri_lo[ta], A.tri_hi[ta]) && !A.skip_vt(vb, ta))
        vt.push_back({0, vb, ta});
    }
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) try_ee(A.tri_edges[ta][i], A.tri_edges[tb][j]);
  } else {
    for (int k = 0; k < 3; ++k) {
      const int va = TA(k, ta), vb = TB(k, tb);
      if (A.first_triangle_of_vertex(va) == ta && near_point(X(va), B.tri_lo[tb], B.tri_hi[tb]))
        vt.push_back({0, va, tb});
      if (B.first_triangle_of_vertex(vb) == tb && near_point(X(vb), A.tri_lo[ta], A.tri_hi[ta]))
        vt.push_back({1, vb, ta});
    }
    for (int i = 0; i < 3; ++i) {
      const int e1 = A.tri_edges[ta][i];
      if (A.first_triangle_of_edge(e1) != ta) continue;
      for (int j = 0; j < 3; ++j) {
        const int e2 = B.tri_edges[tb][j];
        if (B.first_triangle_of_edge(e2) == tb && near_box(A.edge_lo[e1], A.edge_hi[e1], B.edge_lo[e2], B.edge_hi[e2]))
          ee.push_back({e1, e2});
      }
    }
  }
}

void CollisionDetector::Impl::soft_soft(const PairRule& rule, const VecX& x, ContactSet& out, DetectionStats& stats) {
  const bool self = rule.a == rule.b;
  SurfaceData& A = surf[rule.a];
  SurfaceData& B = surf[rule.b];
  if (A.num_tri == 0 || B.num_tri == 0) return;
  vt.clear();
  ee.clear();
  PairCollect pc{this, &A, &B, rule.a, self, &x};
  if (self)
    A.manager->collide(&pc, collect_pairs);
  else
    A.manager->collide(B.manager.get(), &pc, collect_pairs);
  // Sorted and de-duplicated (the order does not depend on FCL's traversal): vertex-triangle
  // candidates by (dir, v) buckets, edge-edge ones by A's edge.
  const int nodes = max_node + 1;
  bucket_sort_unique(vt, 2 * nodes, [nodes](const VtCandidate& c) { return c.dir * nodes + c.v; }, bucket_count,
                     vt_tmp);
  bucket_sort_unique(ee, static_cast<int>(A.surface->edges.cols()), [](const EeCandidate& c) { return c.ea; },
                     bucket_count, ee_tmp);
  stats.candidates += static_cast<int>(vt.size() + ee.size());

  const double m2 = margin * margin;
  const double tiny = 1e-9 * margin;
  auto P = [&](int node) { return Vec3(x.segment<3>(3 * node)); };

  // Vertex-triangle.
  const int first_contact = out.size();
  for (const VtCandidate& cand : vt) {
    const SurfaceData& S = cand.dir == 0 ? B : A;  // the triangle's side
    const auto& T = S.surface->triangles;
    const int t = cand.t, v = cand.v;
    const Vec3 p = P(v);
    const PointTriangleResult r = point_triangle_closest(p, P(T(0, t)), P(T(1, t)), P(T(2, t)));
    if (!(r.dist2 < m2)) continue;
    Vec3 pseudo;
    if (r.feature == Feature::edge) {
      const int e = S.tri_edges[t][r.local];
      int rep = -1;
      for (int k = 0; k < 2 && rep < 0; ++k) {
        const int te = S.edge_tris[e][k];
        if (te >= 0 && !(self && S.skip_vt(v, te))) rep = te;
      }
      if (rep != t) continue;
      pseudo = edge_normal(S, e);
    } else if (r.feature == Feature::vertex) {
      const int w = T(r.local, t);
      const int lw = S.local[w];
      int rep = -1;
      for (int i = S.vt_begin[lw]; i < S.vt_begin[lw + 1] && rep < 0; ++i)
        if (!(self && S.skip_vt(v, S.vt[i]))) rep = S.vt[i];
      if (rep != t) continue;
      pseudo = vertex_normal(S, x, w);
    } else {
      pseudo = S.face_normal[t];
    }
    const Vec3 d = p - r.point;
    const double dist = std::sqrt(r.dist2);
    // Records beside a feature (docs/method.md *Records beside an edge or a vertex*): q on
    // an edge or a vertex of t is the vertex's closest point on the surface only if no
    // other triangle of that feature (one not skipped for v) has its closest point to p off
    // the feature, inside its face or on another of its edges or vertices. Such a triangle
    // holds p strictly closer (q lies in it too, and a triangle's closest point is unique)
    // and gives p its own record; t's would read the lateral offset p - q as a normal and a
    // gap of +-|p - q| (a node beside a flat diagonal pushed sideways, a cylinder vertex
    // 43 um below a fingertip's edge held up). Dropped beyond kFlatDistance times t's size
    // (within it the feature's record takes the face normal above, and dropping it would
    // make the owner switch with round-off). Flat and sharp features alike.
    // (flat_limit: kFlatDistance times t's size, for a closest point on an edge or vertex;
    // also the normal's rule below.)
    const double flat_limit =
        r.feature == Feature::face ? 0.0 : kFlatDistance * triangle_scale(P(T(0, t)), P(T(1, t)), P(T(2, t)));
    if (r.feature != Feature::face && dist > flat_limit && off_feature(S, x, p, v, t, r, self)) continue;
    const double sign = d.dot(pseudo) < 0 ? -1.0 : 1.0;
    // The normal (docs/method.md "Contact normals at tiny gaps"): d / |d| is noise when
    // |d| is round-off (its components along the face are ~eps |x| / |d|: 1e-5 rad at a
    // 1e-12 m gap). A closest point inside the face has d along the face normal N in
    // exact arithmetic: n = N (what contact_derivatives.cpp differentiates). A closest
    // point on an edge or vertex of a flat region of B (N within kFlatAngle of the
    // feature's pseudo-normal) closer than kFlatDistance times the triangle's longest
    // edge is recorded as the vertex against the face's plane: n = N, kind_b = face
    // (weights: the closest point's barycentrics, on the edge), differentiated as such.
    const Vec3& N = S.face_normal[t];
    Feature feature = r.feature;
    Vec3 n;
    if (N.squaredNorm() > 0 &&
        (r.feature == Feature::face ||
         (1 - pseudo.dot(N) < kFlatAngle && dist < flat_limit))) {
      n = N;
      feature = Feature::face;
    } else {
      n = dist > tiny ? Vec3(sign * d / dist) : unit_or(pseudo, Vec3(0, 0, 1));
    }
    // The surfaces must face each other along n: the vertex's own (angle-weighted)
    // normal must point towards the triangle. A vertex on an edge of its surface that
    // lies in the plane of a side face of the other body (coplanar sides, common with
    // matching meshes) would otherwise get a sideways contact that conflicts with the
    // face contact holding it.
    if (vertex_normal(cand.dir == 0 ? A : B, x, v).dot(n) > 0) continue;
    Contact& c = out.contacts.emplace_back();
    c.kind = ContactKind::vertex_triangle;
    c.side_a = cand.dir == 0 ? rule.a : rule.b;
    c.side_b = cand.dir == 0 ? rule.b : rule.a;
    c.count = 4;
    c.nodes = {v, T(0, t), T(1, t), T(2, t)};
    c.weights = {1, -r.bary[0], -r.bary[1], -r.bary[2]};
    c.frame = frame_from_normal(n);
    c.point = p;
    c.point_b = r.point;
    c.gap = n.dot(d);
    c.mu = rule.mu;
    c.feature_a = v;
    c.feature_b = t;
    c.kind_b = feature;
  }

  // A point-point pair (v, w) can come from both vertices (v against a triangle of w,
  // and w against a triangle of v): keep the first in the output order.
  pp.clear();
  for (int i = first_contact; i < out.size(); ++i) {
    // A point-point pair: a triangle weight of exactly -1 (its kind_b is vertex, or face
    // when a flat vertex at a tiny gap took the face normal above).
    const Contact& c = out.contacts[i];
    int w = -1;
    for (int k = 1; k < 4; ++k)
      if (c.weights[k] == -1) w = c.nodes[k];
    if (w < 0) continue;
    pp.push_back({std::min(c.nodes[0], w), std::max(c.nodes[0], w), i});
  }
  if (!pp.empty()) {
    std::sort(pp.begin(), pp.end());
    drop.assign(out.size() - first_contact, 0);
    for (std::size_t i = 1; i < pp.size(); ++i)
      if (pp[i][0] == pp[i - 1][0] && pp[i][1] == pp[i - 1][1]) drop[pp[i][2] - first_contact] = 1;
    int kept = first_contact;
    for (int i = first_contact; i < out.size(); ++i)
      if (!drop[i - first_contact]) out.contacts[kept++] = out.contacts[i];
    out.contacts.resize(kept);
  }

  // Edge-edge.
  const auto& EA = A.surface->edges;
  const auto& EB = B.surface->edges;
  for (const EeCandidate& cand : ee) {
    const int a0 = EA(0, cand.ea), a1 = EA(1, cand.ea), b0 = EB(0, cand.eb), b1 = EB(1, cand.eb);
    const Vec3 pa0 = P(a0), pa1 = P(a1), pb0 = P(b0), pb1 = P(b1);
    const SegmentSegmentResult r = segment_segment_closest(pa0, pa1, pb0, pb1);
    if (!(r.dist2 < m2) || !r.interior()) continue;
    // Two edges that both lie in flat parts of their surfaces (dihedral angle below
    // ~8 degrees) add nothing that the vertex-triangle contacts of those flat parts do
    // not already hold; between two flat faces in contact every crossing pair of their
    // edges would otherwise be one more, redundant row of the NCP.
    if (is_flat(A, cand.ea) && is_flat(B, cand.eb)) continue;
    const Vec3 m = edge_normal(B, cand.eb) - edge_normal(A, cand.ea);
    const Vec3 d = r.point_p - r.point_q;
    const double dist = std::sqrt(r.dist2);
    // The normal (docs/method.md "Contact normals at tiny gaps"): interior closest points
    // of two non-parallel edges have d along their cross product N in exact arithmetic;
    // n = +-N (what contact_derivatives.cpp differentiates, with the same parallel test),
    // oriented as d along N_b - N_a, or N itself along it when |d| is round-off.
    // Near-parallel edges keep d / |d| (N is then itself round-off).
    const Vec3 ua = pa1 - pa0, ub = pb1 - pb0, cr = ua.cross(ub);
    const double la = ua.squaredNorm(), lb = ub.squaredNorm(), lab = ua.dot(ub);
    Vec3 n;
    if (la * lb - lab * lab > 1e-14 * la * lb && cr.squaredNorm() > 0) {
      const Vec3 N = cr.normalized();
      const double o = dist > tiny ? (d.dot(m) < 0 ? -1.0 : 1.0) * (d.dot(N) < 0 ? -1.0 : 1.0) : (N.dot(m) < 0 ? -1.0 : 1.0);
      n = o * N;
    } else if (dist > tiny) {
      n = (d.dot(m) < 0 ? -1.0 : 1.0) * d / dist;
    } else {
      n = unit_or(m, Vec3(0, 0, 1));
    }
    // Facing surfaces only (as for vertex-triangle): A's edge normal towards B, B's
    // towards A.
    if (edge_normal(A, cand.ea).dot(n) > 0 || edge_normal(B, cand.eb).dot(n) < 0) continue;
    Contact& c = out.contacts.emplace_back();
    c.kind = ContactKind::edge_edge;
    c.side_a = rule.a;
    c.side_b = rule.b;
    c.count = 4;
    c.nodes = {a0, a1, b0, b1};
    c.weights = {1 - r.s, r.s, -(1 - r.t), -r.t};
    c.frame = frame_from_normal(n);
    c.point = r.point_p;
    c.point_b = r.point_q;
    c.gap = n.dot(d);
    c.mu = rule.mu;
    c.feature_a = cand.ea;
    c.feature_b = cand.eb;
    c.kind_b = Feature::edge;
  }
}

CollisionDetector::CollisionDetector(const DetectionModel& model) : impl_(std::make_unique<Impl>(model)) {}
CollisionDetector::~CollisionDetector() = default;

void CollisionDetector::set_time(double t) {
  for (auto& o : impl_->model.obstacles)
    if (!o.offset_schedule.empty()) o.offset = plane_offset_at(o, t);
}

bool CollisionDetector::has_moving_obstacles() const {
  for (const auto& o : impl_->model.obstacles)
    if (!o.offset_schedule.empty()) return true;
  return false;
}

DetectionStats CollisionDetector::detect(const VecX& x, ContactSet& out) { return detect(x, out, impl_->model.margin); }

DetectionStats CollisionDetector::detect(const VecX& x, ContactSet& out, double margin) {
  SOFTDIFF_DEMAND(margin > 0 && std::isfinite(margin), "the detection margin must be > 0 and finite");
  Impl& im = *impl_;
  im.surface_margin.assign(im.surf.size(), margin);
  return im.run(x, out);
}

DetectionStats CollisionDetector::detect(const VecX& x, ContactSet& out, const std::vector<double>& surface_margin) {
  Impl& im = *impl_;
  SOFTDIFF_DEMAND(surface_margin.size() == im.surf.size(),
                  "expected " + std::to_string(im.surf.size()) + " surface margins, got " +
                      std::to_string(surface_margin.size()));
  for (double m : surface_margin)
    SOFTDIFF_DEMAND(m > 0 && std::isfinite(m), "the detection margin must be > 0 and finite");
  im.surface_margin = surface_margin;  // same size every call: no allocation after the first
  return im.run(x, out);
}

DetectionStats CollisionDetector::Impl::run(const VecX& x, ContactSet& out) {
  SOFTDIFF_DEMAND(x.size() >= 3 * (static_cast<Eigen::Index>(max_node) + 1),
                  "x has " + std::to_string(x.size()) + " entries, the surfaces need " +
                      std::to_string(3 * (max_node + 1)));
  out.clear();
  DetectionStats stats;
  // Broad phase: surface k's boxes inflated by m_k - mu / 2 (detection.hpp).
  double mu = std::numeric_limits<double>::infinity();
  for (std::size_t k = 0; k < surf.size(); ++k)
    if (surf[k].broad) mu = std::min(mu, surface_margin[k]);
  for (std::size_t k = 0; k < surf.size(); ++k)
    if (surf[k].broad) update_surface(surf[k], x, surface_margin[k] - 0.5 * mu);
  for (const PairRule& rule : model.pairs) {
    const double ma = surface_margin[static_cast<std::size_t>(rule.a)];
    if (rule.b >= num_bodies) {
      margin = ma;
      vertex_obstacle(rule, x, out, stats);
    } else {
      margin = std::max(ma, surface_margin[static_cast<std::size_t>(rule.b)]);
      soft_soft(rule, x, out, stats);
    }
  }
  stats.contacts = out.size();
  return stats;
}

}  // namespace softdiff::collision
