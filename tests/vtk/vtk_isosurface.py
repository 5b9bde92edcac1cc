#!/usr/bin/python3
"""Reference isosurface extraction with VTK, for cross-checking and benchmarking
Lancet's marching cubes.

Usage (Debian's python, which has python3-vtk9; the pyenv python3 on PATH has no VTK):

  /usr/bin/python3 tests/vtk/vtk_isosurface.py VOLUME.mhd --iso VALUE
      [--pad VALUE] [--threads N] [--repeat R] [--normals on|off]

Reads a MetaImage (.mhd/.mha), casts the scalars to float32 (and optionally pads
the volume by one voxel of VALUE on every side, so the grid grows to
(nx+2, ny+2, nz+2) with its first sample at origin - spacing), then runs
vtkMarchingCubes and vtkFlyingEdges3D with the same isovalue.

Filter settings for both: ComputeNormals = --normals (on by default),
ComputeGradients off, ComputeScalars off, one contour value.
Only filter Update() is timed (Modified(); Update(); best of --repeat).

--threads: 0 = VTK's default SMP backend and thread count;
           1 = SMP backend "Sequential" (strictly single-threaded);
           N > 1 = default backend, vtkSMPTools.Initialize(N).
vtkMarchingCubes is serial in VTK 9.1 regardless; vtkFlyingEdges3D uses vtkSMPTools.

Prints one JSON object on stdout. Lengths/areas/volumes are in the units of the
.mhd ElementSpacing (mm for the Lancet test volumes): area in unit^2, volume in
unit^3. vtkMetaImageReader applies the .mhd Offset as the image origin but ignores
TransformMatrix (direction), so the chest volume's flips are not applied; areas,
volumes (relative to the first sample) and counts do not depend on either.
"origin" is the unpadded grid's first sample; "grid_first_sample" is the padded one.

Per filter output:
  triangles, points          cell / point counts of the output vtkPolyData
  area                       sum of per-triangle areas (vtkCellSizeFilter, double),
                             summed with math.fsum
  volume                     signed divergence-theorem volume sum(p0.(p1 x p2))/6,
                             coordinates relative to "origin"; the enclosed volume
                             when the surface is closed, origin-dependent otherwise
  volume_vtkmassproperties   vtkMassProperties volume (valid for closed surfaces only)
  edges                      distinct edges (pairs of distinct point ids)
  boundary_edges             edges used by exactly one triangle (0 = closed surface)
  nonmanifold_edges          edges used by more than two triangles
                             (counted in Python: vtkFeatureEdges in VTK 9.1 makes an
                             O(points^2) allocation and aborts on ~1.5M-point meshes)
  degenerate                 triangles whose area is exactly 0 in double precision
                             (coincident vertices; vtkFlyingEdges3D emits them when
                             grid values equal the isovalue; vtkMarchingCubes merges
                             points and drops triangles with repeated ids instead)
  has_normals                whether point normals are present
  seconds, voxels_per_second best Update() wall time; grid voxels (padded) / seconds

Errors (missing/unreadable file, bad arguments) -> message on stderr, exit 2.
"""

import argparse
import json
import math
import os
import sys
import tempfile
import time
from collections import Counter

try:
    from vtkmodules.vtkCommonCore import (
        vtkCommand,
        vtkOutputWindow,
        vtkSMPTools,
        vtkVersion,
    )
    from vtkmodules.vtkCommonDataModel import vtkImageData
    from vtkmodules.vtkFiltersCore import (
        vtkFlyingEdges3D,
        vtkMarchingCubes,
        vtkMassProperties,
    )
    from vtkmodules.vtkFiltersVerdict import vtkCellSizeFilter
    from vtkmodules.vtkImagingCore import vtkImageCast, vtkImageConstantPad
    from vtkmodules.vtkIOImage import vtkMetaImageReader
except ImportError as exc:  # pragma: no cover
    sys.stderr.write(
        "error: cannot import VTK (%s); install python3-vtk9 and run with /usr/bin/python3\n" % exc
    )
    sys.exit(2)


def fail(msg):
    sys.stderr.write("error: %s\n" % msg)
    sys.exit(2)


