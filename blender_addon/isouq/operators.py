# Operators: import (File > Import), the pipeline run (in process with the isouq Python module,
# else a background subprocess; a modal timer either way), the analysis views C1..C7 (views.py)
# and rendering. Errors go to self.report and return CANCELLED.

import json
import os

import bpy
import re
import tempfile

from bpy.props import BoolProperty, EnumProperty, IntProperty, StringProperty
from bpy_extras.io_utils import ImportHelper

from . import frames, live, native, pipeline, ply_io, props, render, sequence, ui, views

_EXPECTED = (views.ViewError, ply_io.PlyError, frames.SequenceError, ValueError, OSError)


def _preferences(context):
    addon = context.preferences.addons.get(__package__)
    return addon.preferences if addon else None


class _ObjectOperator:
    """Runs `self.run(context, obj)` on the isouq mesh; reports expected errors."""
    bl_options = {"REGISTER", "UNDO"}

    def execute(self, context):
        live.complete(context)  # the columns a live update left for later, before any view reads them
        try:
            obj = views.isouq_object(context)
            message = self.run(context, obj)
        except _EXPECTED as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        if message:
            self.report({"INFO"}, message)
        return {"FINISHED"}


class ISOUQ_OT_import_mesh(bpy.types.Operator, ImportHelper):
    """Import an isouq mesh (.ply) with every per-vertex and per-face attribute"""
    bl_idname = "isouq.import_mesh"
    bl_label = "Import isouq mesh"
    bl_options = {"REGISTER", "UNDO"}

    filename_ext = ".ply"
    filter_glob: StringProperty(default="*.ply", options={"HIDDEN"})
    summary: StringProperty(name="Summary JSON", subtype="FILE_PATH",
                            description="Optional --summary JSON of the same run (C7)")

    def execute(self, context):
        try:
            obj = views.import_ply(context, self.filepath)
            if self.summary:
                views.load_summary(obj, self.summary)
        except _EXPECTED as e:
            self.report({"ERROR"}, f"{os.path.basename(self.filepath)}: {e}")
            return {"CANCELLED"}
        for o in context.view_layer.objects:
            o.select_set(False)
        obj.select_set(True)
        context.view_layer.objects.active = obj
        self.report({"INFO"}, f"{obj.name}: {len(obj.data.vertices)} vertices, "
                              f"{len(obj.data.attributes)} attributes")
        return {"FINISHED"}


class ISOUQ_OT_import_sequence(bpy.types.Operator, ImportHelper):
    """Import a numbered set of isouq meshes (name.0001.ply, name.0002.ply, ...) as one object
    whose mesh follows the scene frame, loaded just in time with every attribute"""
    bl_idname = "isouq.import_sequence"
    bl_label = "Import isouq mesh sequence"
    bl_options = {"REGISTER", "UNDO"}

    filename_ext = ".ply"
    filter_glob: StringProperty(default="*.ply", options={"HIDDEN"})
    summary: StringProperty(name="Summary JSON", subtype="FILE_PATH",
                            description="The sequence summary (--summary); empty: one found "
                                        "beside the files")
    mode: EnumProperty(name="Outside the frames", items=props.SEQUENCE_MODES, default="EXTEND")
    offset: IntProperty(name="Frame offset", default=0,
                        description="File frame = scene frame + offset")
    set_frame_range: BoolProperty(name="Set frame range", default=True,
                                  description="The scene's start and end become the sequence's")

    def execute(self, context):
        try:
            obj = sequence.import_sequence(context, self.filepath, summary=self.summary or None,
                                           mode=self.mode, offset=self.offset,
                                           set_frame_range=self.set_frame_range)
        except _EXPECTED as e:
            self.report({"ERROR"}, f"{os.path.basename(self.filepath)}: {e}")
            return {"CANCELLED"}
        _make_active(context, obj)
        seq = sequence.sequence_of(obj)
        self.report({"INFO"}, f"{obj.name}: {len(seq.frames)} frames ({seq.first}-{seq.last}), "
                              f"showing frame {obj.isouq.sequence_frame}")
        return {"FINISHED"}


def _make_active(context, obj):
    for o in context.view_layer.objects:
        o.select_set(False)
    obj.select_set(True)
    context.view_layer.objects.active = obj


def _safe_name(name):
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name).strip("._") or "volume"


def sequence_folder(context, setting, name):
    """The folder for a Volume sequence's frames: the setting ('//' = the .blend's folder; for an
    unsaved file the temporary folder) and a subfolder per volume."""
    if setting.startswith("//") and not bpy.data.filepath:
        base = os.path.join(tempfile.gettempdir(), setting[2:] or "isouq_sequences")
    else:
        base = bpy.path.abspath(setting or "//isouq_sequences/")
    return os.path.join(base, _safe_name(name))


