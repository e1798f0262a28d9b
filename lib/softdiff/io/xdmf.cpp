#include <softdiff/io/xdmf.hpp>

#include <softdiff/core/error.hpp>

#include <cerrno>
#include <charconv>
#include <cstdio>
#include <cstring>
#include <system_error>

namespace softdiff::io {

std::string xml_escape(std::string_view text) {
  std::string out;
  out.reserve(text.size());
  for (const char c : text) {
    switch (c) {
      case '&': out += "&amp;"; break;
      case '<': out += "&lt;"; break;
      case '>': out += "&gt;"; break;
      case '"': out += "&quot;"; break;
      case '\'': out += "&apos;"; break;
      default: out += c;
    }
  }
  return out;
}

namespace {

// Shortest text that reads back as the same double.
std::string number(double value) {
  char buffer[32];
  const auto result = std::to_chars(buffer, buffer + sizeof buffer, value);
  return std::string(buffer, result.ptr);
}

// Frame k of a node-centred (T, n, 3) dataset. The slab is written in the XDMF 3
// library's own heavy-data syntax, "file:dataset|start:stride:count:dataspace",
// which ParaView's Xdmf3 readers read directly; a HyperSlab DataItem
// (ItemType="HyperSlab") is skipped by them ("unrecognized array type").
void append_frame_slab(std::string& out, const std::string& indent, const std::string& heavy,
                       long frame, long frames, long nodes) {
  const std::string n = std::to_string(nodes);
  out += indent + "<DataItem Dimensions=\"1 " + n + " 3\" NumberType=\"Float\" Precision=\"8\" Format=\"HDF\">" +
         heavy + "|" + std::to_string(frame) + " 0 0:1 1 1:1 " + n + " 3:" + std::to_string(frames) + " " + n +
         " 3</DataItem>\n";
}

}  // namespace

std::string xdmf_text(const std::string& h5_name, const std::vector<XdmfBody>& bodies,
                      const std::vector<double>& times, bool with_velocity) {
  const std::string file = xml_escape(h5_name);
  const long frames = static_cast<long>(times.size());
  std::string out;
  out.reserve(512 + times.size() * (200 + bodies.size() * (with_velocity ? 1400 : 900)));
  out += "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n";
  out += "<!-- softdiff output: open with ParaView's Xdmf3 Reader T (or S). Frame k of "
         "/bodies/NAME/x is its slab \"k 0 0:1 1 1:1 n 3\" (start:stride:count). -->\n";
  out += "<Xdmf Version=\"3.0\">\n";
  out += "  <Domain>\n";
  out += "    <Grid Name=\"softdiff\" GridType=\"Collection\" CollectionType=\"Temporal\">\n";
  for (long k = 0; k < frames; ++k) {
    out += "      <Grid Name=\"frame " + std::to_string(k) +
           "\" GridType=\"Collection\" CollectionType=\"Spatial\">\n";
    out += "        <Time Value=\"" + number(times[static_cast<std::size_t>(k)]) + "\"/>\n";
    for (const XdmfBody& body : bodies) {
      if (body.nodes <= 0 || body.tets <= 0) continue;  // nothing ParaView could show
      const std::string name = xml_escape(body.name);
      const std::string group = file + ":/bodies/" + name;
      const std::string m = std::to_string(body.tets);
      out += "        <Grid Name=\"" + name + "\" GridType=\"Uniform\">\n";
      out += "          <Topology TopologyType=\"Tetrahedron\" NumberOfElements=\"" + m + "\">\n";
      out += "            <DataItem Dimensions=\"" + m +
             " 4\" NumberType=\"Int\" Precision=\"8\" Format=\"HDF\">" + group + "/tets</DataItem>\n";
      out += "          </Topology>\n";
      out += "          <Geometry GeometryType=\"XYZ\">\n";
      append_frame_slab(out, "            ", group + "/x", k, frames, body.nodes);
      out += "          </Geometry>\n";
      if (with_velocity) {
        out += "          <Attribute Name=\"v\" AttributeType=\"Vector\" Center=\"Node\">\n";
        append_frame_slab(out, "            ", group + "/v", k, frames, body.nodes);
        out += "          </Attribute>\n";
      }
      out += "        </Grid>\n";
    }
    out += "      </Grid>\n";
  }
  out += "    </Grid>\n";
  out += "  </Domain>\n";
  out += "</Xdmf>\n";
  return out;
}

void write_text_file_atomically(const std::filesystem::path& path, const std::string& text) {
  std::filesystem::path temporary = path;
  temporary += ".partial";
  const auto fail = [&](const std::string& what, int error) {
    std::remove(temporary.c_str());
    throw ComputationError(path.string() + ": " + what + ": " + std::strerror(error));
  };
  std::FILE* stream = std::fopen(temporary.c_str(), "wb");
  if (stream == nullptr) fail("cannot create " + temporary.string(), errno);
  const bool written = std::fwrite(text.data(), 1, text.size(), stream) == text.size();
  const int write_error = errno;
  if (std::fclose(stream) != 0 || !written) fail("cannot write", written ? errno : write_error);
  std::error_code ec;
  std::filesystem::rename(temporary, path, ec);
  if (ec) fail("cannot rename " + temporary.string(), ec.value());
}

}  // namespace softdiff::io
