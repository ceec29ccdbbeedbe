#!/usr/bin/python3
"""VTK's volume ray casters on the view Octoscope renders (bench/vtk_compare.sh runs this).

Loads a raw little-endian uint16 volume (x fastest) with numpy + vtkImageImport, renders one view
with vtkFixedPointVolumeRayCastMapper ("fixed", CPU) or vtkGPUVolumeRayCastMapper ("gpu", OpenGL;
Mesa llvmpipe under Xvfb here), and prints one JSON line: time to the first image (from opening
the file, the whole volume read first), the median time of the following frames, and PSNR / max
difference (8-bit RGB) against a reference PNG (Octoscope's CPU reference of the same view).

Camera and transfer function match Octoscope's definitions (docs/benchmarks.md, "Side by side with
VTK"): the look-at camera of the camera JSON (position, target, up, vertical fov); voxel i's
centre at (i + 0.5) * spacing (VTK: origin 0.5 * spacing); trilinear interpolation; a sample
distance of `step` voxels (Octoscope steps in voxel space: with anisotropic voxels VTK's world
distance is that of `step` voxels along the view's forward direction); MIP: grey ramp over the
window, opacity 1; DVR: colour and opacity ramps over the window (opacity up to opacity_scale per
smallest spacing, VTK's scalar opacity unit distance = Octoscope's opacity correction reference),
front to back over black.
"""
import argparse
import json
import math
import time

import numpy as np
import vtk
from vtkmodules.util import numpy_support


def read_png_rgb(path, premultiply_alpha):
    reader = vtk.vtkPNGReader()
    reader.SetFileName(path)
    reader.Update()
    img = reader.GetOutput()
    w, h, _ = img.GetDimensions()
    comps = img.GetPointData().GetScalars().GetNumberOfComponents()
    a = numpy_support.vtk_to_numpy(img.GetPointData().GetScalars()).reshape(h, w, comps)
    a = a.astype(np.float64)  # Row 0 is the bottom (VTK's order), as in the grabbed window.
    rgb = a[:, :, :3]
    if comps == 4 and premultiply_alpha:
        # Octoscope's PNG is straight alpha: composite over black like VTK's image.
        rgb = rgb * a[:, :, 3:4] / 255.0
    return np.clip(np.rint(rgb), 0, 255)