class ISOUQ_OT_run_pipeline(bpy.types.Operator):
    """Run isouq on the VDB file or Volume object in the background (in process when the isouq
    Python module loads, else `isouq mesh`) and import the result. Esc cancels"""
    bl_idname = "isouq.run_pipeline"
    bl_label = "Run isouq"
    bl_options = {"REGISTER", "UNDO"}

    _job = None
    _timer = None

    def _prepare(self, context):
        s = context.scene.isouq
        volume, grid, path = s.volume, s.grid, s.input_path
        if not pipeline.is_generated(path):
            path = bpy.path.abspath(path)
        self._sequence = None
        if volume is not None:
            data = volume.data
            if data.packed_file is not None:
                raise ValueError(f"volume '{volume.name}' is packed: unpack it to a .vdb file")
            path = bpy.path.abspath(data.grids.frame_filepath or data.filepath)
            if not grid:
                active = active_grid(data)
                grid = active.name if active is not None else ""
            if data.is_sequence and s.whole_sequence:
                self._sequence = volume_sequence(volume)
                path = self._sequence["pattern"]
        if not path:
            raise ValueError("choose a .vdb file or a Volume object")
        if self._sequence is None and frames.parse_pattern(path) is not None \
                and not pipeline.is_generated(path):
            seq = frames.detect(path)               # a typed pattern: a sequence too
            self._sequence = {"pattern": path, "frames": f"{seq.first}-{seq.last}",
                              "total": len(seq.frames), "offset": 0, "mode": "EXTEND",
                              "name": frames.object_name(seq)}
        if self._sequence is None and not pipeline.is_generated(path) \
                and not os.path.isfile(path):
            raise ValueError(f"input file not found: {path}")
        prefs = _preferences(context)
        binary, tried = pipeline.find_binary(prefs.binary if prefs else "")
        # One input: in process when the isouq module imports (native.py), else the CLI.
        module = native.load(binary) if self._sequence is None else None
        if binary is None and module is None:
            raise ValueError(f"isouq binary not found ({tried}); set it in the add-on preferences")
        menu = native.method_menu() if module is not None else pipeline.method_menu(binary)
        if menu is not None and s.method not in menu:
            raise ValueError(f"this isouq has no method '{s.method}' (it has {', '.join(menu)})")
        request = pipeline.MeshRequest(path, s.isovalue if s.use_isovalue else None, s.method,
                                       s.hidden_features, s.subdivisions, grid,
                                       resolution=s.resolution)
        self._volume = volume
        if module is not None:
            return pipeline.NativeJob(request, module).start()
        if self._sequence is None:
            return pipeline.Job(request, binary).start()
        seq = self._sequence
        request.frames, request.resume = seq["frames"], s.resume
        request.skip_missing = s.skip_missing
        name = volume.name if volume is not None else seq["name"]
        return pipeline.SequenceJob(request, binary, output_dir=sequence_folder(
            context, s.sequence_dir, name), name=_safe_name(name), total=seq["total"]).start()

    def _finish(self, context, job):
        """Imports the outputs of a finished run; returns the operator result."""
        status = job.poll()
        try:
            if job.cancelled:
                kept = ""
                if isinstance(job, pipeline.SequenceJob):
                    done = frames.parse_pattern(job.mesh_path).scan().frames
                    kept = (f"; {len(done)} finished frames kept in {job.output_dir} "
                            "(Resume continues)")
                self.report({"WARNING"}, "isouq run cancelled" + kept)
                return {"CANCELLED"}
            if status != 0:
                self.report({"ERROR"}, job.error_message())
                return {"CANCELLED"}
            if isinstance(job, pipeline.NativeJob):
                return self._import_native(context, job)
            if isinstance(job, pipeline.SequenceJob):
                return self._import_sequence(context, job)
            if not os.path.isfile(job.mesh_path):
                self.report({"ERROR"}, f"isouq finished but wrote no mesh ({job.binary})")
                return {"CANCELLED"}
            return self._import(context, job)
        finally:
            job.cleanup()

    def _import_sequence(self, context, job):
        """The frames written by a sequence run, as sequence objects (and the hidden-feature
        sequence beside them), placed like the Volume and timed like it."""
        seq = self._sequence
        written = frames.parse_pattern(job.mesh_path).scan()
        if not written.frames:
            self.report({"ERROR"}, f"isouq finished but wrote no frame ({job.mesh_path})")
            return {"CANCELLED"}
        summary = job.summary_path if os.path.isfile(job.summary_path) else None
        created = []
        try:
            obj = sequence.import_sequence(context, job.mesh_path, job.name, "MESH", summary,
                                           seq["mode"], seq["offset"])
            created.append(obj)
            if job.hidden_path and frames.parse_pattern(job.hidden_path).scan().frames:
                hidden = sequence.import_sequence(context, job.hidden_path, job.name + "_hidden",
                                                  "HIDDEN", summary, seq["mode"], seq["offset"])
                created.append(hidden)
                obj.isouq.partner, hidden.isouq.partner = hidden, obj
        except _EXPECTED as e:
            _remove_objects(created)
            self.report({"ERROR"}, f"isouq output unreadable: {e}")
            return {"CANCELLED"}
        for o in created:
            if self._volume is not None:
                o.matrix_world = volume_mesh_matrix(self._volume, job.request.grid)
        _make_active(context, obj)
        self.report({"INFO"}, f"{obj.name}: {len(written.frames)} frames in "
                              f"{job.output_dir}")
        return {"FINISHED"}

    def _import_native(self, context, job):
        """The meshes of an in-process run, straight from memory; the object remembers its
        request, so live mode (live.py) can mesh it again."""
        name = pipeline.input_name(job.request.input)
        result, created = job.result, []
        try:
            obj = views.import_mesh(context, native.to_isouq_mesh(result), name, "MESH",
                                    job.request.input)
            created.append(obj)
            obj.isouq.summary = json.dumps(result.summary)
            if result.hidden is not None:
                hidden = views.import_mesh(context, native.to_isouq_mesh(result.hidden),
                                           name + "_hidden", "HIDDEN", job.request.input)
                created.append(hidden)
                _pair_hidden(obj, hidden)
            for o in created:
                if self._volume is not None:
                    o.matrix_world = volume_mesh_matrix(self._volume, job.request.grid)
        except _EXPECTED as e:
            _remove_objects(created)
            self.report({"ERROR"}, f"isouq mesh unusable: {e}")
            return {"CANCELLED"}
        live.remember(obj, job.request)
        context.view_layer.objects.active = obj
        self.report({"INFO"}, f"{obj.name}: {len(obj.data.vertices)} vertices (in process)")
        return {"FINISHED"}

    def _import(self, context, job):
        name = pipeline.input_name(job.request.input)
        created = []
        try:
            obj = views.import_ply(context, job.mesh_path, name, "MESH")
            created.append(obj)
            if os.path.isfile(job.summary_path):
                views.load_summary(obj, job.summary_path)
            if job.hidden_path and os.path.isfile(job.hidden_path):
                hidden = views.import_ply(context, job.hidden_path, name + "_hidden", "HIDDEN")
                created.append(hidden)
                _pair_hidden(obj, hidden)
            for o in created:
                o.isouq.source = job.request.input
                if self._volume is not None:
                    o.matrix_world = volume_mesh_matrix(self._volume, job.request.grid)
        except _EXPECTED as e:
            _remove_objects(created)
            self.report({"ERROR"}, f"isouq output unreadable: {e}")
            return {"CANCELLED"}
        context.view_layer.objects.active = obj
        self.report({"INFO"}, f"{obj.name}: {len(obj.data.vertices)} vertices")
        return {"FINISHED"}

    def execute(self, context):
        """Blocking run (scripts, background mode)."""
        try:
            job = self._prepare(context)
        except _EXPECTED as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        job.wait()
        return self._finish(context, job)

    def invoke(self, context, event):
        if bpy.app.background:
            return self.execute(context)
        try:
            self._job = self._prepare(context)
        except _EXPECTED as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        wm = context.window_manager
        self._timer = wm.event_timer_add(0.25, window=context.window)
        wm.progress_begin(0, 100)
        wm.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        wm = context.window_manager
        if event.type == "ESC":
            self._job.cancel()
        elif event.type != "TIMER":
            return {"PASS_THROUGH"}
        if self._job.poll() is None and not self._job.cancelled:
            fraction = self._job.progress()
            if fraction is not None:
                wm.progress_update(int(100 * fraction))
            done = self._job.frames_done() if isinstance(self._job, pipeline.SequenceJob) else None
            context.workspace.status_text_set(
                f"isouq: meshing {os.path.basename(self._job.request.input)}"
                + (f" frame {done[0] + 1} of {done[1]}" if done and done[0] < done[1] else "")
                + (f" {100 * fraction:.0f}%" if fraction is not None else "") + " (Esc cancels)")
            return {"RUNNING_MODAL"}
        wm.event_timer_remove(self._timer)
        wm.progress_end()
        context.workspace.status_text_set(None)
        return self._finish(context, self._job)


