#!/usr/bin/python3
"""Renders an isouq .vtp in ParaView, coloured by a point array (default err_est), headless:

    xvfb-run -a /usr/bin/python3 scripts/paraview_screenshot.py MESH.vtp OUT.png [--array err_est]

(or under pvpython/pvbatch). The colour range is the 2nd to 98th percentile of the finite values,
as `isouq mesh --color-by` uses; docs/vtp-format.md shows the result.
"""
import argparse

import numpy as np
from paraview import simple
from paraview import servermanager
from vtkmodules.util.numpy_support import vtk_to_numpy


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("mesh")
    parser.add_argument("out")
    parser.add_argument("--array", default="err_est")
    parser.add_argument("--size", default="1200,900")
    parser.add_argument("--title", default=None)
    args = parser.parse_args()

    reader = simple.XMLPolyDataReader(FileName=[args.mesh])
    reader.UpdatePipeline()
    values = vtk_to_numpy(servermanager.Fetch(reader).GetPointData().GetArray(args.array))
    finite = values[np.isfinite(values)]
    lo, hi = np.percentile(finite, [2, 98])

    view = simple.CreateView("RenderView")
    width, height = (int(v) for v in args.size.split(","))
    view.ViewSize = [width, height]
    view.UseColorPaletteForBackground = 0
    view.Background = [1, 1, 1]
    view.OrientationAxesVisibility = 0
    display = simple.Show(reader, view)
    simple.ColorBy(display, ("POINTS", args.array))
    lut = simple.GetColorTransferFunction(args.array)
    lut.ApplyPreset("Viridis (matplotlib)", True)
    lut.RescaleTransferFunction(float(lo), float(hi))
    lut.NanColor = [0.5, 0.5, 0.5]
    bar = simple.GetScalarBar(lut, view)
    bar.Title = args.title or f"{args.array} (world units)"
    bar.ComponentTitle = ""
    bar.TitleColor = bar.LabelColor = [0, 0, 0]
    bar.Visibility = 1
    display.SetScalarBarVisibility(view, True)
    simple.ResetCamera(view)
    view.CameraPosition = [2.2, -3.0, 2.0]
    view.CameraFocalPoint = [0.0, 0.0, 0.0]
    view.CameraViewUp = [0, 0, 1]
    simple.ResetCamera(view)
    view.GetActiveCamera().Dolly(1.2)
    simple.SaveScreenshot(args.out, view, ImageResolution=[width, height])


if __name__ == "__main__":
    main()