class ErrorObserver:
    """Collects VTK ErrorEvents instead of letting them only go to the output window."""

    def __init__(self):
        self.messages = []

    def __call__(self, obj, event, calldata=None):
        self.messages.append("%s: %s" % (obj.GetClassName(), event))

    def attach(self, algo):
        algo.AddObserver(vtkCommand.ErrorEvent, self)
        return algo


def parse_args(argv):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("volume", help="MetaImage .mhd/.mha file")
    p.add_argument("--iso", type=float, required=True, help="isovalue")
    p.add_argument("--pad", type=float, default=None,
                   help="pad one voxel of this value on every side (default: no padding)")
    p.add_argument("--threads", type=int, default=0,
                   help="0 = VTK default, 1 = Sequential backend, N = Initialize(N)")
    p.add_argument("--repeat", type=int, default=3, help="timed repeats, best is reported")
    p.add_argument("--normals", choices=("on", "off"), default="on")
    p.add_argument("--same-job", action="store_true",
                   help="also time VTK doing Lancet's whole first-surface job (see same_job())")
    p.add_argument("--quick", action="store_true",
                   help="counts, area and timing only (skip volume and edge topology, slow in Python)")
    a = p.parse_args(argv)
    if a.repeat < 1:
        fail("--repeat must be >= 1")
    if a.threads < 0:
        fail("--threads must be >= 0")
    if not math.isfinite(a.iso):
        fail("--iso must be finite")
    return a


def setup_smp(threads):
    if threads == 1:
        if not vtkSMPTools.SetBackend("Sequential"):
            fail("VTK SMP backend 'Sequential' not available")
        vtkSMPTools.Initialize(1)
    elif threads > 1:
        vtkSMPTools.Initialize(threads)
    else:
        vtkSMPTools.Initialize()
    return vtkSMPTools.GetBackend(), vtkSMPTools.GetEstimatedNumberOfThreads()


def load_volume(path, pad):
    if not os.path.isfile(path):
        fail("no such file: %s" % path)
    reader = vtkMetaImageReader()
    if not reader.CanReadFile(path):
        fail("not a readable MetaImage file: %s" % path)
    errs = ErrorObserver()
    errs.attach(reader)
    reader.SetFileName(path)
    # MetaIO reports short/missing data files only on std::cerr (no VTK error event),
    # so capture file descriptor 2 while reading, echo it, and look for its complaints.
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as tmp:
        os.dup2(tmp.fileno(), 2)
        try:
            reader.Update()
        finally:
            os.dup2(saved, 2)
            os.close(saved)
        tmp.seek(0)
        metaio_msgs = tmp.read().decode("utf-8", "replace")
    if metaio_msgs:
        sys.stderr.write(metaio_msgs)
    if "MetaImage:" in metaio_msgs or "MetaObject:" in metaio_msgs:
        fail("MetaImage reader reported a problem with %s" % path)
    raw = reader.GetOutput()
    dims = list(raw.GetDimensions())
    if errs.messages or raw.GetNumberOfPoints() == 0 or raw.GetPointData().GetScalars() is None:
        fail("could not read volume data from %s" % path)
    if raw.GetPointData().GetScalars().GetNumberOfComponents() != 1:
        fail("expected a single-component volume: %s" % path)

    cast = errs.attach(vtkImageCast())
    cast.SetInputData(raw)
    cast.SetOutputScalarTypeToFloat()
    cast.ClampOverflowOff()
    last = cast
    if pad is not None:
        padf = errs.attach(vtkImageConstantPad())
        padf.SetInputConnection(cast.GetOutputPort())
        e = raw.GetExtent()
        padf.SetOutputWholeExtent(e[0] - 1, e[1] + 1, e[2] - 1, e[3] + 1, e[4] - 1, e[5] + 1)
        padf.SetConstant(pad)
        last = padf
    last.Update()
    if errs.messages:
        fail("VTK error while preparing volume: %s" % "; ".join(errs.messages))
    # Detach from the pipeline so the timed filters never re-execute the reader/cast/pad.
    img = vtkImageData()
    img.DeepCopy(last.GetOutput())
    scalar_range = raw.GetPointData().GetScalars().GetRange()
    return img, dims, raw, scalar_range


