"""Render what Blender imports from a splatreel USD export, from the camera `splatreel render --save-cameras` used.

Run with Blender's Python (the `bpy` module; tests/test_blender.py installs it into .venv-blender):

    .venv-blender/bin/python scripts/blender_render.py EXPORT.usdc CAMERAS.json OUT.png [FRAME]

The file is imported at Blender's default options (File > Import > USD); the point cloud it makes (the splat prim's
Points fallback, or --what points) gets an emission material reading its ``displayColor`` attribute, so the picture
shows the colours Blender received; Cycles on the CPU, a white world, the Standard view transform. The camera is
the first of the nerfstudio camera path (OpenGL axes, like Blender's cameras; vertical field of view). Used for the
Blender picture of docs/formats/export.md.
"""

import json
import math
import sys

import bpy
from mathutils import Matrix


def main(usd: str, cameras: str, png: str, frame: int = 0) -> None:
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.wm.usd_import(filepath=usd)
    scene = bpy.context.scene
    scene.frame_set(frame)

    material = bpy.data.materials.new("displayColor")
    material.use_nodes = True
    nodes = material.node_tree.nodes
    nodes.clear()
    attribute = nodes.new("ShaderNodeAttribute")
    attribute.attribute_name = "displayColor"
    emission, output = nodes.new("ShaderNodeEmission"), nodes.new("ShaderNodeOutputMaterial")
    links = material.node_tree.links
    links.new(attribute.outputs["Color"], emission.inputs["Color"])
    links.new(emission.outputs[0], output.inputs["Surface"])
    for obj in bpy.data.objects:
        if obj.type == "POINTCLOUD":
            obj.data.materials.append(material)

    path = json.loads(open(cameras).read())
    key = path["camera_path"][0]
    camera_data = bpy.data.cameras.new("camera")
    camera_data.sensor_fit = "VERTICAL"
    camera_data.angle_y = math.radians(key["fov"])
    camera = bpy.data.objects.new("camera", camera_data)
    camera.matrix_world = Matrix([key["camera_to_world"][i:i + 4] for i in range(0, 16, 4)])
    scene.collection.objects.link(camera)
    scene.camera = camera

    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = 16
    scene.world = bpy.data.worlds.new("white")
    scene.world.use_nodes = True
    scene.world.node_tree.nodes["Background"].inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    scene.view_settings.view_transform = "Standard"  # sRGB out, as splatreel renders
    scene.render.resolution_x, scene.render.resolution_y = path["render_width"], path["render_height"]
    scene.render.filepath = png
    bpy.ops.render.render(write_still=True)


if __name__ == "__main__":
    args = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else sys.argv[1:]
    main(args[0], args[1], args[2], int(args[3]) if len(args) > 3 else 0)