class ISOUQ_OT_apply_threshold(_ObjectOperator, bpy.types.Operator):
    """C1: colour vertices above/below the threshold, select those above, plot the CDF"""
    bl_idname = "isouq.apply_threshold"
    bl_label = "Apply Threshold"

    def run(self, context, obj):
        count, path = views.apply_threshold(context, obj)
        ui.show_png("cdf", path)
        return f"{count} of {len(obj.data.vertices)} vertices above the threshold"


class ISOUQ_OT_add_box(_ObjectOperator, bpy.types.Operator):
    """C2: add a cube empty to move and scale over the surface"""
    bl_idname = "isouq.add_box"
    bl_label = "Add Box"

    def run(self, context, obj):
        box = views.add_box(context, obj)
        for o in context.view_layer.objects:
            o.select_set(False)
        box.select_set(True)
        context.view_layer.objects.active = box
        return None


class ISOUQ_OT_select_box(_ObjectOperator, bpy.types.Operator):
    """C2: select the vertices inside the box"""
    bl_idname = "isouq.select_box"
    bl_label = "Select in Box"

    def run(self, context, obj):
        return f"{views.select_box(context, obj)} vertices in the box"


class ISOUQ_OT_apply_methods(_ObjectOperator, bpy.types.Operator):
    """C3: place selected vertices with one method and the others with another, at once"""
    bl_idname = "isouq.apply_methods"
    bl_label = "Apply Methods"

    def run(self, context, obj):
        return f"{views.apply_methods(context, obj)} vertices use the inside method"


