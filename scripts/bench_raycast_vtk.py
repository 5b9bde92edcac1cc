#!/usr/bin/python3
"""VTK's GPU ray caster on the frames lancet-bench-raycast renders, for the side-by-side figure.

Reads what `lancet-bench-raycast --vtk-export DIR` wrote (volume.mhd, setup.json) and renders the
same volume, camera, image size, sample distance, reference step (VTK's scalar opacity unit
distance: its opacity correction) and transfer-function table with vtkGPUVolumeRayCastMapper:
jittered, shaded (ambient 0.3, diffuse 0.7, no specular: our shading), linear interpolation,
automatic sample-distance adjustment off. Prints one JSON object: ms per frame per preset (median
of the frames after one warm-up, each ended by glFinish). Needs an X display (VTK 9.1 in Debian
renders through GLX): scripts/bench-raycast-vs-vtk runs it under xvfb-run.

    bench_raycast_vtk.py DIR [--frames F] [--screenshot PREFIX]
"""

import argparse
import json
import statistics
import sys
import time

import vtk


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dir")
    ap.add_argument("--frames", type=int, default=5)
    ap.add_argument("--screenshot", help="write PREFIX-<preset>.png of each preset's last frame")
    args = ap.parse_args()
    with open(f"{args.dir}/setup.json") as f:
        setup = json.load(f)

    reader = vtk.vtkMetaImageReader()
    reader.SetFileName(f"{args.dir}/volume.mhd")
    reader.Update()
    if reader.GetOutput().GetNumberOfPoints() == 0:
        print(f"bench_raycast_vtk: {args.dir}/volume.mhd: no voxels read", file=sys.stderr)
        return 1

    size = int(setup["image"])
    window = vtk.vtkRenderWindow()
    window.SetOffScreenRendering(1)
    window.SetSize(size, size)
    renderer = vtk.vtkRenderer()
    renderer.SetBackground(0, 0, 0)
    window.AddRenderer(renderer)

    mapper = vtk.vtkGPUVolumeRayCastMapper()
    mapper.SetInputConnection(reader.GetOutputPort())
    mapper.SetAutoAdjustSampleDistances(0)
    mapper.SetSampleDistance(float(setup["sample_distance"]))
    mapper.SetUseJittering(1)
    prop = vtk.vtkVolumeProperty()
    prop.SetInterpolationTypeToLinear()
    prop.SetScalarOpacityUnitDistance(float(setup["reference_step"]))
    prop.SetAmbient(0.3)
    prop.SetDiffuse(0.7)
    prop.SetSpecular(0.0)
    vol = vtk.vtkVolume()
    vol.SetMapper(mapper)
    vol.SetProperty(prop)
    renderer.AddVolume(vol)

    cam = setup["camera"]
    camera = renderer.GetActiveCamera()
    camera.SetPosition(*cam["eye"])
    camera.SetFocalPoint(*cam["centre"])
    camera.SetViewUp(*cam["up"])
    camera.SetViewAngle(float(cam["fov_deg"]))
    camera.SetClippingRange(float(cam["near"]), float(cam["far"]))

    results = []
    for preset in setup["presets"]:
        colour = vtk.vtkColorTransferFunction()
        opacity = vtk.vtkPiecewiseFunction()
        for value, r, g, b, a in preset["points"]:
            colour.AddRGBPoint(value, r, g, b)
            opacity.AddPoint(value, a)
        prop.SetColor(colour)
        prop.SetScalarOpacity(opacity)
        if preset["mip"]:
            mapper.SetBlendModeToMaximumIntensity()
            prop.ShadeOff()
        else:
            mapper.SetBlendModeToComposite()
            prop.ShadeOn()
        times = []
        for frame in range(args.frames + 1):
            t0 = time.perf_counter()
            window.Render()
            window.WaitForCompletion()
            if frame > 0:  # the first uploads the volume and the tables
                times.append(1000.0 * (time.perf_counter() - t0))
        if args.screenshot:
            grab = vtk.vtkWindowToImageFilter()
            grab.SetInput(window)
            grab.ReadFrontBufferOff()
            grab.Update()
            png = vtk.vtkPNGWriter()
            png.SetFileName(f"{args.screenshot}-{preset['name'].split()[0]}.png")
            png.SetInputConnection(grab.GetOutputPort())
            png.Write()
        results.append({"preset": preset["name"], "vtk_ms": round(statistics.median(times), 1)})

    info = window.ReportCapabilities()
    renderer_line = next((l for l in info.splitlines() if "OpenGL renderer string" in l), "").split(":", 1)[-1].strip()
    print(json.dumps({"vtk": vtk.vtkVersion.GetVTKVersion(), "gl": renderer_line, "image": size, "presets": results}, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
