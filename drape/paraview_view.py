"""Show a drape results folder in ParaView: the blank warped by its displacement (scale 1),
coloured by the shear angle (deg), the locking angle marked, at the last written load step.

This file runs inside ParaView's own Python (``pvpython`` or ``paraview --script``), not in
drape's environment: it imports nothing from drape. ``drape view`` starts it:

    pvpython --force-offscreen-rendering drape/paraview_view.py RESULTS --screenshot out.png
    paraview --script=<a two-line wrapper setting sys.argv and running this file>

What it draws:

* ``fields.xdmf`` read with ParaView's Xdmf3ReaderS (dolfinx 0.5 writes one temporal grid per
  function on the same mesh; the reader gives one block per function). The blocks are merged
  into one grid carrying every field (a programmable filter copying the arrays onto the first
  block's mesh), then warped by ``displacement`` with scale factor 1.
* Colour: the cell field ``shear_angle_deg`` on a diverging map over [-L, +L], L the locking
  angle; cells past +-L get the above/below-range colours (dark red / dark blue) so that locked
  zones stand out, and the colour bar carries the annotations "+L locking" / "-L locking".
* The lines |shear angle| = L (contours of the shear angle averaged to the nodes), in black.
* A caption: results folder, load factor t, largest |shear angle| and the locking angle.
* ``--ply N`` (a stack of plies): only the cells of ply N (a threshold on the DG0 cell field
  ``ply`` the stack's results carry), its shear map and lines; the caption names the ply.
"""

import argparse
import builtins
import math
import os
import sys

# Importing paraview.simple under pvpython defines vtk's numpy algorithms (max, min, abs, sum)
# in __main__, i.e. in this file's globals: the builtins are called as builtins.max etc.

MERGE_SCRIPT = """
from vtkmodules.vtkCommonDataModel import vtkCompositeDataSet
inp = self.GetInputDataObject(0, 0)
out = self.GetOutputDataObject(0)
blocks = []
if inp.IsA("vtkCompositeDataSet"):
    it = inp.NewIterator()
    it.SkipEmptyNodesOn()
    it.InitTraversal()
    while not it.IsDoneWithTraversal():
        blocks.append(it.GetCurrentDataObject())
        it.GoToNextItem()
else:
    blocks.append(inp)
out.ShallowCopy(blocks[0])
for block in blocks[1:]:
    if block.GetNumberOfPoints() != out.GetNumberOfPoints() or \\
            block.GetNumberOfCells() != out.GetNumberOfCells():
        continue
    for data, into in ((block.GetPointData(), out.GetPointData()),
                       (block.GetCellData(), out.GetCellData())):
        for i in range(data.GetNumberOfArrays()):
            into.AddArray(data.GetArray(i))
"""

DEFAULT_LOCKING_ANGLE = 40.0


def parse(argv):
    parser = argparse.ArgumentParser(prog="paraview_view.py", description=__doc__.split("\n\n")[0])
    parser.add_argument("results", help="a drape results folder (with fields.xdmf)")
    parser.add_argument("--locking-angle", type=float, default=DEFAULT_LOCKING_ANGLE,
                        help="locking angle, deg (default %(default)s)")
    parser.add_argument("--screenshot", default=None, help="write this PNG and exit")
    parser.add_argument("--size", default="1200x900", help="screenshot size in pixels, WxH")
    parser.add_argument("--time", type=float, default=None,
                        help="load factor to show (default: the last written step)")
    parser.add_argument("--ply", type=int, default=None,
                        help="a stack's results: show ply N only (0 the bottom ply)")
    return parser.parse_args(argv)


class NoSuchPly(Exception):
    """--ply names a ply the results do not have (or they are not a stack's)."""


def one_ply(fields, ply):
    """The cells of ply ``ply`` of the merged fields: a threshold on the cell field "ply"."""
    from paraview import simple as pv

    data = pv.servermanager.Fetch(fields)
    plies = data.GetCellData().GetArray("ply")
    if plies is None:
        raise NoSuchPly("these results have no cell field 'ply' (not a stack of plies)")
    top = int(round(plies.GetRange()[1]))
    if not 0 <= ply <= top:
        raise NoSuchPly(f"no ply {ply}: the stack has plies 0 to {top}")
    only = pv.Threshold(registrationName=f"ply {ply}", Input=fields)
    only.Scalars = ["CELLS", "ply"]
    only.LowerThreshold = ply - 0.5
    only.UpperThreshold = ply + 0.5
    only.ThresholdMethod = "Between"
    return only


