# Reads an XDMF file with ParaView's Xdmf3 readers and prints, for every reader, time
# step and leaf block (in order), one line:
#   READER STEP TIME BLOCK POINTS CELLS SUM_OF_POINT_COORDINATES SUM_OF_V SUM_OF_DISPLACEMENT
# Run with pvpython (Debian: python3-paraview); used by test_io when pvpython exists.
#   pvpython paraview_read_xdmf.py /absolute/path/out.xmf
import sys

from paraview import servermanager as sm
from paraview import simple as pv
from vtkmodules.numpy_interface import dataset_adapter as dsa
from vtkmodules.vtkCommonDataModel import vtkDataObjectTree


def leaves(data):
    if isinstance(data, vtkDataObjectTree):
        iterator = data.NewTreeIterator()
        iterator.VisitOnlyLeavesOn()
        iterator.InitTraversal()
        while not iterator.IsDoneWithTraversal():
            yield iterator.GetCurrentDataObject()
            iterator.GoToNextItem()
    elif data is not None:
        yield data


path = sys.argv[1]
for name in ("Xdmf3ReaderT", "Xdmf3ReaderS"):
    reader = getattr(pv, name)(FileName=[path])
    for step, time in enumerate(reader.TimestepValues or []):
        reader.UpdatePipeline(time)
        for block, leaf in enumerate(leaves(sm.Fetch(reader))):
            wrapped = dsa.WrapDataObject(leaf)
            points = float(wrapped.Points.sum()) if leaf.GetNumberOfPoints() else 0.0
            sums = []
            for field in ("v", "displacement"):
                has = leaf.GetPointData().HasArray(field)
                sums.append(float(wrapped.PointData[field].sum()) if has else float("nan"))
            print("%s %d %g %d %d %d %.6f %.6f %.6f" % (name, step, time, block, leaf.GetNumberOfPoints(),
                                                        leaf.GetNumberOfCells(), points, sums[0], sums[1]))
    pv.Delete(reader)
