# The clothdb round trip in Blender (docs/guide/blender.md): open a clothdb database through the
# `clothdb` command, list its worst clips by a quality metric, load a clip with its body, edit it,
# write the edit back with the settings `clothdb clip import` expects, and undo.
#
# Everything goes through the `clothdb` command (a subprocess; its path is in the add-on's
# preferences): the add-on holds no knowledge of the file format. The clip is built from the OBJ
# and PC2 files `clothdb clip export` writes, read here directly, so that no importer converts
# axes or reorders vertices; the edit is written as PC2 from the evaluated mesh in the object's
# local space (the clip's character space), one sample per clip frame, which is what
# `clip import` checks for.
import json
import os
import struct
import subprocess
import tempfile

import bpy
from bpy.props import CollectionProperty, EnumProperty, IntProperty, PointerProperty, StringProperty

bl_info = {
    "name": "clothdb",
    "author": "clothdb",
    "version": (1, 0, 0),
    "blender": (3, 4, 0),
    "location": "3D Viewport > Sidebar > clothdb",
    "description": "Edit the cloth clips of a clothdb database: load a clip with its body, "
    "write the edit back, undo",
    "category": "Animation",
}

# The metrics `clothdb clips list --by` accepts (cli/cmd_clips.cpp) and their keys in its --json
# rows.
METRICS = [
    ("strain", "Max strain (%)", "Largest edge strain in any frame", "max_strain_percent"),
    ("penetration", "Max penetration (mm)", "Deepest penetration of the body",
     "max_penetration_mm"),
    ("mean-penetration", "Mean penetration (mm)", "Mean penetration depth",
     "mean_penetration_mm"),
    ("jitter", "Jitter (mm)", "Frame-to-frame jitter", "jitter_mm"),
    ("halved", "Halved steps", "Solver steps halved to stay stable", "halved_steps"),
    ("pop", "Pop (mm)", "Largest jump at an edge out of the clip", "worst_pop_mm"),
    ("steering", "Steering (mm)", "Largest steering pull", "steering_mm"),
    ("self-intersections", "Self-intersections", "Edge-triangle crossings in a frame",
     "self_intersections"),
]
METRIC_KEY = {m[0]: m[3] for m in METRICS}

# `clothdb clip import`'s exit status for an import equal to the stored clip (nothing written).
NO_CHANGE_EXIT_STATUS = 3


def _prefs(context):
    return context.preferences.addons[__name__].preferences


def run_clothdb(context, args, stdout_only=False):
    """Runs `clothdb ARGS`; returns (exit status, stdout + stderr), or stdout alone when asked
    and it succeeded (for --json)."""
    exe = bpy.path.abspath(_prefs(context).clothdb_path or "clothdb")
    try:
        done = subprocess.run([exe] + [str(a) for a in args], capture_output=True, text=True,
                              check=False)
    except OSError as e:
        return 127, "cannot run %s: %s (set the clothdb path in the add-on's preferences)" % (
            exe, e)
    if stdout_only and done.returncode == 0:
        return 0, done.stdout
    return done.returncode, (done.stdout + done.stderr).strip()


# ---- files `clothdb clip export` writes

def read_obj(path):
    """Vertices and faces of an OBJ (v and f lines), in file order: no axis conversion."""
    verts, faces = [], []
    with open(path) as f:
        for line in f:
            parts = line.split()
            if not parts:
                continue
            if parts[0] == "v":
                verts.append(tuple(float(x) for x in parts[1:4]))
            elif parts[0] == "f":
                idx = [int(p.split("/")[0]) for p in parts[1:]]
                faces.append(tuple(i - 1 if i > 0 else len(verts) + i for i in idx))
    return verts, faces


def read_pc2_header(path):
    with open(path, "rb") as f:
        head = f.read(32)
    sig, version, points, start, rate, samples = struct.unpack("<12siiffi", head)
    if sig != b"POINTCACHE2\0" or version != 1:
        raise ValueError("%s: not a PC2 file" % path)
    return points, start, rate, samples


