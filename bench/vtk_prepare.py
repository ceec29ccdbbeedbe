#!/usr/bin/python3
"""Inputs of bench/vtk_compare.sh, from the demo OME-TIFF (uncompressed, one channel, uint16).

Writes into OUT_DIR: volume.raw (little-endian uint16, x fastest, y = TIFF row, z = page: the
voxel order Octoscope reads), camera.json (Octoscope's standard iso perspective view of the
volume's box (--spacing: µm per voxel) as a look-at camera, camera.cpp's formula: eye at the box centre minus
(1,1,1)/sqrt(3) * radius / sin(fov/2)), params_mip.json and params_dvr.json (one grey channel,
window from the 60th to the 99.9th percentile of the voxels, DVR opacity_scale 0.3, step 1), and
prints the dimensions and window as JSON. Also `--compare A.png B.png`: PSNR / max difference of
two Octoscope PNGs (composited over black).
"""
import argparse
import json
import math
import os

import numpy as np
import vtk
from vtkmodules.util import numpy_support

from vtk_compare import error, read_png_rgb


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--tiff")
    p.add_argument("--out-dir")
    p.add_argument("--fov", type=float, default=30.0)
    p.add_argument("--spacing", type=float, nargs=3, default=[1.0, 1.0, 1.0], help="µm per voxel")
    p.add_argument("--compare", nargs=2)
    args = p.parse_args()
    if args.compare:
        a = read_png_rgb(args.compare[0], premultiply_alpha=True)
        b = read_png_rgb(args.compare[1], premultiply_alpha=True)
        psnr, max_diff = error(a, b)
        print(json.dumps({"psnr_db": psnr, "max_diff": max_diff}))
        return
    reader = vtk.vtkTIFFReader()
    reader.SetFileName(args.tiff)
    reader.FileLowerLeftOn()  # Keep the file's row order: row r is y = r.
    reader.Update()
    img = reader.GetOutput()
    nx, ny, nz = img.GetDimensions()
    voxels = numpy_support.vtk_to_numpy(img.GetPointData().GetScalars())
    if voxels.dtype != np.uint16 or voxels.size != nx * ny * nz:
        raise SystemExit(f"{args.tiff}: expected one uint16 channel, got {voxels.dtype}")
    os.makedirs(args.out_dir, exist_ok=True)
    voxels.astype("<u2").tofile(os.path.join(args.out_dir, "volume.raw"))
    lo, hi = (float(v) for v in np.percentile(voxels, [60, 99.9]))
    hi = max(hi, lo + 1)

    # Camera::Standard(kIso, perspective): forward (1,1,1)/sqrt(3), up (0,-1,0), the bounding
    # sphere fitted into the fov.
    extent = np.array([nx, ny, nz], dtype=np.float64) * np.array(args.spacing)
    centre = extent / 2
    radius = float(np.linalg.norm(extent)) / 2
    distance = radius / math.sin(math.radians(args.fov) / 2)
    forward = np.ones(3) / math.sqrt(3)
    eye = centre - forward * distance
    camera = {"projection": "perspective", "position": eye.tolist(), "target": centre.tolist(),
              "up": [0, -1, 0], "fov_y_degrees": args.fov}
    with open(os.path.join(args.out_dir, "camera.json"), "w") as f:
        json.dump(camera, f)
    channel = {"color": [1, 1, 1], "window": hi - lo, "level": (lo + hi) / 2}
    for mode, opacity in (("mip", 1.0), ("dvr", 0.3)):
        params = {"mode": mode, "step_voxels": 1,
                  "channels": [dict(channel, opacity_scale=opacity)]}
        with open(os.path.join(args.out_dir, f"params_{mode}.json"), "w") as f:
            json.dump(params, f)
    print(json.dumps({"dims": [nx, ny, nz], "window": [lo, hi], "dvr_opacity": 0.3}))


if __name__ == "__main__":
    main()