def _typed(arr):
    """Zero-copy 1-D memoryview of a VTK data array (buffer protocol)."""
    codes = {"float": "f", "double": "d", "long long": "q", "long": "l", "int": "i",
             "vtkTypeInt64": "q", "vtkTypeInt32": "i", "idtype": "q"}
    code = codes.get(arr.GetDataTypeAsString())
    if code is None:
        fail("unexpected VTK array type %s" % arr.GetDataTypeAsString())
    mv = memoryview(arr).cast("B").cast(code)
    if mv.itemsize != arr.GetDataTypeSize():
        fail("array item size mismatch for %s" % arr.GetDataTypeAsString())
    return mv


def mesh_stats(poly, ref, full=True):
    """Counts, area, volume, edge topology of a triangle-only vtkPolyData.

    ref: reference point for the signed (divergence-theorem) volume; the volume of a
    closed surface does not depend on it.
    """
    ntri = poly.GetNumberOfCells()
    out = {
        "triangles": ntri,
        "points": poly.GetNumberOfPoints(),
        "area": 0.0,
        "volume": 0.0,
        "volume_vtkmassproperties": 0.0,
        "boundary_edges": 0,
        "nonmanifold_edges": 0,
        "degenerate": 0,
    }
    if ntri == 0:
        return out
    polys = poly.GetPolys()
    if polys.GetNumberOfCells() != ntri or polys.GetMaxCellSize() != 3 or \
            polys.GetNumberOfConnectivityIds() != 3 * ntri:
        fail("filter output is not a triangle-only mesh")

    # Per-triangle area in double (vtkTriangle::TriangleArea), summed with math.fsum.
    sizes = vtkCellSizeFilter()
    sizes.SetInputData(poly)
    sizes.ComputeVertexCountOff()
    sizes.ComputeLengthOff()
    sizes.ComputeAreaOn()
    sizes.ComputeVolumeOff()
    sizes.ComputeSumOff()
    sizes.SetAreaArrayName("Area")
    sizes.Update()
    areas = sizes.GetOutput().GetCellData().GetArray("Area")
    amv = _typed(areas)
    out["area"] = math.fsum(amv)
    out["degenerate"] = sum(1 for a in amv if a == 0.0) if areas.GetRange()[0] <= 0.0 else 0
    if not full:
        return out

    # Valid for closed triangle meshes only (its open-surface value depends on a
    # normal-weighting that counts degenerate triangles).
    mp = vtkMassProperties()
    mp.SetInputData(poly)
    mp.Update()
    out["volume_vtkmassproperties"] = mp.GetVolume()

    conn = _typed(polys.GetConnectivityArray())
    a, b, c = conn[0::3], conn[1::3], conn[2::3]

    # Signed volume sum_t (p0 . (p1 x p2)) / 6 with coordinates relative to ref.
    pts = _typed(poly.GetPoints().GetData())
    rx, ry, rz = ref
    X = [v - rx for v in pts[0::3]]
    Y = [v - ry for v in pts[1::3]]
    Z = [v - rz for v in pts[2::3]]

    def det(i, j, k):
        x0 = X[i]; y0 = Y[i]; z0 = Z[i]
        x1 = X[j]; y1 = Y[j]; z1 = Z[j]
        x2 = X[k]; y2 = Y[k]; z2 = Z[k]
        return x0 * (y1 * z2 - z1 * y2) - y0 * (x1 * z2 - z1 * x2) + z0 * (x1 * y2 - y1 * x2)

    out["volume"] = math.fsum(map(det, a, b, c)) / 6.0

    # Edge use counts (vtkFeatureEdges in VTK 9.1 tries to allocate O(points^2)
    # memory on large meshes, so count in Python). Edges with equal end ids skipped.
    P = poly.GetNumberOfPoints()

    def key(i, j):
        return i * P + j if i < j else (j * P + i if j < i else -1)

    uses = Counter(map(key, a, b))
    uses.update(map(key, b, c))
    uses.update(map(key, c, a))
    uses.pop(-1, None)
    hist = Counter(uses.values())
    out["edges"] = len(uses)
    out["boundary_edges"] = hist.get(1, 0)
    out["nonmanifold_edges"] = sum(n for k, n in hist.items() if k > 2)
    return out


def contour_filter(cls, img, iso, normals):
    """A vtkMarchingCubes / vtkFlyingEdges3D set up as every run here uses it."""
    f = cls()
    f.SetInputData(img)
    f.SetNumberOfContours(1)
    f.SetValue(0, iso)
    f.SetComputeNormals(normals)
    f.SetComputeGradients(False)
    f.SetComputeScalars(False)
    return f