def merged_fields(reader):
    """One unstructured grid with every field of the XDMF file (all blocks share the mesh)."""
    from paraview.simple import ProgrammableFilter
    merge = ProgrammableFilter(registrationName="fields", Input=reader)
    merge.OutputDataSetType = "vtkUnstructuredGrid"
    merge.Script = MERGE_SCRIPT
    merge.CopyArrays = 0
    return merge


def build(results, locking_angle, time=None, offscreen=False, ply=None):
    """The pipeline and the render view (of ply ``ply`` only if given); returns (view, info
    dict)."""
    from paraview import simple as pv

    reader, times, t = open_fields(results, time, offscreen)
    fields = merged_fields(reader)
    if ply is not None:
        fields.UpdatePipeline(t)
        fields = one_ply(fields, ply)
    fields.UpdatePipeline(t)
    warped = pv.WarpByVector(registrationName="warped by displacement", Input=fields)
    warped.Vectors = ["POINTS", "displacement"]
    warped.ScaleFactor = 1.0
    warped.UpdatePipeline(t)

    view = render_view(t)
    show_shear_map(warped, view, locking_angle)
    show_locking_lines(warped, view, locking_angle)
    low, high, locked, cells = shear_summary(fields, locking_angle)
    largest = builtins.max(builtins.abs(low), builtins.abs(high))
    shown = "" if ply is None else f" ply {ply}"
    caption = (f"{os.path.basename(os.path.abspath(results))}{shown}: t = {t:.4g}, "
               f"largest shear angle magnitude {largest:.2f} deg, "
               f"locking angle {locking_angle:g} deg "
               f"({locked} of {cells} cells past it)")
    show_caption(view, caption)
    place_camera(warped, view)
    pv.SetActiveSource(warped)
    info = {"time": t, "times": times, "shear_range": (low, high), "locked_cells": locked,
            "cells": cells, "caption": caption, "ply": ply}
    return view, info


def open_fields(results, time, offscreen):
    """The reader of RESULTS/fields.xdmf, its load factors and the one to show (the nearest
    to ``time``, default the last)."""
    from paraview import simple as pv

    path = os.path.join(os.path.abspath(results), "fields.xdmf")
    reader = pv.Xdmf3ReaderS(registrationName="fields.xdmf", FileName=[path])
    values = reader.TimestepValues
    if isinstance(values, (int, float)):     # a file of one written step: a number, no list
        values = [values]
    times = [float(v) for v in values] if len(values) else [0.0]
    t = times[-1] if time is None else builtins.min(times,
                                                    key=lambda value: builtins.abs(value - time))
    if offscreen:
        # (in the GUI, under Xvfb at least, these block ParaView 5.11's --script)
        scene = pv.GetAnimationScene()
        scene.UpdateAnimationUsingDataTimeSteps()
        scene.AnimationTime = t
    return reader, times, t


def render_view(t):
    """The render view at load factor t: white background, orientation axes."""
    from paraview import simple as pv

    view = pv.GetActiveViewOrCreate("RenderView")
    view.ViewTime = t
    view.Background = [1.0, 1.0, 1.0]
    try:
        view.UseColorPaletteForBackground = 0
    except AttributeError:
        pass
    view.OrientationAxesVisibility = 1
    return view


def show_shear_map(warped, view, locking_angle):
    """The warped blank coloured by the cell shear angle over [-L, +L], beyond it the
    above/below-range colours, the colour bar annotated at +-L."""
    from paraview import simple as pv

    display = pv.Show(warped, view)
    display.Representation = "Surface With Edges"
    display.EdgeColor = [0.55, 0.55, 0.55]
    pv.ColorBy(display, ("CELLS", "shear_angle_deg"))
    lut = pv.GetColorTransferFunction("shear_angle_deg")
    lut.ApplyPreset("Cool to Warm", True)
    lut.RescaleTransferFunction(-locking_angle, locking_angle)
    lut.AutomaticRescaleRangeMode = "Never"
    lut.UseAboveRangeColor = 1
    lut.AboveRangeColor = [0.45, 0.0, 0.0]
    lut.UseBelowRangeColor = 1
    lut.BelowRangeColor = [0.0, 0.0, 0.4]
    lut.Annotations = [f"{locking_angle:g}", f"+{locking_angle:g} locking",
                       f"{-locking_angle:g}", f"-{locking_angle:g} locking", "0", "0"]
    bar = pv.GetScalarBar(lut, view)
    bar.Title = "shear angle (deg)"
    bar.ComponentTitle = ""
    bar.TitleColor = bar.LabelColor = [0.0, 0.0, 0.0]
    bar.DrawAnnotations = 1
    bar.AddRangeAnnotations = 0
    bar.ScalarBarLength = 0.6
    bar.RangeLabelFormat = "%-#.1f"
    display.SetScalarBarVisibility(view, True)


