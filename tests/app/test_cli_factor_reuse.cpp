// linear_solver.factor_reuse: pcg on the command line (docs/scene.md, docs/cli.md): the
// run's JSON counts the factorizations and PCG iterations; the combinations it does not
// serve (contact, newton_iterations > 1, integrator: static, a type other than cholmod)
// and misplaced keys are refused with exit code 2, a message naming the key, and no
// output file.
#include <support/cli.hpp>

#include <gtest/gtest.h>

#include <filesystem>
#include <regex>
#include <string>

using namespace softdiff::test;
namespace fs = std::filesystem;

namespace cli_factor_reuse {

const fs::path kRoot = SOFTDIFF_SOURCE_DIR;
const fs::path kWork = fs::path(SOFTDIFF_TEST_DATA_DIR) / "cli_factor_reuse";

// The shipped beam, clamped, falling under gravity for `steps` steps (steps = 0: no dt
// and steps, as integrator: static wants).
std::string scene(const std::string& solver, const std::string& simulation_extra = "", const std::string& tail = "",
                  int steps = 20) {
  const std::string timing = steps > 0 ? "  dt: 0.01\n  steps: " + std::to_string(steps) + "\n" : "";
  return "softdiff: 1\n"
         "simulation:\n" +
         timing + simulation_extra + "linear_solver: " + solver +
         "\n"
         "bodies:\n"
         "  - name: beam\n"
         "    mesh: " +
         (kRoot / "meshes/beam.msh").string() +
         "\n"
         "    material: {law: corotational, young: 1.0e6, poisson: 0.45, density: 1070}\n"
         "    fixed:\n"
         "      - group: clamp\n" +
         tail;
}

long json_integer(const std::string& json, const std::string& key) {
  const std::regex re("\"" + key + "\":([0-9]+)");
  std::smatch m;
  if (!std::regex_search(json, m, re)) return -1;
  return std::stol(m[1]);
}

TEST(CliFactorReuse, JsonCountsFactorizationsAndPcgIterations) {
  const fs::path dir = fresh_dir(kWork, "counts");
  write_text(dir / "scene.yaml", scene("{type: cholmod, factor_reuse: pcg}"));
  const auto r = run_cli("simulate scene.yaml -o out.h5 --json --quiet", dir);
  ASSERT_EQ(r.code, 0) << r.err;
  // 20 steps form 20 matrices; the first is factorized, later ones keep a factor.
  EXPECT_EQ(json_integer(r.out, "factorizations"), 20) << r.out;
  const long numeric = json_integer(r.out, "numeric_factorizations");
  const long kept = json_integer(r.out, "kept_factors");
  EXPECT_GE(numeric, 1) << r.out;
  EXPECT_GE(kept, 1) << r.out;
  EXPECT_EQ(numeric + kept - json_integer(r.out, "pcg_fallbacks"), 20) << r.out;
  EXPECT_EQ(json_integer(r.out, "pcg_solves"), kept) << r.out;
  EXPECT_GE(json_integer(r.out, "pcg_iterations"), kept) << r.out;

  // Without reuse: every matrix is factorized, no PCG.
  write_text(dir / "scene.yaml", scene("cholmod"));
  const auto d = run_cli("simulate scene.yaml -o out.h5 --json --quiet --force", dir);
  ASSERT_EQ(d.code, 0) << d.err;
  EXPECT_EQ(json_integer(d.out, "numeric_factorizations"), 20) << d.out;
  EXPECT_EQ(json_integer(d.out, "pcg_iterations"), 0) << d.out;
}

struct Refused {
  std::string name, solver, simulation_extra, tail, message;
  int steps = 20;
};

class CliFactorReuseRefused : public ::testing::TestWithParam<Refused> {};

TEST_P(CliFactorReuseRefused, ExitsWithCode2AndNoOutput) {
  const Refused& p = GetParam();
  const fs::path dir = fresh_dir(kWork, p.name);
  write_text(dir / "scene.yaml", scene(p.solver, p.simulation_extra, p.tail, p.steps));
  const auto r = run_cli("simulate scene.yaml -o out.h5", dir);
  EXPECT_EQ(r.code, 2) << r.err;
  EXPECT_NE(r.err.find(p.message), std::string::npos) << r.err;
  EXPECT_NE(r.err.find("scene.yaml:"), std::string::npos) << r.err;  // the file and line
  EXPECT_FALSE(fs::exists(dir / "out.h5"));
  EXPECT_FALSE(fs::exists(dir / "out.h5.partial"));
}

INSTANTIATE_TEST_SUITE_P(
    Cases, CliFactorReuseRefused,
    ::testing::Values(
        Refused{"contact", "{factor_reuse: pcg}", "", "contact: {enabled: true}\n",
                "linear_solver.factor_reuse: pcg is not available with contact"},
        Refused{"newton", "{factor_reuse: pcg}", "  newton_iterations: 4\n", "",
                "linear_solver.factor_reuse: pcg is not available with simulation.newton_iterations > 1"},
        Refused{"static", "{factor_reuse: pcg}", "  integrator: static\n", "",
                "linear_solver.factor_reuse: pcg is not available with simulation.integrator: static", 0},
        Refused{"cg", "{type: cg, factor_reuse: pcg}", "", "", "linear_solver.factor_reuse: only used by type 'cholmod'"},
        Refused{"refactor_without_reuse", "{type: cholmod, refactor_iterations: 4}", "", "",
                "linear_solver.refactor_iterations: only used with factor_reuse: pcg"},
        Refused{"bad_value", "{factor_reuse: yes}", "", "", "linear_solver.factor_reuse"}),
    [](const auto& p) { return p.param.name; });

}  // namespace cli_factor_reuse
