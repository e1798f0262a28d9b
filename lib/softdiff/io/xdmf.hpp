#pragma once
// The XDMF file written beside an output file (out.h5 -> out.xmf) so that ParaView
// (either XDMF reader) opens the frames of /bodies/<name>/x as a time series.
//
// Layout (XDMF 3, for ParaView's "Xdmf3 Reader T" / "Xdmf3 Reader S"):
//   Domain
//     Grid "softdiff" (Collection, Temporal)
//       Grid "frame k" (Collection, Spatial), Time = /time[k]
//         Grid "<body>" (Uniform)
//           Topology Tetrahedron      <- out.h5:/bodies/<body>/tets (m, 4)
//           Geometry XYZ              <- out.h5:/bodies/<body>/x|k 0 0:1 1 1:1 n 3:T n 3
//           Attribute "v" (Node, Vector) <- the same slab of /bodies/<body>/v (if written)
// A frame is selected with the XDMF 3 library's heavy-data slab syntax
// ("file:dataset|start:stride:count:dataspace"), not with a HyperSlab DataItem:
// ParaView's Xdmf3 readers skip HyperSlab DataItems (no points), and its legacy
// XDMF (2) reader does not read the slab syntax. Checked with ParaView 5.11.
// Heavy data is referenced by the .h5 file's name alone (same folder), so the pair
// of files can be moved together; that name cannot contain ':' or '|'.
#include <filesystem>
#include <string>
#include <string_view>
#include <vector>

namespace softdiff::io {

struct XdmfBody {
  std::string name;
  long nodes = 0;  // n: rows of /bodies/<name>/rest and of each frame of x
  long tets = 0;   // m: rows of /bodies/<name>/tets
};

// The whole document. `h5_name`: the HDF5 file as referenced (its file name);
// `times`: one entry per frame (T frames).
std::string xdmf_text(const std::string& h5_name, const std::vector<XdmfBody>& bodies,
                      const std::vector<double>& times, bool with_velocity);

// Writes `text` to `path` through a temporary file in the same folder and an atomic
// rename. Throws ComputationError on failure (the temporary file is removed).
void write_text_file_atomically(const std::filesystem::path& path, const std::string& text);

// Escapes &, <, >, " and ' for XML text and attribute values.
std::string xml_escape(std::string_view text);

}  // namespace softdiff::io
