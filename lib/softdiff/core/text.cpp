#include <softdiff/core/text.hpp>

#include <sstream>

namespace softdiff {

std::vector<std::string> split_list(const std::string& s, char sep) {
  std::vector<std::string> out;
  std::stringstream in(s);
  std::string item;
  while (std::getline(in, item, sep)) {
    item.erase(0, item.find_first_not_of(" \t\r"));
    item.erase(item.find_last_not_of(" \t\r") + 1);
    out.push_back(item);
  }
  if (!s.empty() && s.back() == sep) out.push_back("");
  return out;
}

}  // namespace softdiff
