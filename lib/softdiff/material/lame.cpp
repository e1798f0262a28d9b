#include <softdiff/material/material.hpp>

namespace softdiff::material {

std::string_view law_name(Law law) {
  switch (law) {
    case Law::corotational: return "corotational";
    case Law::stvk: return "stvk";
    case Law::neo_hookean: return "neo_hookean";
    case Law::linear: return "linear";
  }
  return "?";
}

Lame lame_from_young_poisson(double young, double poisson) {
  return {young / (2.0 * (1.0 + poisson)), young * poisson / ((1.0 + poisson) * (1.0 - 2.0 * poisson))};
}

}  // namespace softdiff::material