class ISOUQ_OT_reset_positions(_ObjectOperator, bpy.types.Operator):
    """C3: back to the primary method's positions as imported"""
    bl_idname = "isouq.reset_positions"
    bl_label = "Reset Positions"

    def run(self, context, obj):
        views.reset_positions(obj)


class ISOUQ_OT_show_heatmap(_ObjectOperator, bpy.types.Operator):
    """C4: the measure as a heat map, with a legend"""
    bl_idname = "isouq.show_heatmap"
    bl_label = "Heat Map"
    reset_range: BoolProperty(name="Range from data", default=True)

    def run(self, context, obj):
        ui.show_png("legend", views.apply_heatmap(context, obj, self.reset_range))


class ISOUQ_OT_plot_bars(_ObjectOperator, bpy.types.Operator):
    """C5: bars of err_est, d_lc, d_lw for the vertices in the box"""
    bl_idname = "isouq.plot_bars"
    bl_label = "Plot Bars"

    def run(self, context, obj):
        count, path = views.plot_bars(context, obj)
        ui.show_png("bars", path)
        return f"{count} vertices in the box"


class ISOUQ_OT_compare_methods(_ObjectOperator, bpy.types.Operator):
    """C6: a copy beside the mesh placed with another method"""
    bl_idname = "isouq.compare_methods"
    bl_label = "Side by Side"

    def run(self, context, obj):
        return f"added {views.compare_methods(context, obj).name}"


class ISOUQ_OT_show_hidden(_ObjectOperator, bpy.types.Operator):
    """C6: hidden-feature surface (transparent orange) over standard MC (opaque blue)"""
    bl_idname = "isouq.show_hidden"
    bl_label = "Hidden over Standard"

    def run(self, context, obj):
        views.show_hidden(context, obj)


class ISOUQ_OT_combined_view(_ObjectOperator, bpy.types.Operator):
    """Heat map and hidden features in one view"""
    bl_idname = "isouq.combined_view"
    bl_label = "Combined View"

    def run(self, context, obj):
        views.combined_view(context, obj)


class ISOUQ_OT_load_summary(_ObjectOperator, bpy.types.Operator, ImportHelper):
    """C7: attach a --summary JSON to the isouq mesh"""
    bl_idname = "isouq.load_summary"
    bl_label = "Load Summary"
    filename_ext = ".json"
    filter_glob: StringProperty(default="*.json", options={"HIDDEN"})

    def run(self, context, obj):
        views.load_summary(obj, self.filepath)


class ISOUQ_OT_render_view(_ObjectOperator, bpy.types.Operator):
    """Render the visible isouq objects to PNG (and optionally a multilayer EXR with AOVs)"""
    bl_idname = "isouq.render_view"
    bl_label = "Render View"

    def run(self, context, obj):
        s = context.scene.isouq
        path = bpy.path.abspath(s.render_path)
        exr = os.path.splitext(path)[0] + ".exr" if s.render_exr else None
        objects = [o for o in context.scene.objects
                   if o.type == "MESH" and o.isouq.role != "NONE" and not o.hide_render]
        written = render.render_view(context, objects, path, s.render_engine, s.render_size,
                                     exr, (s.measure, "hidden"))
        return "wrote " + ", ".join(written)