def write_pc2(path, frames, start=0.0, rate=1.0):
    """PC2: header, then every frame's float32 x, y, z (the layout clothdb reads)."""
    points = len(frames[0]) if frames else 0
    with open(path, "wb") as f:
        f.write(struct.pack("<12siiffi", b"POINTCACHE2\0", 1, points, start, rate, len(frames)))
        for frame in frames:
            f.write(struct.pack("<%df" % (3 * points), *[c for v in frame for c in v]))


def mesh_object(context, name, obj_path):
    verts, faces = read_obj(obj_path)
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(verts, [], faces)
    mesh.update()
    obj = bpy.data.objects.new(name, mesh)
    context.scene.collection.objects.link(obj)
    return obj


def add_mesh_cache(obj, pc2_path):
    """A Mesh Cache that plays the clip's frame k at scene frame k: frame start 0, frame scale 1,
    no axis conversion, and Deform Mode Integrate so that shape keys edit on top of the cache."""
    mod = obj.modifiers.new("clothdb cache", "MESH_CACHE")
    mod.cache_format = "PC2"
    mod.filepath = pc2_path
    mod.time_mode = "FRAME"
    mod.play_mode = "SCENE"
    mod.frame_start = 0.0
    mod.frame_scale = 1.0
    mod.interpolation = "LINEAR"
    mod.deform_mode = "INTEGRATE"
    mod.forward_axis = "POS_Y"
    mod.up_axis = "POS_Z"
    mod.flip_axis = set()
    return mod


def set_scene_timing(scene, rate, frames):
    fps = max(1, round(rate))
    scene.render.fps = fps
    scene.render.fps_base = fps / rate
    scene.frame_start = 0
    scene.frame_end = frames - 1
    scene.frame_set(0)


def evaluated_frames(context, obj, frames):
    """The object's evaluated vertices (modifiers and shape keys applied) in its local space, one
    list per scene frame 0 .. frames-1: the clip's character space, as `clip import` expects."""
    scene = context.scene
    out = []
    for f in range(frames):
        scene.frame_set(f)
        depsgraph = context.evaluated_depsgraph_get()
        ev = obj.evaluated_get(depsgraph)
        mesh = ev.to_mesh()
        out.append([tuple(v.co) for v in mesh.vertices])
        ev.to_mesh_clear()
    return out


# ---- state

class ClothdbClipItem(bpy.types.PropertyGroup):
    clip: IntProperty(name="Clip")
    value: StringProperty(name="Value")
    frames: IntProperty(name="Frames")
    status: StringProperty(name="Status")


class ClothdbState(bpy.types.PropertyGroup):
    database: StringProperty(name="Database", subtype="FILE_PATH")
    metric: EnumProperty(name="Worst by", items=[m[:3] for m in METRICS], default="strain")
    worst: IntProperty(name="Clips", default=20, min=1, max=1000)
    clips: CollectionProperty(type=ClothdbClipItem)
    clip_index: IntProperty(name="Clip", default=0)
    on_break: EnumProperty(
        name="On break",
        items=[("refuse", "Refuse", "An edit that breaks continuity writes nothing"),
               ("ramp", "Ramp", "Fade the edit out toward the original at a broken end"),
               ("reblend", "Reblend", "Record the larger blend errors")],
        default="refuse")
    verdict: StringProperty(name="Verdict")
    verdict_status: IntProperty(name="Exit status", default=-1)


class ClothdbPreferences(bpy.types.AddonPreferences):
    bl_idname = __name__
    clothdb_path: StringProperty(name="clothdb command", subtype="FILE_PATH", default="clothdb",
                                 description="The clothdb executable (build/cli/clothdb)")

    def draw(self, context):
        self.layout.prop(self, "clothdb_path")


def _state(context):
    return context.scene.clothdb


def _verdict(state, status, text):
    state.verdict_status = status
    state.verdict = text


# ---- operators

