"""Render a view of an `i2sdf export` scene with Blender's Cycles, headless.

    blender -b --factory-startup --python scripts/blender_render.py -- \
        --scene room.glb --camera test_000 --out view.png [--width 160 --height 120] \
        [--spp 256] [--bounces 8] [--lighting surfaces|lights] [--diffuse principled|lambert]
        [--specular imported|gltf]

The glTF importer brings the file into Blender (glTF's +Y up becomes Blender's +Z up), the named
camera (`SPLIT_NAME` of the dataset's frames, as `i2sdf export` writes them) becomes the scene
camera, and Cycles path traces it with no world light (the room is lit by its emitters alone, as
`i2sdf edit` renders it). The PNG is Blender's "Standard" view transform at exposure 0: the sRGB of
the linear render, the same encoding as the dataset's LDR images, whose linear units the exported
emission is in. `--exr` also writes the linear render.

`--lighting surfaces` (the default) lights the room by its emissive surfaces and removes any
punctual lights (`i2sdf export --lights`); `--lighting lights` lights it by the punctual lights
alone, the emitters' surfaces made non-emissive and transparent (a light inside a closed emitter
would be shadowed by it) — to check that the lights carry the emitters' power.

`--diffuse lambert` replaces the diffuse lobe of Blender 3.x's Principled BSDF (Burley's
"Disney" diffuse, whose retro-reflection brightens rough surfaces) by a Lambertian one of the
same base colour, the specular lobe kept. `--specular gltf` replaces the specular lobe the
importer made (Blender 3.4 maps `KHR_materials_specular` onto the Principled BSDF's "Specular"
without its specularFactor: about 0.5, F0 ≈ 0.04, whatever the file says) by a GGX lobe with the
file's own F0 and F90 (Schlick on the view angle): with `--diffuse lambert`, the BRDF i2sdf
recovered (Kd/π + GGX) as the file states it.

Only for cross-checking exports (it is not used by i2sdf itself).
"""

import argparse
import json
import struct
import sys

import bpy
import numpy as np

# Debian's Blender 3.4 importer still uses `np.bool`, which NumPy 1.24 (Debian 12's) removed.
if not hasattr(np, "bool"):
    np.bool = bool


def lambertian_diffuse(tree):
    """Principled (diffuse + specular) → Lambert(base colour) + Principled(black base): the
    specular lobe alone, its inputs as imported."""
    bsdf = tree.nodes.get("Principled BSDF")
    out = tree.nodes.get("Material Output")
    if bsdf is None or out is None:
        return
    diffuse = tree.nodes.new("ShaderNodeBsdfDiffuse")
    diffuse.inputs["Roughness"].default_value = 0.0
    base = bsdf.inputs["Base Color"]
    if base.is_linked:
        tree.links.new(base.links[0].from_socket, diffuse.inputs["Color"])
        tree.links.remove(base.links[0])
    else:
        diffuse.inputs["Color"].default_value = base.default_value
    base.default_value = (0.0, 0.0, 0.0, 1.0)
    add = tree.nodes.new("ShaderNodeAddShader")
    tree.links.new(diffuse.outputs["BSDF"], add.inputs[0])
    tree.links.new(bsdf.outputs["BSDF"], add.inputs[1])
    tree.links.new(add.outputs["Shader"], out.inputs["Surface"])


def gltf_materials(path):
    """The file's materials by name (its JSON, from a .glb's first chunk or a .gltf)."""
    data = open(path, "rb").read()
    if data[:4] == b"glTF":
        n = struct.unpack("<I", data[12:16])[0]
        doc = json.loads(data[20 : 20 + n])
    else:
        doc = json.loads(data)
    return {m.get("name"): m for m in doc.get("materials", [])}