class ISOUQ_OT_open_plot(bpy.types.Operator):
    """Open a plot in a new Image Editor window"""
    bl_idname = "isouq.open_plot"
    bl_label = "Open Plot"
    key: StringProperty(default="cdf")

    def execute(self, context):
        image = ui.plot_image(self.key)
        if image is None:
            self.report({"ERROR"}, f"no {self.key} plot yet")
            return {"CANCELLED"}
        bpy.ops.wm.window_new()
        area = context.window_manager.windows[-1].screen.areas[0]
        area.type = "IMAGE_EDITOR"
        area.spaces.active.image = image
        return {"FINISHED"}


def active_grid(data, name=""):
    """The Volume data's grid `name`, else its active grid (grids loaded on demand), or None
    when the file cannot be read. (Blender 3.4's VolumeGrids has active_index, not active.)"""
    grids = data.grids
    if not (grids.is_loaded or grids.load()) or not len(grids):
        return None
    found = next((g for g in grids if g.name == name), None) if name else None
    return found or grids[min(max(grids.active_index, 0), len(grids) - 1)]


def _remove_objects(objects):
    """Removes objects made by a run that failed half way, with their meshes."""
    for o in objects:
        me = o.data
        bpy.data.objects.remove(o)
        bpy.data.meshes.remove(me)


def _pair_hidden(obj, hidden):
    """The hidden-feature mesh shares the main mesh's summary; each is the other's partner (C6)."""
    hidden.isouq.summary = obj.isouq.summary
    obj.isouq.partner, hidden.isouq.partner = hidden, obj


def volume_mesh_matrix(volume, grid_name=""):
    """Where a mesh of a Volume object's grid goes so that it lies on Blender's own drawing of
    the Volume: Blender draws voxel (i, j, k) over the cell [i, i+1]^3 of index space (OpenVDB,
    and so isouq, put the sample at the point (i, j, k)), and its Volume to Mesh modifier shifts
    its meshes by half a voxel to match (measured: docs/sequences.md). isouq's meshes, in the
    grid's world space, get the Volume's matrix and the same half-voxel shift."""
    from mathutils import Matrix, Vector
    grid = active_grid(volume.data, grid_name)
    if grid is None:
        return volume.matrix_world.copy()
    index_to_object = grid.matrix_object
    half = index_to_object.to_3x3() @ Vector((0.5, 0.5, 0.5))
    return volume.matrix_world @ Matrix.Translation(half)


def volume_sequence(volume):
    """What `isouq mesh` needs for a Volume object whose file is a sequence (is_sequence): the
    #### pattern of its filepath, the frames Blender plays (frame_offset + 1 to
    frame_offset + frame_duration), and how scene frames map to them. Blender shows file frame
    scene - frame_start + 1 + frame_offset, so the mesh sequence's offset (file = scene +
    offset) is frame_offset + 1 - frame_start; its mode is the Volume's sequence_mode."""
    data = volume.data
    pattern = frames.pattern_of(bpy.path.abspath(data.filepath))
    first, count = data.frame_offset + 1, data.frame_duration
    if count <= 0:                      # Blender did not count the files: every frame on disk
        seq = frames.detect(pattern)
        first, count = seq.first, seq.last - seq.first + 1
    return {"pattern": pattern, "frames": f"{first}-{first + count - 1}", "total": count,
            "offset": data.frame_offset + 1 - data.frame_start, "mode": data.sequence_mode,
            "name": volume.name}


def menu_import(self, context):
    self.layout.operator(ISOUQ_OT_import_mesh.bl_idname, text="isouq mesh (.ply)")
    self.layout.operator(ISOUQ_OT_import_sequence.bl_idname, text="isouq mesh sequence (.ply)")


classes = (ISOUQ_OT_import_mesh, ISOUQ_OT_import_sequence, ISOUQ_OT_run_pipeline, ISOUQ_OT_apply_threshold,
           ISOUQ_OT_add_box, ISOUQ_OT_select_box, ISOUQ_OT_apply_methods,
           ISOUQ_OT_reset_positions, ISOUQ_OT_show_heatmap, ISOUQ_OT_plot_bars,
           ISOUQ_OT_compare_methods, ISOUQ_OT_show_hidden, ISOUQ_OT_combined_view,
           ISOUQ_OT_load_summary, ISOUQ_OT_render_view, ISOUQ_OT_open_plot)
