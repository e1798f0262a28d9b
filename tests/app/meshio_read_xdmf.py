# Reads softdiff's XDMF output with meshio 7's xdmf.TimeSeriesReader and checks it
# against the HDF5 file with h5py (docs/output.md "XDMF"):
#   - the mesh: points = /bodies/BODY/x[0], cells = /bodies/BODY/tets (tetra; tetra10 for a
#     quadratic body, with gmsh's nodes 8 and 9 swapped; a body without tets, a rigid body:
#     triangle, /bodies/BODY/surface);
#   - every frame k: time = /time[k], point data x = x[k], displacement = x[k] - rest,
#     v = v[k] and contact_force = contact_force[k] when the file has them.
# Usage (Debian's python3 with python3-meshio, python3-h5py, python3-numpy):
#   /usr/bin/python3 meshio_read_xdmf.py OUT.h5 BODY FILE.xmf
# Prints "ok BODY FRAMES FIELDS" and exits 0, or prints what differs and exits 1.
import sys

import h5py
import meshio
import numpy as np


def main(h5_path, body, xmf_path):
    problems = []
    with h5py.File(h5_path, "r") as f, meshio.xdmf.TimeSeriesReader(xmf_path) as reader:
        group = f["bodies"][body]
        x = group["x"][()]
        rest = group["rest"][()]
        times = f["time"][()]
        points, cells = reader.read_points_cells()
        if not np.array_equal(points, x[0]):
            problems.append("mesh points differ from x[0]")
        tets = group["tets"][()]
        # A quadratic body: Tetrahedron_10 in XDMF's (VTK's) order, gmsh's nodes 8 and 9 swapped.
        # A body without tets (a rigid body): its surface triangles.
        cell_type, expected_cells = ("tetra10", tets[:, [0, 1, 2, 3, 4, 5, 6, 7, 9, 8]]) if tets.shape[1] == 10 \
            else ("triangle", group["surface"][()]) if tets.shape[0] == 0 else ("tetra", tets)
        if len(cells) != 1 or cells[0].type != cell_type or not np.array_equal(cells[0].data, expected_cells):
            problems.append("cells differ from tets: %s" % [(c.type, c.data.shape) for c in cells])
        if reader.num_steps != len(times):
            problems.append("%d steps, the file has %d frames" % (reader.num_steps, len(times)))
        expected_fields = {"x", "displacement"} | {name for name in ("v", "contact_force") if name in group}
        for k in range(min(reader.num_steps, len(times))):
            t, point_data, cell_data = reader.read_data(k)
            if t != times[k]:
                problems.append("frame %d: time %r, /time has %r" % (k, t, times[k]))
            if set(point_data) != expected_fields:
                problems.append("frame %d: point data %s, expected %s" % (k, sorted(point_data), sorted(expected_fields)))
                continue
            expected = {"x": x[k], "displacement": x[k] - rest}
            for name in ("v", "contact_force"):
                if name in expected_fields:
                    expected[name] = group[name][k]
            for name, values in expected.items():
                if not np.array_equal(point_data[name], values):
                    problems.append("frame %d: %s differs (largest difference %g)" %
                                    (k, name, np.abs(point_data[name] - values).max()))
        if problems:
            print("\n".join(problems[:20]))
            return 1
        print("ok %s %d %s" % (body, reader.num_steps, ",".join(sorted(expected_fields))))
        return 0


if __name__ == "__main__":
    sys.exit(main(*sys.argv[1:4]))