class CLOTHDB_OT_open(bpy.types.Operator):
    """Open a clothdb database and list its worst clips"""
    bl_idname = "clothdb.open"
    bl_label = "Open database"
    filepath: StringProperty(subtype="FILE_PATH")

    def execute(self, context):
        state = _state(context)
        path = bpy.path.abspath(self.filepath or state.database)
        status, out = run_clothdb(context, ["db", "info", path])
        if status != 0:
            self.report({"ERROR"}, out)
            _verdict(state, status, out)
            return {"CANCELLED"}
        state.database = path
        _verdict(state, 0, out.splitlines()[0] if out else "")
        return bpy.ops.clothdb.list_clips()

    def invoke(self, context, event):
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}


class CLOTHDB_OT_list_clips(bpy.types.Operator):
    """List the worst clips by the chosen metric (clothdb clips list --json)"""
    bl_idname = "clothdb.list_clips"
    bl_label = "List worst clips"

    def execute(self, context):
        state = _state(context)
        status, out = run_clothdb(context, ["clips", "list", state.database, "--json", "--by",
                                            state.metric, "--worst", state.worst],
                                  stdout_only=True)
        if status != 0:
            self.report({"ERROR"}, out)
            _verdict(state, status, out)
            return {"CANCELLED"}
        try:
            table = json.loads(out)
        except ValueError as e:
            self.report({"ERROR"}, "clothdb clips list --json: %s" % e)
            return {"CANCELLED"}
        state.clips.clear()
        key = METRIC_KEY[state.metric]
        for row in table["clips"]:
            item = state.clips.add()
            item.clip = int(row["id"])
            item.frames = int(row.get("frames", 0))
            item.status = str(row.get("status", ""))
            value = row.get(key)
            item.value = "-" if value is None else "%.3g" % value
        state.clip_index = 0
        return {"FINISHED"}


class CLOTHDB_OT_load_clip(bpy.types.Operator):
    """Load a clip with its body: the cloth with a Mesh Cache of its frames, the body capsules,
    and the scene's frame range and fps set to the clip's"""
    bl_idname = "clothdb.load_clip"
    bl_label = "Load clip"
    clip: IntProperty(name="Clip", default=0)

    def execute(self, context):
        state = _state(context)
        clip = self.clip or (state.clips[state.clip_index].clip if state.clips else 0)
        if clip <= 0:
            self.report({"ERROR"}, "no clip chosen")
            return {"CANCELLED"}
        folder = tempfile.mkdtemp(prefix="clothdb_clip%d_" % clip)
        status, out = run_clothdb(context, ["clip", "export", state.database, clip, "--out",
                                            folder])
        if status != 0:
            self.report({"ERROR"}, out)
            _verdict(state, status, out)
            return {"CANCELLED"}
        with open(os.path.join(folder, "clip.json")) as f:
            info = json.load(f)
        rate, frames = float(info["frame_rate"]), int(info["frames"])
        cloth = mesh_object(context, "clothdb clip %d" % clip, os.path.join(folder, "cloth.obj"))
        add_mesh_cache(cloth, os.path.join(folder, "cloth.pc2"))
        cloth["clothdb_database"] = state.database
        cloth["clothdb_clip"] = clip
        cloth["clothdb_frames"] = frames
        cloth["clothdb_rate"] = rate
        cloth["clothdb_folder"] = folder
        if os.path.exists(os.path.join(folder, "body.obj")):
            body = mesh_object(context, "clothdb body %d" % clip, os.path.join(folder, "body.obj"))
            add_mesh_cache(body, os.path.join(folder, "body.pc2"))
            body.hide_select = True
            cloth["clothdb_body"] = body.name
        set_scene_timing(context.scene, rate, frames)
        for o in context.view_layer.objects:
            o.select_set(False)
        cloth.select_set(True)
        context.view_layer.objects.active = cloth
        _verdict(state, 0, "clip %d: %d frames at %g fps, scene frames 0-%d" % (
            clip, frames, rate, frames - 1))
        return {"FINISHED"}


