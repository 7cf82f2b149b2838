# Runs inside `blender -b --factory-startup` (tests/blender/run_blender_test.sh): drives the
# clothdb add-on's operators against a small database and checks what each one leaves behind.
# Prints "ok <check>" per check and "all ok" at the end; any failure raises (exit status 1).
import os
import struct
import subprocess
import sys

import addon_utils
import bpy

EXE = os.environ["CLOTHDB_EXE"]
DB = os.environ["CLOTHDB_TEST_DB"]
sys.path.insert(0, os.environ["CLOTHDB_ADDON_DIR"])


def check(cond, what, detail=""):
    if not cond:
        raise AssertionError("FAIL %s %s" % (what, detail))
    print("ok", what, flush=True)


def read_pc2(path):
    with open(path, "rb") as f:
        data = f.read()
    _, _, points, start, rate, samples = struct.unpack("<12siiffi", data[:32])
    floats = struct.unpack("<%df" % (points * samples * 3), data[32:])
    return points, start, rate, samples, floats


def edit_log_count():
    out = subprocess.run([EXE, "clip", "log", DB], capture_output=True, text=True).stdout
    return int(out.split()[0])


addon_utils.enable("clothdb_blender", default_set=True)
import clothdb_blender  # noqa: E402

bpy.context.preferences.addons["clothdb_blender"].preferences.clothdb_path = EXE
scene = bpy.context.scene
state = scene.clothdb
# Blender's defaults, which are not the clip's: the add-on must set them.
check(scene.frame_start == 1 and scene.render.fps == 24, "factory defaults (frames 1-250, 24 fps)")

# Open and list the worst clips by strain.
state.database = DB
check(bpy.ops.clothdb.open() == {"FINISHED"}, "open database", state.verdict)
check(len(state.clips) > 1, "clips listed", str(len(state.clips)))
values = [float(c.value) for c in state.clips if c.value != "-"]
check(values == sorted(values, reverse=True), "worst first by strain", str(values))

# Load the worst clip: the Mesh Cache plays clip frame k at scene frame k at the clip's fps.
clip = state.clips[0].clip
check(bpy.ops.clothdb.load_clip(clip=clip) == {"FINISHED"}, "load clip", state.verdict)
cloth = bpy.context.active_object
frames, rate = int(cloth["clothdb_frames"]), float(cloth["clothdb_rate"])
mod = cloth.modifiers["clothdb cache"]
check(mod.frame_start == 0 and mod.frame_scale == 1 and mod.deform_mode == "INTEGRATE",
      "mesh cache frame start 0, scale 1, integrate")
check(scene.frame_start == 0 and scene.frame_end == frames - 1, "scene frame range is the clip's",
      "%d-%d" % (scene.frame_start, scene.frame_end))
check(abs(scene.render.fps / scene.render.fps_base - rate) < 1e-6, "scene fps is the clip's",
      "%g vs %g" % (scene.render.fps / scene.render.fps_base, rate))
check("clothdb_body" in cloth and cloth["clothdb_body"] in bpy.data.objects, "body loaded")
points, _, _, samples, exported = read_pc2(os.path.join(cloth["clothdb_folder"], "cloth.pc2"))
check(samples == frames and points == len(cloth.data.vertices), "cache matches the mesh")
for f in (0, frames // 2, frames - 1):
    got = clothdb_blender.evaluated_frames(bpy.context, cloth, f + 1)[f]
    worst = max(abs(got[v][c] - exported[3 * (f * points + v) + c]) for v in range(points)
                for c in range(3))
    check(worst < 1e-5, "frame %d plays clip frame %d" % (f, f), "%g m" % worst)

# Unchanged: "no change" (its own exit status), nothing logged.
logged = edit_log_count()
bpy.ops.clothdb.write_edit()
check(state.verdict_status == clothdb_blender.NO_CHANGE_EXIT_STATUS and "no change" in state.verdict,
      "an unchanged clip is refused as no change", state.verdict)
check(edit_log_count() == logged, "nothing logged")

# A shape-key edit over the cache: kept through Deform Mode Integrate, written back and imported.
cloth.shape_key_add(name="Basis")
key = cloth.shape_key_add(name="edit")
for i in range(0, len(key.data), 7):
    key.data[i].co.z += 0.002
key.value = 1.0
state.on_break = "ramp"
bpy.ops.clothdb.write_edit()
check(state.verdict_status == 0 and "imported as edit" in state.verdict,
      "a shape-key edit is imported", state.verdict)
check(edit_log_count() == logged + 1, "the import is logged")
edited = read_pc2(os.path.join(cloth["clothdb_folder"], "edited.pc2"))
check(edited[1] == 0 and edited[2] == 1 and edited[3] == frames,
      "edit written from frame 0, one sample per frame", str(edited[1:4]))

# Undo through clothdb.
check(bpy.ops.clothdb.undo() == {"FINISHED"} and "undid edit" in state.verdict, "undo",
      state.verdict)
check(edit_log_count() == logged + 2, "the undo is logged")
print("all ok", flush=True)
