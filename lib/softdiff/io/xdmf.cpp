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

// A plain HDF DataItem naming a whole dataset of the given shape.
void append_data_item(std::string& out, const std::string& indent, const std::string& dimensions, const char* type,
                      const std::string& heavy) {
  out += indent + "<DataItem Dimensions=\"" + dimensions + "\" NumberType=\"" + type +
         "\" Precision=\"8\" Format=\"HDF\">" + heavy + "</DataItem>\n";
}

// One body's grid at frame k: topology, geometry (the view of x) and the node fields.
void append_body_grid(std::string& out, const std::string& indent, const std::string& file, const XdmfBody& body,
                      long frame, const std::string* time, const std::vector<std::string>& fields) {
  const std::string name = xml_escape(body.name);
  const std::string m = std::to_string(body.tets);
  const std::string n3 = std::to_string(body.nodes) + " 3";
  const auto view = [&](const std::string& field) {
    return file + ":" + xml_escape(frame_view_path(body.name, field, frame));
  };
  out += indent + "<Grid Name=\"" + name + "\" GridType=\"Uniform\">\n";
  if (time != nullptr) out += indent + "  <Time Value=\"" + *time + "\"/>\n";
  if (body.tets == 0) {
    const std::string k = std::to_string(body.triangles);
    out += indent + "  <Topology TopologyType=\"Triangle\" NumberOfElements=\"" + k + "\">\n";
    append_data_item(out, indent + "    ", k + " 3", "Int", file + ":/bodies/" + name + "/surface");
  } else if (body.nodes_per_tet == 10) {
    out += indent + "  <Topology TopologyType=\"Tetrahedron_10\" NumberOfElements=\"" + m + "\">\n";
    append_data_item(out, indent + "    ", m + " 10", "Int", file + ":" + xml_escape(xdmf_tets_path(body.name)));
  } else {
    out += indent + "  <Topology TopologyType=\"Tetrahedron\" NumberOfElements=\"" + m + "\">\n";
    append_data_item(out, indent + "    ", m + " 4", "Int", file + ":/bodies/" + name + "/tets");
  }
  out += indent + "  </Topology>\n";
  out += indent + "  <Geometry GeometryType=\"XYZ\">\n";
  append_data_item(out, indent + "    ", n3, "Float", view("x"));
  out += indent + "  </Geometry>\n";
  for (const std::string& field : fields) {
    out += indent + "  <Attribute Name=\"" + xml_escape(field) + "\" AttributeType=\"Vector\" Center=\"Node\">\n";
    append_data_item(out, indent + "    ", n3, "Float", view(field));
    out += indent + "  </Attribute>\n";
  }
  out += indent + "</Grid>\n";
}

}  // namespace

std::string xdmf_tets_path(const std::string& body) { return "/xdmf/" + body + "/tets"; }

std::string frame_view_path(const std::string& body, const std::string& field, long frame) {
  return "/xdmf/" + body + "/" + field + "/" + std::to_string(frame);
}

std::filesystem::path xdmf_body_path(const std::filesystem::path& h5_file, const std::string& body) {
  std::filesystem::path path = h5_file;
  path.replace_extension();
  path += "." + body + ".xmf";
  return path;
}

std::string xdmf_text(const std::string& h5_name, const std::vector<XdmfBody>& bodies,
                      const std::vector<double>& times, const std::vector<std::string>& fields) {
  const std::string file = xml_escape(h5_name);
  std::vector<const XdmfBody*> shown;  // bodies ParaView can show (nodes and tets, or a surface)
  for (const XdmfBody& body : bodies)
    if (body.nodes > 0 && (body.tets > 0 || body.triangles > 0)) shown.push_back(&body);
  const bool single = shown.size() == 1;
  const long frames = static_cast<long>(times.size());
  std::string out;
  out.reserve(512 + times.size() * (200 + shown.size() * (700 + 300 * fields.size())));
  out += "<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n";
  out += "<!-- softdiff output: ParaView (Xdmf3 Reader S or T) and meshio.xdmf.TimeSeriesReader read it. "
         "Frame k of /bodies/BODY/FIELD is the HDF5 virtual dataset /xdmf/BODY/FIELD/k. -->\n";
  out += "<Xdmf Version=\"3.0\">\n";
  out += "  <Domain>\n";
  out += "    <Grid Name=\"softdiff\" GridType=\"Collection\" CollectionType=\"Temporal\">\n";
  for (long k = 0; k < frames; ++k) {
    const std::string time = number(times[static_cast<std::size_t>(k)]);
    if (single) {
      append_body_grid(out, "      ", file, *shown.front(), k, &time, fields);
      continue;
    }
    out += "      <Grid Name=\"frame " + std::to_string(k) + "\" GridType=\"Collection\" CollectionType=\"Spatial\">\n";
    out += "        <Time Value=\"" + time + "\"/>\n";
    for (const XdmfBody* body : shown) append_body_grid(out, "        ", file, *body, k, nullptr, fields);
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
