"""Render a view of an `i2sdf export` scene with Blender's Cycles, headless.

    blender -b --factory-startup --python scripts/blender_render.py -- \
        --scene room.glb --camera test_000 --out view.png [--width 160 --height 120] \
        [--spp 256] [--bounces 8]

The glTF importer brings the file into Blender (glTF's +Y up becomes Blender's +Z up), the named
camera (`SPLIT_NAME` of the dataset's frames, as `i2sdf export` writes them) becomes the scene
camera, and Cycles path traces it with no world light (the room is lit by its emitters alone, as
`i2sdf edit` renders it). The PNG is Blender's "Standard" view transform at exposure 0: the sRGB of
the linear render, the same encoding as the dataset's LDR images, whose linear units the exported
emission is in. `--exr` also writes the linear render.

Only for cross-checking exports (it is not used by i2sdf itself).
"""

import argparse
import sys

import bpy
import numpy as np

# Debian's Blender 3.4 importer still uses `np.bool`, which NumPy 1.24 (Debian 12's) removed.
if not hasattr(np, "bool"):
    np.bool = bool


def main(argv):
    p = argparse.ArgumentParser(prog="blender_render.py")
    p.add_argument("--scene", required=True, help=".glb or .gltf written by i2sdf export")
    p.add_argument("--camera", required=True, help="camera node name, e.g. test_000")
    p.add_argument("--out", required=True, help="output PNG")
    p.add_argument("--exr", help="also write the linear render here")
    p.add_argument("--width", type=int, default=160)
    p.add_argument("--height", type=int, default=120)
    p.add_argument("--spp", type=int, default=256)
    p.add_argument("--bounces", type=int, default=8)
    a = p.parse_args(argv)

    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.import_scene.gltf(filepath=a.scene)
    scene = bpy.context.scene
    cams = [o for o in scene.objects if o.type == "CAMERA" and o.name == a.camera]
    if not cams:
        names = sorted(o.name for o in scene.objects if o.type == "CAMERA")
        sys.exit(f"no camera named {a.camera} in {a.scene}; cameras: {', '.join(names[:8])}…")
    scene.camera = cams[0]
    # the importer fits the sensor to the aspect ratio it read; the render size must match it
    r = scene.render
    r.engine = "CYCLES"
    r.resolution_x, r.resolution_y, r.resolution_percentage = a.width, a.height, 100
    r.film_transparent = False
    scene.cycles.device = "CPU"
    scene.cycles.samples = a.spp
    scene.cycles.use_denoising = False
    scene.cycles.max_bounces = a.bounces
    scene.cycles.diffuse_bounces = a.bounces
    scene.cycles.glossy_bounces = a.bounces
    scene.cycles.seed = 0
    # no world light: the room's emitters light it
    world = bpy.data.worlds.new("black")
    world.use_nodes = True
    world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.0
    scene.world = world
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.view_settings.exposure = 0.0
    scene.view_settings.gamma = 1.0
    scene.sequencer_colorspace_settings.name = "sRGB"
    if a.exr:
        r.image_settings.file_format = "OPEN_EXR"
        r.image_settings.color_depth = "32"
        r.filepath = a.exr
        bpy.ops.render.render(write_still=True)
    r.image_settings.file_format = "PNG"
    r.image_settings.color_mode = "RGB"
    r.image_settings.color_depth = "8"
    r.filepath = a.out
    bpy.ops.render.render(write_still=True)


if __name__ == "__main__":
    main(sys.argv[sys.argv.index("--") + 1 :] if "--" in sys.argv else [])
