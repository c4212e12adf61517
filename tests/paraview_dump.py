"""Run by ParaView's pvpython from tests/test_paraview.py (not collected by pytest): open files
with ParaView's readers and dump what ParaView sees to JSON, for the test to compare with drape's
own numbers.

    pvpython paraview_dump.py OUT.json xdmf FILE.xdmf
    pvpython paraview_dump.py OUT.json vtu FILE.vtu
    pvpython paraview_dump.py OUT.json view RESULTS

``view``: the one grid `drape view` draws at the last load factor (drape/paraview_view.py's
reader and merge of the XDMF's blocks): its points and displacement.

For an XDMF file, with each of Xdmf3ReaderS and XDMFReader: the time values, and for every
time and every block (dolfinx 0.5 writes one grid per function) the arrays by name with their
centring (point/cell), and the mesh (points, cells) of the first block.
"""

import builtins
import json
import sys

from paraview import servermanager as sm
from paraview import simple as pv
from vtkmodules.util.numpy_support import vtk_to_numpy


def leaves(data):
    if data.IsA("vtkCompositeDataSet"):
        it = data.NewIterator()
        it.SkipEmptyNodesOn()
        it.InitTraversal()
        while not it.IsDoneWithTraversal():
            yield it.GetCurrentDataObject()
            it.GoToNextItem()
    else:
        yield data


def arrays(grid):
    found = {}
    for centre, data in (("point", grid.GetPointData()), ("cell", grid.GetCellData())):
        for i in range(data.GetNumberOfArrays()):
            found[data.GetArrayName(i)] = (centre, vtk_to_numpy(data.GetArray(i)).tolist())
    return found


def mesh(grid):
    points = vtk_to_numpy(grid.GetPoints().GetData()).tolist()
    cells = []
    for c in range(grid.GetNumberOfCells()):
        ids = grid.GetCell(c).GetPointIds()
        cells.append([ids.GetId(k) for k in range(ids.GetNumberOfIds())])
    return {"points": points, "cells": cells,
            "cell_types": [grid.GetCellType(c) for c in range(grid.GetNumberOfCells())]}


def dump_xdmf(path):
    out = {}
    for name in ("Xdmf3ReaderS", "XDMFReader"):
        if name == "XDMFReader":
            reader = pv.XDMFReader(FileNames=[path])
        else:
            reader = pv.Xdmf3ReaderS(FileName=[path])
        times = [float(t) for t in reader.TimestepValues]
        steps = []
        for t in times:
            reader.UpdatePipeline(t)
            data = sm.Fetch(reader)
            blocks = [g for g in leaves(data) if g.GetNumberOfCells() > 0]
            fields = {}
            for grid in blocks:
                fields.update(arrays(grid))
            steps.append({"t": t, "blocks": len(blocks), "fields": fields})
        out[name] = {"times": times, "steps": steps, "mesh": mesh(blocks[0])}
        pv.Delete(reader)
    return out


def dump_vtu(path):
    reader = pv.XMLUnstructuredGridReader(FileName=[path])
    reader.UpdatePipeline()
    grid = next(leaves(sm.Fetch(reader)))
    return {"mesh": mesh(grid), "fields": arrays(grid)}


def dump_view(results):
    import os
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "drape"))
    import paraview_view
    reader, _, t = paraview_view.open_fields(results, None, True)
    merged = paraview_view.merged_fields(reader)
    merged.UpdatePipeline(t)
    grid = sm.Fetch(merged)
    return {"t": t, "points": vtk_to_numpy(grid.GetPoints().GetData()).tolist(),
            "displacement": vtk_to_numpy(grid.GetPointData().GetArray("displacement")).tolist()}


if __name__ == "__main__":
    target, kind, path = sys.argv[1:4]
    result = {"xdmf": dump_xdmf, "vtu": dump_vtu, "view": dump_view}[kind](path)
    with builtins.open(target, "w") as stream:
        json.dump(result, stream)