def show_locking_lines(warped, view, locking_angle):
    """|shear angle| = locking angle: black contour lines of the node-averaged shear angle."""
    from paraview import simple as pv

    nodal = pv.CellDatatoPointData(registrationName="shear angle at nodes", Input=warped)
    contour = pv.Contour(registrationName="locking angle", Input=nodal)
    contour.ContourBy = ["POINTS", "shear_angle_deg"]
    contour.Isosurfaces = [-locking_angle, locking_angle]
    lines = pv.Show(contour, view)
    lines.ColorArrayName = ["POINTS", ""]
    lines.AmbientColor = lines.DiffuseColor = [0.0, 0.0, 0.0]
    lines.LineWidth = 3.0


def shear_summary(fields, locking_angle):
    """The shear angle's range (deg), the number of cells at or past the locking angle and
    the number of cells, from the merged fields."""
    from paraview import simple as pv

    data = pv.servermanager.Fetch(fields)
    shear = data.GetCellData().GetArray("shear_angle_deg")
    low, high = shear.GetRange() if shear is not None else (math.nan, math.nan)
    locked = 0
    if shear is not None:
        locked = builtins.sum(1 for i in range(shear.GetNumberOfTuples())
                              if builtins.abs(shear.GetValue(i)) >= locking_angle)
    return low, high, locked, data.GetNumberOfCells()


def show_caption(view, caption):
    from paraview import simple as pv

    text = pv.Text(registrationName="caption", Text=caption)
    label = pv.Show(text, view)
    label.WindowLocation = "Upper Left Corner"
    label.FontSize = 14
    label.Color = [0.0, 0.0, 0.0]


def place_camera(warped, view):
    """A flat blank seen from above (+z); a formed one obliquely; parallel projection."""
    bounds = warped.GetDataInformation().GetBounds()
    size = builtins.max(bounds[1] - bounds[0], bounds[3] - bounds[2], 1e-12)
    view.CameraParallelProjection = 1
    if bounds[5] - bounds[4] > 1e-3 * size:
        view.CameraPosition = [1.0, -1.5, 1.2]
        view.CameraViewUp = [0.0, 0.0, 1.0]
    else:
        view.CameraPosition = [0.0, 0.0, 1.0]
        view.CameraViewUp = [0.0, 1.0, 0.0]
    view.CameraFocalPoint = [0.0, 0.0, 0.0]
    view.ResetCamera()


def main(argv=None):
    args = parse(sys.argv[1:] if argv is None else argv)
    if not os.path.isfile(os.path.join(args.results, "fields.xdmf")):
        print(f"paraview_view.py: no fields.xdmf in {args.results}", file=sys.stderr)
        return 2
    from paraview import simple as pv
    try:
        view, info = build(args.results, args.locking_angle, args.time,
                           offscreen=bool(args.screenshot), ply=args.ply)
    except NoSuchPly as error:
        print(f"paraview_view.py: {error}", file=sys.stderr)
        return 2
    if args.screenshot:
        width, height = (int(v) for v in args.size.lower().split("x"))
        view.ViewSize = [width, height]
        view.ResetCamera()
        pv.Render(view)
        pv.SaveScreenshot(args.screenshot, view, ImageResolution=[width, height],
                          TransparentBackground=0)
        print(f"paraview_view.py: {info['caption']}; wrote {args.screenshot}")
    else:
        pv.Render(view)
    return 0


if __name__ == "__main__":
    code = main()
    # under `paraview --script` the GUI stays open: do not exit there. After a screenshot, leave
    # without tearing the render window down: with Mesa/GLX under Xvfb the teardown at exit
    # raises an X error (GLXBadContext) that turns a finished job into exit code 1.
    if code or "--screenshot" in sys.argv:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
