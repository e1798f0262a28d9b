// libFuzzer target: the scene loader (io/scene: YAML parsing, the schema, every
// value's validation, `--set` overrides). Every input must either load or fail with
// softdiff::InputError; any other exception, a crash or undefined behaviour is a
// finding (regression tests: tests/io/test_scene.cpp, "FuzzRegression").
// The scene is written next to a one-tetrahedron mesh `mesh.msh` (and `key.stl`), so
// that the seed scenes' mesh paths resolve. An input whose first line starts with
// "#set " gives one override KEY=VALUE (the rest of that line), as --set does.
// Run: build/fuzz/fuzz_scene [-max_total_time=60] CORPUS_DIR tests/fuzz/corpus/scene
#include <softdiff/core/error.hpp>
#include <softdiff/io/scene.hpp>

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>
#include <unistd.h>
#include <vector>

namespace fs = std::filesystem;

namespace {
const fs::path& folder() {
  static const fs::path dir = [] {
    const fs::path d = fs::temp_directory_path() / ("softdiff_fuzz_scene_" + std::to_string(::getpid()));
    fs::create_directories(d);
    std::ofstream(d / "mesh.msh") << "$MeshFormat\n2.2 0 8\n$EndMeshFormat\n$Nodes\n4\n1 0 0 0\n2 1 0 0\n3 0 1 0\n"
                                     "4 0 0 1\n$EndNodes\n$Elements\n1\n1 4 2 1 1 1 2 3 4\n$EndElements\n";
    std::ofstream(d / "key.stl") << "solid k\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\n"
                                    "vertex 0 1 0\nendloop\nendfacet\nendsolid k\n";
    return d;
  }();
  return dir;
}
}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  std::vector<std::string> overrides;
  if (text.rfind("#set ", 0) == 0) overrides.push_back(text.substr(5, text.find('\n') - 5));
  const fs::path file = folder() / "scene.yaml";
  std::FILE* f = std::fopen(file.c_str(), "wb");
  if (!f) return 0;
  std::fwrite(data, 1, size, f);
  std::fclose(f);
  try {
    const softdiff::io::SceneDesc scene = softdiff::io::load_scene(file, overrides);
    (void)scene;
  } catch (const softdiff::InputError&) {
  }
  return 0;
}
