// The default build runs on every x86-64 CPU (docs/performance.md "Portable builds").
// The CLI is run on emulated CPUs (qemu-x86_64, Debian's qemu-user: scripts/setup
// installs it) on a contact scene, the kind of scene that crashed when softdiff and
// libfcl disagreed on Eigen's alignment:
//  - "qemu64": baseline x86-64 (SSE2, SSE3, no AVX); "Haswell": AVX2 and FMA. The host CPU
//    (the test machines have AVX-512) runs it natively.
//  - A portable build must complete on each and agree with the host's run. The runs
//    differ only in the BLAS kernels OpenBLAS selects for each CPU (summation order
//    in CHOLMOD's supernodal updates), so positions agree to round-off amplified by
//    the system's conditioning: 1e-9 m on 20 mm cubes (measured: 6e-17 m on the
//    baseline CPU, 9e-17 m on AVX2).
//  - A build for the build machine's CPU (-DSOFTDIFF_NATIVE=ON) must instead stop with
//    the message of app/isa_check.cpp (exit 1) where the CPU lacks its extensions,
//    never with SIGILL.
#include <support/cli.hpp>
#include <support/h5.hpp>

#include <gtest/gtest.h>
#include <hdf5.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <string>
#include <vector>

using namespace softdiff::test;
namespace fs = std::filesystem;

