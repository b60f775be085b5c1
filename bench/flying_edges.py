#!/usr/bin/python3
"""ParaView's FlyingEdges on a raw scan already in memory (bench/README.md "Loading a dense scan"):
reads name_XxYxZ_uint8.raw whole with numpy, wraps it as vtkImageData without a copy, and
times vtkFlyingEdges3D (ParaView 5.11's VTK, Debian python3-paraview) at the given isovalue
with the given thread counts. Prints one markdown row per thread count: read seconds, contour
median seconds, triangles, SMP backend, load average.

usage: bench/flying_edges.py FILE ISOVALUE [THREADS,...] [REPEATS]"""
import os
import re
import sys
import time

import numpy as np
from vtkmodules.util import numpy_support
from vtkmodules.vtkCommonCore import vtkSMPTools
from vtkmodules.vtkCommonDataModel import vtkImageData
from vtkmodules.vtkFiltersCore import vtkFlyingEdges3D


def main():
    path, isovalue = sys.argv[1], float(sys.argv[2])
    threads = [int(t) for t in (sys.argv[3] if len(sys.argv) > 3 else "0,1").split(",")]
    repeats = int(sys.argv[4]) if len(sys.argv) > 4 else 3
    nx, ny, nz, dtype = re.match(r".*_(\d+)x(\d+)x(\d+)_(\w+)\.raw$", path).groups()
    t0 = time.perf_counter()
    values = np.fromfile(path, dtype=np.dtype(dtype))
    read = time.perf_counter() - t0
    image = vtkImageData()
    image.SetDimensions(int(nx), int(ny), int(nz))
    image.GetPointData().SetScalars(numpy_support.numpy_to_vtk(values, deep=False))
    for n in threads:
        vtkSMPTools.Initialize(n)  # 0: the backend's default (all cores)
        times, triangles = [], 0
        for _ in range(repeats + 1):  # the first is a warm-up
            contour = vtkFlyingEdges3D()
            contour.SetInputData(image)
            contour.SetValue(0, isovalue)
            contour.ComputeNormalsOff()
            contour.ComputeGradientsOff()
            contour.ComputeScalarsOff()
            t0 = time.perf_counter()
            contour.Update()
            times.append(time.perf_counter() - t0)
            triangles = contour.GetOutput().GetNumberOfCells()
            del contour
        times = sorted(times[1:])
        print(f"| FlyingEdges3D | {n or 'default'} ({vtkSMPTools.GetEstimatedNumberOfThreads()}) | {read:.2f} "
              f"| {times[len(times) // 2]:.3f} | {triangles} | {vtkSMPTools.GetBackend()} | {os.getloadavg()[0]:.2f} |",
              flush=True)


if __name__ == "__main__":
    main()
