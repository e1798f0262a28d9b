#pragma once
// The scene format (spec: scene.md, version 1) as a schema table: every key, its
// type, range and enum values, which keys are required, and which belong to
// features not implemented yet. Used by load_scene() for validation, unknown-key
// suggestions and --set paths. Adding a feature: give its Field no `planned`, and
// read its values in scene.cpp.
#include <softdiff/io/yaml_validate.hpp>

namespace softdiff::io {

const schema::Spec& scene_schema();

}  // namespace softdiff::io