def gltf_specular(tree, desc):
    """The Add shader's specular input ← GGX glossy, colour Schlick(F0, F90) on the view angle,
    F0 = min(0.04·specularColor, 1)·specular and F90 = specular (KHR_materials_specular), from
    the material's factors or, where it has them, its textures."""
    nodes, links = tree.nodes, tree.links
    bsdf = nodes.get("Principled BSDF")
    add = next((n for n in nodes if n.type == "ADD_SHADER"), None)
    if bsdf is None or add is None:
        sys.exit("--specular gltf needs --diffuse lambert")
    ext = desc.get("extensions", {}).get("KHR_materials_specular", {})
    factor = ext.get("specularFactor", 1.0)
    colour = ext.get("specularColorFactor", [1.0, 1.0, 1.0])
    glossy = nodes.new("ShaderNodeBsdfGlossy")
    glossy.distribution = "GGX"
    rough = bsdf.inputs["Roughness"]
    if rough.is_linked:
        links.new(rough.links[0].from_socket, glossy.inputs["Roughness"])
    else:
        glossy.inputs["Roughness"].default_value = rough.default_value
    images = {n.image.name: n for n in nodes if n.type == "TEX_IMAGE" and n.image}
    if "specular_color" in images and "roughness_g_specular_a" in images:
        # textured: F0 = min(0.04·S·tex, 1)·A, F90 = A
        scaled = nodes.new("ShaderNodeVectorMath")
        scaled.operation = "MULTIPLY"
        links.new(images["specular_color"].outputs["Color"], scaled.inputs[0])
        scaled.inputs[1].default_value = [0.04 * c for c in colour]
        capped = nodes.new("ShaderNodeVectorMath")
        capped.operation = "MINIMUM"
        links.new(scaled.outputs["Vector"], capped.inputs[0])
        capped.inputs[1].default_value = (1.0, 1.0, 1.0)
        f0 = nodes.new("ShaderNodeVectorMath")
        f0.operation = "SCALE"
        links.new(capped.outputs["Vector"], f0.inputs[0])
        links.new(images["roughness_g_specular_a"].outputs["Alpha"], f0.inputs["Scale"])
        f0_out, f90_out = f0.outputs["Vector"], images["roughness_g_specular_a"].outputs["Alpha"]
    else:
        f0_value = [min(0.04 * c, 1.0) * factor for c in colour]
        f0_out = f90_out = None
    weight = nodes.new("ShaderNodeLayerWeight")
    power = nodes.new("ShaderNodeMath")
    power.operation = "POWER"
    links.new(weight.outputs["Facing"], power.inputs[0])
    power.inputs[1].default_value = 5.0
    mix = nodes.new("ShaderNodeMixRGB")
    links.new(power.outputs["Value"], mix.inputs["Fac"])
    if f0_out is not None:
        links.new(f0_out, mix.inputs["Color1"])
        links.new(f90_out, mix.inputs["Color2"])
    else:
        mix.inputs["Color1"].default_value = (*f0_value, 1.0)
        mix.inputs["Color2"].default_value = (factor, factor, factor, 1.0)
    links.new(mix.outputs["Color"], glossy.inputs["Color"])
    links.new(glossy.outputs["BSDF"], add.inputs[1])


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
    p.add_argument("--lighting", choices=["surfaces", "lights"], default="surfaces")
    p.add_argument("--diffuse", choices=["principled", "lambert"], default="principled")
    p.add_argument("--specular", choices=["imported", "gltf"], default="imported")
    a = p.parse_args(argv)

    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.import_scene.gltf(filepath=a.scene)
    scene = bpy.context.scene
    cams = [o for o in scene.objects if o.type == "CAMERA" and o.name == a.camera]
    if not cams:
        names = sorted(o.name for o in scene.objects if o.type == "CAMERA")
        sys.exit(f"no camera named {a.camera} in {a.scene}; cameras: {', '.join(names[:8])}…")
    scene.camera = cams[0]
    lights = [o for o in scene.objects if o.type == "LIGHT"]
    if a.lighting == "surfaces":
        for o in lights:
            bpy.data.objects.remove(o, do_unlink=True)
    else:
        if not lights:
            sys.exit(f"--lighting lights: {a.scene} has no lights (export with --lights)")
        for m in bpy.data.materials:
            if m.name.startswith("emitter_") and m.use_nodes:
                bsdf = m.node_tree.nodes.get("Principled BSDF")
                bsdf.inputs["Emission Strength"].default_value = 0.0
                bsdf.inputs["Alpha"].default_value = 0.0
                m.blend_method = "BLEND"
    described = gltf_materials(a.scene) if a.specular == "gltf" else {}
    if a.diffuse == "lambert":
        for m in bpy.data.materials:
            if m.name.startswith("emitter_") or not m.use_nodes:
                continue
            lambertian_diffuse(m.node_tree)
            if a.specular == "gltf":
                gltf_specular(m.node_tree, described.get(m.name, {}))
    elif a.specular == "gltf":
        sys.exit("--specular gltf needs --diffuse lambert")
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
