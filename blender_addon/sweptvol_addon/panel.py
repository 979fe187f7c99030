"""The 3D View sidebar panel, the scene settings it shows, and the status bar line."""

import bpy

from . import exchange, operators, sampling


class SweptvolSettings(bpy.types.PropertyGroup):
    use_scene_range: bpy.props.BoolProperty(
        name="Scene range", description="Sweep the scene's frame range and step", default=True)
    frame_start: bpy.props.FloatProperty(name="Start", default=1.0)
    frame_end: bpy.props.FloatProperty(name="End", default=250.0)
    frame_step: bpy.props.FloatProperty(
        name="Step", description="Frames between samples (below 1: sub-frames)",
        default=1.0, min=0.001, soft_min=0.05)
    accuracy: bpy.props.EnumProperty(
        name="Accuracy",
        items=[("TOLERANCE", "Tolerance", "The guaranteed accuracy in scene units"),
               ("RESOLUTION", "Resolution", "Voxels along the longest edge of the grid")],
        default="TOLERANCE")
    tolerance: bpy.props.FloatProperty(
        name="Tolerance", description="ε_global: how far the result may reach beyond the swept "
        "volume (smaller is slower)", default=0.05, min=1e-6, subtype="DISTANCE", unit="LENGTH",
        precision=4)
    motion: bpy.props.EnumProperty(
        name="Motion",
        items=[("screw", "Continuous", "Cover the motion between samples: the screw motion from "
                "each sample to the next, with the bound stated for it"),
               ("discrete", "Samples only", "Cover only the sampled poses (the paper's method)")],
        default="screw")
    halvings: bpy.props.IntProperty(
        name="Halvings", description="Continuous motion: where Blender moves an object off the "
        "screw motion between two samples (Bezier easing, overshoot, constraints), halve that "
        "interval, at most this many times (0: keep the samples; the largest deviation is still "
        "measured and recorded on the result)", default=sampling.DEFAULT_HALVINGS, min=0, max=12)
    resolution: bpy.props.IntProperty(
        name="Resolution", description="Voxels along the longest grid edge", default=256,
        min=8, max=4096)
    obstacles: bpy.props.PointerProperty(
        name="Obstacles", type=bpy.types.Collection,
        description="Mesh objects of this collection are obstacles: each gets a guaranteed "
        "clearance interval, a verdict and a clearance map")
    reference: bpy.props.PointerProperty(
        name="Relative to", type=bpy.types.Object, poll=lambda self, o: o.type == "MESH",
        description="Sweep the selected objects in the frame of this moving object (it is an "
        "obstacle too); the results follow it")
    use_require_clearance: bpy.props.BoolProperty(
        name="Require clearance", description="Mark the job when an obstacle may come closer",
        default=False)
    require_clearance: bpy.props.FloatProperty(
        name="Clearance", description="The least clearance every obstacle must keep",
        default=0.0, min=0.0, subtype="DISTANCE", unit="LENGTH", precision=4)


class SWEPTVOL_PT_panel(bpy.types.Panel):
    bl_label = "Swept Volume"
    bl_idname = "SWEPTVOL_PT_panel"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "Sweptvol"

    def draw(self, context):
        layout = self.layout
        s = context.scene.sweptvol
        meshes = [o for o in context.selected_objects if o.type == "MESH"]
        box = layout.box()
        box.label(text=f"{len(meshes)} object(s) to sweep", icon="OBJECT_DATA")
        for o in meshes[:8]:
            box.label(text=o.name, icon="MESH_DATA")
        if len(meshes) > 8:
            box.label(text=f"... and {len(meshes) - 8} more")

        col = layout.column(align=True)
        col.prop(s, "use_scene_range")
        if s.use_scene_range:
            sc = context.scene
            col.label(text=f"frames {sc.frame_start}-{sc.frame_end}, step {sc.frame_step}")
        else:
            col.prop(s, "frame_start")
            col.prop(s, "frame_end")
            col.prop(s, "frame_step")
        col = layout.column(align=True)
        col.prop(s, "accuracy", expand=True)
        col.prop(s, "tolerance" if s.accuracy == "TOLERANCE" else "resolution")
        layout.prop(s, "motion")
        if s.motion == "screw":
            layout.prop(s, "halvings")
        col = layout.column(align=True)
        col.prop(s, "obstacles")
        col.prop(s, "reference")
        row = col.row(align=True)
        row.prop(s, "use_require_clearance", text="")
        sub = row.row()
        sub.enabled = s.use_require_clearance
        sub.prop(s, "require_clearance", text="Require clearance")
        row = layout.row()
        row.scale_y = 1.4
        row.operator("sweptvol.compute", icon="MOD_SOLIDIFY")

        active = [j for j in operators.JOBS if j["state"] not in exchange.FINISHED]
        for job in active:
            box = layout.box()
            box.label(text=job["label"], icon="TIME")
            box.label(text=job["line"])
            box.operator("sweptvol.cancel", icon="CANCEL").job = job["dir"]
        done = operators.last_job()
        if done is not None and done["state"] in exchange.FINISHED:
            box = layout.box()
            icon = "CHECKMARK" if done["state"] == "done" else "ERROR"
            box.label(text=f"{done['label']}: {done['line']}", icon=icon)
            icons = {"contact": "ERROR", "possible-contact": "QUESTION", "clear": "CHECKMARK"}
            for entry in done.get("clearance", []):
                box.label(text=entry["line"], icon=icons.get(entry["verdict"], "INFO"))
            if done["state"] == "done":
                row = box.row(align=True)
                row.operator("sweptvol.import_result", text="Re-import").job = done["dir"]
                row.operator("sweptvol.open_depth_images", icon="IMAGE_DATA").job = done["dir"]


def draw_status(self, context):
    active = [j for j in operators.JOBS if j["state"] not in exchange.FINISHED]
    if active:
        self.layout.label(text=f"sweptvol: {active[-1]['label']}: {active[-1]['line']}", icon="TIME")


classes = (SweptvolSettings, SWEPTVOL_PT_panel)


def register():
    bpy.types.Scene.sweptvol = bpy.props.PointerProperty(type=SweptvolSettings)
    bpy.types.STATUSBAR_HT_header.append(draw_status)


def unregister():
    bpy.types.STATUSBAR_HT_header.remove(draw_status)
    del bpy.types.Scene.sweptvol