def run_filter(cls, img, iso, normals, repeat, voxels, ref, full):
    f = contour_filter(cls, img, iso, normals)
    best = float("inf")
    for _ in range(repeat):
        f.Modified()
        t0 = time.perf_counter()
        f.Update()
        best = min(best, time.perf_counter() - t0)
    res = mesh_stats(f.GetOutput(), ref, full)
    res["has_normals"] = f.GetOutput().GetPointData().GetNormals() is not None
    res["seconds"] = best
    res["voxels_per_second"] = voxels / best if best > 0 else None
    return res


def same_job(path, iso, repeat):
    """What Lancet does from a CT file to a cuttable skin, done the VTK way: read the file
    (vtkMetaImageReader), extract with normals (vtkFlyingEdges3D), build the point-to-cell links
    that answer "which triangles share this vertex" (vtkPolyData.BuildLinks, the connectivity a
    cut walks), and build a search structure for closest-point and segment queries
    (vtkStaticCellLocator.BuildLocator). Each stage is timed on its own (best of repeat, every
    repeat starting from a fresh object), and the total is the sum of the bests."""
    from vtkmodules.vtkCommonDataModel import vtkPolyData, vtkStaticCellLocator

    def best(fn):
        t = float("inf")
        out = None
        for _ in range(repeat):
            t0 = time.perf_counter()
            made = fn()
            t = min(t, time.perf_counter() - t0)
            out = made  # the last one freed here, outside the timer (as the C++ side times it)
        return t, out

    def read():
        r = vtkMetaImageReader()
        r.SetFileName(path)
        r.Update()
        return r.GetOutput()

    t_read, img = best(read)

    def extract():
        f = contour_filter(vtkFlyingEdges3D, img, iso, True)
        f.Update()
        return f.GetOutput()

    t_extract, poly = best(extract)

    def links():
        p = vtkPolyData()
        p.ShallowCopy(poly)
        p.BuildLinks()
        return p

    t_links, _ = best(links)

    def locator():
        loc = vtkStaticCellLocator()
        loc.SetDataSet(poly)
        loc.BuildLocator()
        return loc

    t_locator, _ = best(locator)
    return {"read_s": t_read, "flying_edges_normals_s": t_extract, "build_links_s": t_links,
            "static_cell_locator_s": t_locator, "triangles": poly.GetNumberOfCells(),
            "seconds": t_read + t_extract + t_links + t_locator}


def main(argv):
    a = parse_args(argv)
    # Keep VTK warnings/errors off stdout (it must hold only the JSON object).
    vtkOutputWindow.GetInstance().SetDisplayModeToAlwaysStdErr()

    backend, nthreads = setup_smp(a.threads)
    img, dims, raw, srange = load_volume(a.volume, a.pad)
    voxels = img.GetNumberOfPoints()
    normals = a.normals == "on"
    ref = raw.GetOrigin()  # first sample of the unpadded grid

    result = {
        "file": a.volume,
        "dims": dims,
        "grid_dims": list(img.GetDimensions()),
        "spacing": list(raw.GetSpacing()),
        "origin": list(raw.GetOrigin()),
        "grid_first_sample": [o + e * d for o, e, d in
                              zip(img.GetOrigin(), img.GetExtent()[0::2], img.GetSpacing())],
        "units": "ElementSpacing units (mm); area unit^2, volume unit^3",
        "scalar_range": list(srange),
        "iso": a.iso,
        "pad": a.pad,
        "threads": a.threads,
        "normals": normals,
        "vtk_version": vtkVersion.GetVTKVersion(),
        "smp_backend": backend,
        "smp_threads": nthreads,
        "voxels": voxels,
        "marching_cubes": run_filter(vtkMarchingCubes, img, a.iso, normals, a.repeat, voxels, ref, not a.quick),
        "flying_edges": run_filter(vtkFlyingEdges3D, img, a.iso, normals, a.repeat, voxels, ref, not a.quick),
    }
    if a.same_job:
        result["same_job"] = same_job(a.volume, a.iso, a.repeat)
    json.dump(result, sys.stdout)
    sys.stdout.write("\n")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
