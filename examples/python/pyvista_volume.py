"""Optimize a transfer function with t2tf and volume-render with it in PyVista, off screen.

    python examples/python/pyvista_volume.py [VOLUME] [--prompt TEXT] [--out view.png]

Offline by default: the tiny test model in tests/fixtures (its TF means nothing, but every
step runs); pass --model openai/clip-vit-base-patch32 (and no --tokenizer) for real results.
Needs `pip install pyvista`, and a display or `xvfb-run` for VTK's off-screen window.
"""
import argparse
from pathlib import Path

import numpy as np
import pyvista as pv

import t2tf

REPO = Path(__file__).resolve().parents[2]
SHARED = REPO.parent / "shared" / "data"


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("volume", nargs="?", default=SHARED / "volumes" / "neghip_64x64x64_uint8.raw")
    p.add_argument("--prompt", default="a protein molecule")
    p.add_argument("--steps", type=int, default=20)
    p.add_argument("--model", default=REPO / "tests" / "fixtures" / "clip" / "quick_gelu")
    p.add_argument("--tokenizer", default=SHARED / "clip" / "tokenizer.json")
    p.add_argument("--out", default="pyvista_volume.png")
    args = p.parse_args()

    volume = t2tf.read_volume(args.volume)
    result = t2tf.optimize(volume, args.prompt, steps=args.steps, model=args.model,
                           tokenizer=args.tokenizer or None)
    tf = result.transfer_function

    # The volume as VTK image data: to_numpy() is indexed [z, y, x], so its C-order ravel
    # is VTK's point order (x fastest).
    nz, ny, nx = volume.shape
    grid = pv.ImageData(dimensions=(nx, ny, nz), spacing=volume.spacing, origin=volume.origin)
    grid.point_data["values"] = volume.to_numpy().ravel()

    # PyVista takes the TF as a lookup table of RGBA bytes over its range: sample it.
    values, rgba = tf.sample(256)
    lut = pv.LookupTable()
    lut.values = np.round(rgba * 255).astype(np.uint8)
    lut.scalar_range = tf.range
    plotter = pv.Plotter(off_screen=True, window_size=(512, 512))
    actor = plotter.add_volume(grid, scalars="values", cmap=lut, show_scalar_bar=False)
    # t2tf's opacities are per ScalarOpacityUnitDistance, as in ParaView, and it samples
    # trilinearly between points.
    actor.prop.SetScalarOpacityUnitDistance(tf.unit_distance)
    actor.prop.SetInterpolationTypeToLinear()
    plotter.background_color = (0.3, 0.3, 0.3)
    plotter.camera.position = result.camera["position"]
    plotter.camera.focal_point = result.camera["focal_point"]
    plotter.camera.up = result.camera["view_up"]
    plotter.camera.view_angle = result.camera["view_angle"]
    plotter.renderer.reset_camera_clipping_range()  # near and far planes for the new camera
    plotter.screenshot(args.out)
    print("wrote %s (%d steps, TF %s)" % (args.out, result.steps_run, tf.name))


if __name__ == "__main__":
    main()