def error(image, reference):
    diff = image - reference
    mse = float(np.mean(diff * diff))
    psnr = float("inf") if mse == 0 else 10 * math.log10(255.0 ** 2 / mse)
    return psnr, float(np.max(np.abs(diff)))


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--raw", required=True)
    p.add_argument("--dims", type=int, nargs=3, required=True)
    p.add_argument("--camera", required=True, help="Octoscope look-at camera JSON")
    p.add_argument("--mode", choices=["mip", "dvr"], required=True)
    p.add_argument("--window", type=float, nargs=2, required=True, help="stored lo hi")
    p.add_argument("--opacity", type=float, default=1.0, help="DVR opacity_scale")
    p.add_argument("--step", type=float, default=1.0)
    p.add_argument("--spacing", type=float, nargs=3, default=[1.0, 1.0, 1.0], help="µm per voxel")
    p.add_argument("--size", type=int, default=1024)
    p.add_argument("--mapper", choices=["fixed", "gpu"], required=True)
    p.add_argument("--frames", type=int, default=3)
    p.add_argument("--reference")
    p.add_argument("--out")
    args = p.parse_args()
    with open(args.camera) as f:
        cam = json.load(f)
    nx, ny, nz = args.dims
    lo, hi = args.window

    # Window and renderer first (not part of "opening the file").
    window = vtk.vtkRenderWindow()
    window.SetOffScreenRendering(1)
    window.SetSize(args.size, args.size)
    renderer = vtk.vtkRenderer()
    renderer.SetBackground(0, 0, 0)
    window.AddRenderer(renderer)

    start = time.perf_counter()
    start_cpu = time.process_time()  # All threads of the process (a shared machine's fair clock).
    # 1. Open the file: VTK needs the whole volume in memory.
    voxels = np.fromfile(args.raw, dtype="<u2", count=nx * ny * nz)
    if voxels.size != nx * ny * nz:
        raise SystemExit(f"{args.raw}: {voxels.size} voxels, expected {nx * ny * nz}")
    importer = vtk.vtkImageImport()
    importer.CopyImportVoidPointer(voxels, voxels.nbytes)
    importer.SetDataScalarTypeToUnsignedShort()
    importer.SetNumberOfScalarComponents(1)
    importer.SetWholeExtent(0, nx - 1, 0, ny - 1, 0, nz - 1)
    importer.SetDataExtentToWholeExtent()
    spacing = np.array(args.spacing, dtype=np.float64)
    importer.SetDataSpacing(*spacing)
    importer.SetDataOrigin(*(0.5 * spacing))  # Voxel i's centre at (i + 0.5) * spacing.
    importer.Update()
    loaded = time.perf_counter()

    # 2. Transfer functions equivalent to Octoscope's linear windowed ramp.
    color = vtk.vtkColorTransferFunction()
    color.AddRGBPoint(lo, 0, 0, 0)
    color.AddRGBPoint(hi, 1, 1, 1)
    opacity = vtk.vtkPiecewiseFunction()
    if args.mode == "mip":
        opacity.AddPoint(0, 1)
        opacity.AddPoint(65535, 1)
    else:
        opacity.AddPoint(lo, 0)
        if args.opacity <= 1:
            opacity.AddPoint(hi, args.opacity)
        else:  # Reaches 1 inside the window and stays there.
            opacity.AddPoint(lo + (hi - lo) / args.opacity, 1)
            opacity.AddPoint(hi, 1)
    prop = vtk.vtkVolumeProperty()
    prop.SetColor(color)
    prop.SetScalarOpacity(opacity)
    prop.SetScalarOpacityUnitDistance(float(spacing.min()))
    prop.SetInterpolationTypeToLinear()
    prop.ShadeOff()

    if args.mapper == "fixed":
        mapper = vtk.vtkFixedPointVolumeRayCastMapper()
        mapper.SetImageSampleDistance(1.0)
        mapper.SetMinimumImageSampleDistance(1.0)
        mapper.SetMaximumImageSampleDistance(1.0)
    else:
        mapper = vtk.vtkGPUVolumeRayCastMapper()
    mapper.SetAutoAdjustSampleDistances(0)
    # One voxel of arc in voxel space along the view's forward direction, in µm.
    forward = np.array(cam["target"], dtype=np.float64) - np.array(cam["position"], dtype=np.float64)
    forward /= np.linalg.norm(forward)
    voxel_step_um = 1.0 / np.linalg.norm(forward / spacing)
    mapper.SetSampleDistance(args.step * voxel_step_um)
    mapper.SetInputConnection(importer.GetOutputPort())
    if args.mode == "mip":
        mapper.SetBlendModeToMaximumIntensity()
    else:
        mapper.SetBlendModeToComposite()
    volume = vtk.vtkVolume()
    volume.SetMapper(mapper)
    volume.SetProperty(prop)
    renderer.AddVolume(volume)

    # 3. The camera: Octoscope's look-at camera (position, target, up, vertical fov).
    camera = renderer.GetActiveCamera()
    camera.SetPosition(*cam["position"])
    camera.SetFocalPoint(*cam["target"])
    camera.SetViewUp(*cam.get("up", [0, -1, 0]))
    camera.SetViewAngle(cam.get("fov_y_degrees", 30))
    camera.OrthogonalizeViewUp()
    renderer.ResetCameraClippingRange()

    window.Render()
    first = time.perf_counter()
    first_cpu = time.process_time() - start_cpu
    frames = []
    cpu_frames = []
    for _ in range(args.frames):
        camera.Modified()
        volume.Modified()
        t = time.perf_counter()
        c = time.process_time()
        window.Render()
        frames.append(time.perf_counter() - t)
        cpu_frames.append(time.process_time() - c)

    grab = vtk.vtkWindowToImageFilter()
    grab.SetInput(window)
    grab.SetInputBufferTypeToRGB()
    grab.ReadFrontBufferOff()
    grab.Update()
    if args.out:
        writer = vtk.vtkPNGWriter()
        writer.SetFileName(args.out)
        writer.SetInputConnection(grab.GetOutputPort())
        writer.Write()
    out = grab.GetOutput()
    w, h, _ = out.GetDimensions()
    rgb = numpy_support.vtk_to_numpy(out.GetPointData().GetScalars()).reshape(h, w, 3)
    rgb = rgb.astype(np.float64)
    result = {
        "mapper": args.mapper,
        "mode": args.mode,
        "size": args.size,
        "ms_load": 1e3 * (loaded - start),
        "ms_first_image": 1e3 * (first - start),
        "ms_frame_median": 1e3 * sorted(frames)[len(frames) // 2] if frames else None,
        "cpu_ms_first_image": 1e3 * first_cpu,
        "cpu_ms_frame_median": 1e3 * sorted(cpu_frames)[len(cpu_frames) // 2] if frames else None,
        "opengl": window.ReportCapabilities().splitlines()[1:3] if args.mapper == "gpu" else None,
    }
    if args.reference:
        ref = read_png_rgb(args.reference, premultiply_alpha=True)
        result["psnr_db"], result["max_diff"] = error(rgb, ref)
    print(json.dumps(result))


if __name__ == "__main__":
    main()
