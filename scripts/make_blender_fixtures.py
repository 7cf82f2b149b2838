"""Writes the Blender-made motion fixtures of tests/data/blender/ from CMU 01_01.bvh.

Run headless with Debian's Blender 3.4 (any working directory):

    blender -b --factory-startup --python scripts/make_blender_fixtures.py -- \
        /usr/share/assimp/models/BVH/01_01.bvh tests/data/blender 2.0

It imports the BVH as Blender's importer does by default for an artist (scene rate taken from
the file, 120 Hz; first BVH frame on Blender frame 1), keeps the first SECONDS seconds and exports
them the way an artist would: FBX (File > Export > FBX, armature only, animation baked) and glTF
(binary .glb, animation). The files are what Blender writes, warts included (the armature object
as an extra FBX node, glTF key times starting at frame 1 / fps): the loader must read them right.
"""
import builtins
import os
import sys

import bpy

argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
if len(argv) != 3:
    sys.exit("usage: blender -b --python make_blender_fixtures.py -- BVH OUT_DIR SECONDS")
bvh_path, out_dir, seconds = os.path.abspath(argv[0]), os.path.abspath(argv[1]), float(argv[2])
os.makedirs(out_dir, exist_ok=True)
CMU_SCALE = 0.0564444

# Blender 3.4's BVH importer opens the file with mode 'rU', which Debian 12's Python 3.11 no longer
# accepts ("ValueError: invalid mode: 'rU'"): map it to 'r' (universal newlines are the default).
_open = builtins.open


def _open_without_u(file, mode="r", *args, **kwargs):
    return _open(file, mode.replace("U", ""), *args, **kwargs)


builtins.open = _open_without_u

# Empty scene (no default cube, camera or light).
bpy.ops.wm.read_factory_settings(use_empty=True)
# CMU's BVH is in units of 0.0564444 m (motions/cmu_walk.json): imported at that scale, Blender's
# scene is in metres, as an artist's would be.
bpy.ops.import_anim.bvh(filepath=bvh_path, global_scale=CMU_SCALE, update_scene_fps=True,
                        update_scene_duration=True)
builtins.open = _open

scene = bpy.context.scene
fps = scene.render.fps / scene.render.fps_base
# BVH frame 0 is Blender frame 1 (the importer's default frame_start); keep SECONDS seconds of it,
# i.e. round(SECONDS * fps) + 1 frames, the BVH's frames 0 .. round(SECONDS * fps).
last = 1 + round(seconds * fps)
scene.frame_start = 1
scene.frame_end = last
# The glTF exporter of Blender 3.4 writes the whole action whatever the scene range: drop the keys
# past the range from the action (the FBX exporter bakes the scene range either way).
for obj in scene.objects:
    action = obj.animation_data.action if obj.animation_data else None
    if action is None:
        continue
    for fcurve in action.fcurves:
        points = fcurve.keyframe_points
        for k in range(len(points) - 1, -1, -1):
            if points[k].co.x > last + 1e-6:
                points.remove(points[k], fast=True)
        fcurve.update()
print(f"make_blender_fixtures: {fps:g} fps, frames {scene.frame_start}..{scene.frame_end}")

stem = os.path.splitext(os.path.basename(bvh_path))[0]
fbx_path = os.path.join(out_dir, f"{stem}_blender.fbx")
glb_path = os.path.join(out_dir, f"{stem}_blender.glb")
# The exporters' defaults, as File > Export gives them (FBX: leaf bones added, animation baked).
bpy.ops.export_scene.fbx(filepath=fbx_path)
bpy.ops.export_scene.gltf(filepath=glb_path, export_format="GLB", export_animations=True,
                          export_frame_range=True)
for path in (fbx_path, glb_path):
    print(f"make_blender_fixtures: wrote {path} ({os.path.getsize(path)} bytes)")
