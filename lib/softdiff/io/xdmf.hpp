#pragma once
// The XDMF files written beside an output file, read by ParaView's Xdmf3 readers
// ("Xdmf3 Reader S" / "T") and by meshio 7's xdmf.TimeSeriesReader:
//   out.h5 -> out.xmf          every body (ParaView);
//          -> out.<body>.xmf   one body per file (meshio reads one mesh per file).
// With a single body, out.xmf has the per-body layout too.
//
// Layout (XDMF 3):
//   Domain
//     Grid "softdiff" (Collection, Temporal)
//       one body:   Grid "<body>" (Uniform), Time = /time[k]         <- frame k
//       several:    Grid "frame k" (Collection, Spatial), Time = /time[k]
//                     Grid "<body>" (Uniform)                         (per body)
//         Topology Tetrahedron       <- out.h5:/bodies/<body>/tets (m, 4)
//                  Triangle          <- out.h5:/bodies/<body>/surface (k, 3) for a body without
//                                       tets (a rigid body: its surface, x posed per frame)
//                  Tetrahedron_10    <- out.h5:/xdmf/<body>/tets (m, 10) for a quadratic body:
//                                       /bodies/<body>/tets (gmsh's node order) with
//                                       nodes 8 and 9 swapped (XDMF and VTK list the
//                                       edges 01 12 20 30 31 32, gmsh 01 12 20 30 32 31)
//         Geometry XYZ               <- out.h5:/xdmf/<body>/x/<k>  (n, 3)
//         Attribute "<field>" (Node, Vector) <- out.h5:/xdmf/<body>/<field>/<k>
//           for field in x, v (when written), displacement, contact_force (when written)
// /xdmf/<body>/<field>/<k> is an HDF5 virtual dataset: a view of frame k of
// /bodies/<body>/<field> (T, n, 3) that stores a mapping, not the values. Every
// DataItem is a plain HDF DataItem naming a whole dataset: meshio's reader accepts
// nothing else (no HyperSlab DataItem, no "file:path|slab" syntax), and ParaView's
// Xdmf3 readers skip HyperSlab DataItems. meshio reads the mesh (points and cells)
// once, from the first frame; the positions of frame k are its point data "x".
// Heavy data is referenced by the .h5 file's name alone (same folder), so the files
// can be moved together; that name cannot contain ':' or '|'.
#include <filesystem>
#include <string>
#include <string_view>
#include <vector>

namespace softdiff::io {

struct XdmfBody {
  std::string name;
  long nodes = 0;  // n: rows of /bodies/<name>/rest and of each frame of x
  long tets = 0;   // m: rows of /bodies/<name>/tets
  int nodes_per_tet = 4;  // 4, or 10 (Tetrahedron_10 from /xdmf/<name>/tets)
  // A surface-only body (tets == 0: a rigid body's surface, posed per frame in x):
  // Topology Triangle from /bodies/<name>/surface (triangles, 3).
  long triangles = 0;
};

// The (m, 10) connectivity in XDMF's order of a quadratic body: "/xdmf/<body>/tets".
std::string xdmf_tets_path(const std::string& body);

// The view of frame k of /bodies/<body>/<field>: "/xdmf/<body>/<field>/<k>".
std::string frame_view_path(const std::string& body, const std::string& field, long frame);

// The per-body XDMF file beside `h5_file`: out.h5 -> out.<body>.xmf.
std::filesystem::path xdmf_body_path(const std::filesystem::path& h5_file, const std::string& body);

// The whole document. `h5_name`: the HDF5 file as referenced (its file name);
// `times`: one entry per frame (T frames); `fields`: the node fields of each frame,
// written as attributes; "x" (the geometry) must be among them.
std::string xdmf_text(const std::string& h5_name, const std::vector<XdmfBody>& bodies,
                      const std::vector<double>& times, const std::vector<std::string>& fields);

// Writes `text` to `path` through a temporary file in the same folder and an atomic
// rename. Throws ComputationError on failure (the temporary file is removed).
void write_text_file_atomically(const std::filesystem::path& path, const std::string& text);

// Escapes &, <, >, " and ' for XML text and attribute values.
std::string xml_escape(std::string_view text);

}  // namespace softdiff::io
