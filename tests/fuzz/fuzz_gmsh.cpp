// libFuzzer target: the Gmsh MSH reader (io/gmsh_msh: MSH 2.2 and 4.1, ASCII and
// binary). Every input must either read or fail with softdiff::InputError (a clear
// message, exit code 2 in the CLI): any other exception, a crash, a leak or undefined
// behaviour (AddressSanitizer, UBSan) is a finding. Crashes found become regression
// tests in tests/io/test_gmsh_msh.cpp ("FuzzRegression").
// Run: build/fuzz/fuzz_gmsh [-max_total_time=60] CORPUS_DIR tests/fuzz/corpus/gmsh
#include <softdiff/core/error.hpp>
#include <softdiff/io/gmsh_msh.hpp>

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <string>
#include <unistd.h>

namespace {
// The reader takes a path: each input is written to this process's own file.
const std::filesystem::path& input_file() {
  static const std::filesystem::path file =
      std::filesystem::temp_directory_path() / ("softdiff_fuzz_gmsh_" + std::to_string(::getpid()) + ".msh");
  return file;
}
}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  std::FILE* f = std::fopen(input_file().c_str(), "wb");
  if (!f) return 0;
  std::fwrite(data, 1, size, f);
  std::fclose(f);
  try {
    const softdiff::mesh::TetMesh mesh = softdiff::io::read_gmsh(input_file());
    (void)mesh;
  } catch (const softdiff::InputError&) {
  }
  try {
    const softdiff::io::GmshTriangles triangles = softdiff::io::read_gmsh_triangles(input_file());
    (void)triangles;
  } catch (const softdiff::InputError&) {
  }
  return 0;
}
