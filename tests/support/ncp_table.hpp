#pragma once
// The per-step NCP record of a run, for measurement harnesses (the DISABLED_*Table
// tests; run with --gtest_also_run_disabled_tests): one line per step
//     NCPTABLE | <scene> | <backend> | step | contacts | residual | iterations | ...
// and a summary line per run. Not an assertion: what a change of the contact solver
// does is read from these tables (docs/method.md "Contact", robustness).
#include <softdiff/data.hpp>

#include <algorithm>
#include <cstdint>
#include <filesystem>
#include <cstdio>
#include <string>

namespace softdiff::test {

struct NcpTable {
  std::string scene, backend;
  double tolerance = 1e-8;
  long solves = 0, above = 0, iterations = 0;
  double worst = 0;
  // If not empty: every dense problem that ends above the tolerance is written to
  // <dump_dir>/<scene>_<step>.ncp (int32 nc; doubles G (column-major), g, mu, and the
  // returned lambda), for experiments on single solves.
  std::string dump_dir;

  void row(long step, const Data& data) {
    const auto& cd = data.contact;
    const int nc = cd.contacts.size();
    if (nc == 0) return;
    const auto& r = cd.result;
    ++solves;
    above += r.residuals.max() > tolerance;
    iterations += r.iterations;
    worst = std::max(worst, r.residuals.max());
    std::printf("NCPTABLE | %s | %s | %3ld | %4d | %.2e | %5d | pgs %5d | pol %d | ws %d/%d | sp %d | rho %3d | "
                "st %3d sl %3d br %3d\n",
                scene.c_str(), backend.c_str(), step, nc, r.residuals.max(), r.iterations, r.fallback_iterations,
                r.polished ? 1 : 0, r.working_set_rounds, r.working_set_fallback ? 1 : 0, r.sparse_rounds,
                r.rho_updates, r.sticking, r.sliding, r.breaking);
    std::fflush(stdout);
    if (!dump_dir.empty() && r.residuals.max() > tolerance && cd.G.rows() == 3 * nc) {
      std::filesystem::create_directories(dump_dir);
      const std::string path = dump_dir + "/" + scene + "_" + std::to_string(step) + ".ncp";
      std::FILE* f = std::fopen(path.c_str(), "wb");
      if (!f) return;
      const std::int32_t n32 = nc;
      std::fwrite(&n32, sizeof n32, 1, f);
      std::fwrite(cd.G.data(), sizeof(double), static_cast<std::size_t>(cd.G.size()), f);
      std::fwrite(cd.g.data(), sizeof(double), static_cast<std::size_t>(cd.g.size()), f);
      std::fwrite(cd.mu.data(), sizeof(double), static_cast<std::size_t>(cd.mu.size()), f);
      std::fwrite(cd.lambda.data(), sizeof(double), static_cast<std::size_t>(cd.lambda.size()), f);
      std::fclose(f);
      // The contacts' records beside it (text, one line each): kind side_a side_b count,
      // nodes (4), weights (4), normal (3), gap, point (3), point_b (3), feature_a,
      // feature_b, kind_b: to find duplicate records of one point (self-contact).
      std::FILE* t = std::fopen((dump_dir + "/" + scene + "_" + std::to_string(step) + ".ctc").c_str(), "w");
      if (!t) return;
      for (const auto& c : cd.contacts.contacts) {
        const Vec3 nrm = c.frame.col(2);
        std::fprintf(t, "%d %d %d %d  %d %d %d %d  %.17g %.17g %.17g %.17g  %.17g %.17g %.17g  %.17g  "
                        "%.17g %.17g %.17g  %.17g %.17g %.17g  %d %d %d\n",
                     static_cast<int>(c.kind), c.side_a, c.side_b, c.count, c.nodes[0], c.nodes[1], c.nodes[2],
                     c.nodes[3], c.weights[0], c.weights[1], c.weights[2], c.weights[3], nrm[0], nrm[1], nrm[2],
                     c.gap, c.point[0], c.point[1], c.point[2], c.point_b[0], c.point_b[1], c.point_b[2],
                     c.feature_a, c.feature_b, static_cast<int>(c.kind_b));
      }
      std::fclose(t);
    }
  }
  void summary(const std::string& end) const {
    std::printf("NCPSUMMARY | %s | %s | %ld solves, %ld above %.0e, worst %.2e, %ld iterations | %s\n",
                scene.c_str(), backend.c_str(), solves, above, tolerance, worst, iterations, end.c_str());
    std::fflush(stdout);
  }
};

}  // namespace softdiff::test