def _clip_object(context):
    obj = context.active_object
    if obj is None or "clothdb_clip" not in obj:
        return None
    return obj


class CLOTHDB_OT_write_edit(bpy.types.Operator):
    """Write the edited clip back: every clip frame of the evaluated mesh (modifiers and shape keys
    applied) in its local space, as PC2 with one sample per frame from frame 0, then
    `clothdb clip import`; its verdict is shown"""
    bl_idname = "clothdb.write_edit"
    bl_label = "Write edit back"

    def execute(self, context):
        state = _state(context)
        obj = _clip_object(context)
        if obj is None:
            self.report({"ERROR"}, "select a clip loaded by clothdb")
            return {"CANCELLED"}
        frames = int(obj["clothdb_frames"])
        positions = evaluated_frames(context, obj, frames)
        if any(len(p) != len(obj.data.vertices) for p in positions):
            self.report({"ERROR"}, "the vertex count changed: the clip keeps its topology")
            return {"CANCELLED"}
        path = os.path.join(obj["clothdb_folder"], "edited.pc2")
        write_pc2(path, positions)
        status, out = run_clothdb(context, ["clip", "import", obj["clothdb_database"],
                                            int(obj["clothdb_clip"]), path, "--on-break",
                                            state.on_break])
        _verdict(state, status, out)
        if status == 0:
            self.report({"INFO"}, out.splitlines()[-1] if out else "imported")
        elif status == NO_CHANGE_EXIT_STATUS:
            self.report({"WARNING"}, out)
        else:
            self.report({"ERROR"}, out)
        return {"FINISHED"} if status in (0, NO_CHANGE_EXIT_STATUS) else {"CANCELLED"}


class CLOTHDB_OT_undo(bpy.types.Operator):
    """Revert the database's newest edit (clothdb undo)"""
    bl_idname = "clothdb.undo"
    bl_label = "Undo last edit"

    def execute(self, context):
        state = _state(context)
        obj = _clip_object(context)
        database = obj["clothdb_database"] if obj else state.database
        status, out = run_clothdb(context, ["undo", database])
        _verdict(state, status, out)
        if status != 0:
            self.report({"ERROR"}, out)
            return {"CANCELLED"}
        self.report({"INFO"}, out)
        return {"FINISHED"}


# ---- interface

class CLOTHDB_UL_clips(bpy.types.UIList):
    def draw_item(self, context, layout, data, item, icon, active_data, active_propname):
        layout.label(text="clip %d" % item.clip)
        layout.label(text=item.value)
        layout.label(text="%d fr %s" % (item.frames, item.status))


class CLOTHDB_PT_panel(bpy.types.Panel):
    bl_label = "clothdb"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "clothdb"

    def draw(self, context):
        state = _state(context)
        col = self.layout.column()
        col.prop(state, "database")
        col.operator("clothdb.open")
        row = col.row()
        row.prop(state, "metric")
        row.prop(state, "worst")
        col.operator("clothdb.list_clips")
        col.template_list("CLOTHDB_UL_clips", "", state, "clips", state, "clip_index")
        col.operator("clothdb.load_clip")
        col.prop(state, "on_break")
        col.operator("clothdb.write_edit")
        col.operator("clothdb.undo")
        if state.verdict:
            box = col.box()
            for line in state.verdict.splitlines()[-8:]:
                box.label(text=line)


CLASSES = (ClothdbClipItem, ClothdbState, ClothdbPreferences, CLOTHDB_OT_open,
           CLOTHDB_OT_list_clips, CLOTHDB_OT_load_clip, CLOTHDB_OT_write_edit, CLOTHDB_OT_undo,
           CLOTHDB_UL_clips, CLOTHDB_PT_panel)


def register():
    for c in CLASSES:
        bpy.utils.register_class(c)
    bpy.types.Scene.clothdb = PointerProperty(type=ClothdbState)


def unregister():
    del bpy.types.Scene.clothdb
    for c in reversed(CLASSES):
        bpy.utils.unregister_class(c)