// A named namespace: this file is compiled in a unity batch with others.
namespace cli_portable {

const fs::path kRoot = SOFTDIFF_SOURCE_DIR;
const fs::path kWork = fs::path(SOFTDIFF_TEST_DATA_DIR) / "cli_portable";

// Two 20 mm cubes (a coarse gmsh mesh: the emulator is slow) stacked 0.1 mm apart over
// a plane: vertex-plane contacts and soft-soft contacts, whose broad phase is libfcl's
// AABB tree.
fs::path cube_mesh(const fs::path& dir) {
  write_text(dir / "cube.geo",
             "SetFactory(\"OpenCASCADE\");\nBox(1) = {0, 0, 0, 0.02, 0.02, 0.02};\n"
             "Mesh.MeshSizeMin = 0.01;\nMesh.MeshSizeMax = 0.01;\n");  // 45 nodes, 119 tets
  const std::string cmd = std::string("'") + GMSH_EXECUTABLE + "' -3 -format msh41 '" + (dir / "cube.geo").string() +
                          "' -o '" + (dir / "cube.msh").string() + "' >/dev/null 2>&1";
  EXPECT_EQ(std::system(cmd.c_str()), 0) << cmd;
  return dir / "cube.msh";
}

std::string scene(const fs::path& mesh) {
  const std::string material = "    material: {law: corotational, young: 1.0e5, poisson: 0.3, density: 1000}\n";
  return "softdiff: 1\n"
         "simulation: {dt: 0.005, steps: 3}\n"
         "bodies:\n"
         "  - name: beam\n"
         "    mesh: " + mesh.string() + "\n"
         "    translate: [0, 0, 0.0001]\n" + material +
         "  - name: top\n"
         "    mesh: " + mesh.string() + "\n"
         "    translate: [0, 0, 0.0203]\n" + material +
         "obstacles:\n"
         "  - {name: floor, type: plane, normal: [0, 0, 1], offset: 0}\n"
         "contact:\n"
         "  pairs: [[beam, floor, 0.5], [top, beam, 0.5]]\n"
         "  tolerance: 1.0e-6\n";
}

std::string qemu() {
  for (const char* p : {"/usr/bin/qemu-x86_64", "/usr/bin/qemu-x86_64-static"})
    if (fs::exists(p)) return p;
  return {};
}

struct Frames {
  std::vector<double> x;
  long contacts = 0;
  long soft_soft = 0;  // contacts between the two beams (names: beam 0, top 1, floor 2)
};

Frames read_run(const fs::path& file) {
  Frames r;
  const hid_t f = H5Fopen(file.c_str(), H5F_ACC_RDONLY, H5P_DEFAULT);
  EXPECT_GE(f, 0) << file;
  if (f < 0) return r;
  r.x = h5_read(f, "/bodies/beam/x");
  const std::vector<double> top = h5_read(f, "/bodies/top/x");
  r.x.insert(r.x.end(), top.begin(), top.end());
  r.contacts = static_cast<long>(h5_shape(f, "/contact/force").at(0));
  std::vector<int> pairs(2 * static_cast<std::size_t>(r.contacts));
  const hid_t d = H5Dopen2(f, "/contact/pair", H5P_DEFAULT);
  EXPECT_GE(H5Dread(d, H5T_NATIVE_INT, H5S_ALL, H5S_ALL, H5P_DEFAULT, pairs.data()), 0);
  H5Dclose(d);
  for (std::size_t k = 0; k < pairs.size(); k += 2) r.soft_soft += pairs[k] < 2 && pairs[k + 1] < 2;
  H5Fclose(f);
  return r;
}

TEST(PortableBuild, ContactSceneRunsOnBaselineAndAvx2Cpus) {
#if !defined(__x86_64__)
  GTEST_SKIP() << "x86-64 only";
#else
  const std::string q = qemu();
  ASSERT_FALSE(q.empty()) << "qemu-x86_64 not found: scripts/setup installs qemu-user";
  const fs::path dir = fresh_dir(kWork, "runs");
  write_text(dir / "scene.yaml", scene(cube_mesh(dir)));
  const CliRun version = run_cli("--version", dir);
  ASSERT_EQ(version.code, 0) << version.err;
  const bool portable = version.out.find("portable") != std::string::npos;

  const CliRun host = run_cli("simulate scene.yaml -o host.h5 --quiet", dir);
  ASSERT_EQ(host.code, 0) << host.err;
  const Frames reference = read_run(dir / "host.h5");
  ASSERT_GT(reference.soft_soft, 0) << "the scene must have soft-soft contacts (libfcl's broad phase)";

  // qemu64 with an Intel vendor: qemu's default qemu64 model says AMD, for which
  // OpenBLAS picks kernels with 3DNow! instructions (femms) that qemu does not emulate.
  for (const std::string cpu : {"qemu64,vendor=GenuineIntel", "Haswell"}) {
    SCOPED_TRACE("emulated CPU " + cpu);
    // The CLI itself runs under qemu (run_cli prefixes nothing: the emulator is
    // given as the program and the CLI as its argument). OPENBLAS_CORETYPE is removed
    // from its environment: OpenBLAS must pick the kernels of the emulated CPU, and a
    // machine may set it for its own (seen: OPENBLAS_CORETYPE=Haswell in the
    // environment of an AMD EPYC test machine, with which the baseline run stopped on
    // an AVX instruction in OpenBLAS, not in softdiff).
    const std::string tag = cpu.substr(0, cpu.find(','));
    const std::string out = tag + ".h5";
    const std::string cmd = "cd '" + dir.string() + "' && env -u OPENBLAS_CORETYPE OMP_NUM_THREADS=1 '" + q + "' -cpu " + cpu + " '" +
                            SOFTDIFF_CLI "' simulate scene.yaml -o " + out + " --quiet >" + tag +
                            ".out 2>" + tag + ".err </dev/null";
    const int status = std::system(cmd.c_str());
    ASSERT_TRUE(WIFEXITED(status)) << "killed by a signal: " << read_text(dir / (tag + ".err"));
    const int code = WEXITSTATUS(status);
    const std::string err = read_text(dir / (tag + ".err"));
    if (!portable) {
      // A native build on an AVX-512 host: both emulated CPUs lack AVX-512.
      EXPECT_EQ(code, 1) << err;
      EXPECT_NE(err.find("-DSOFTDIFF_NATIVE=OFF"), std::string::npos) << err;
      EXPECT_FALSE(fs::exists(dir / out));
      continue;
    }
    ASSERT_EQ(code, 0) << err;
    const Frames run = read_run(dir / out);
    EXPECT_EQ(run.contacts, reference.contacts);
    EXPECT_EQ(run.soft_soft, reference.soft_soft);
    ASSERT_EQ(run.x.size(), reference.x.size());
    double worst = 0;
    for (std::size_t i = 0; i < run.x.size(); ++i) worst = std::max(worst, std::abs(run.x[i] - reference.x[i]));
    EXPECT_LE(worst, 1e-9) << "largest position difference against the host's run, m";
    std::printf("[ %s ] largest position difference against the host: %.3g m\n", tag.c_str(), worst);
  }
#endif
}

}  // namespace cli_portable
