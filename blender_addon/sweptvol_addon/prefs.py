"""Add-on preferences: the watched folder, the sweptvol binary, whether to start the daemon."""

import os
import shutil
import tempfile

import bpy


def addon_name():
    return __package__


class SWEPTVOL_AP_preferences(bpy.types.AddonPreferences):
    bl_idname = __package__

    watch_folder: bpy.props.StringProperty(
        name="Watched folder",
        description="The folder `sweptvol watch` watches; jobs are written into it",
        subtype="DIR_PATH",
        default=os.path.join(tempfile.gettempdir(), "sweptvol-jobs"),
    )
    sweptvol_binary: bpy.props.StringProperty(
        name="sweptvol binary",
        description="Path of the sweptvol program (empty: look it up on PATH)",
        subtype="FILE_PATH",
        default="",
    )
    auto_start: bpy.props.BoolProperty(
        name="Start the daemon when needed",
        description="Start `sweptvol watch` on the folder if no daemon runs there, and stop it "
        "when Blender exits",
        default=True,
    )
    backend: bpy.props.EnumProperty(
        name="Backend",
        description="Where jobs run (job.json `backend`)",
        items=[
            ("auto", "Auto", "The daemon's backend: a hardware GPU if there is one, else the CPU"),
            ("gpu", "GPU", "A GPU adapter (fails if the daemon has none)"),
            ("cpu", "CPU", "The CPU twin of the sweep"),
        ],
        default="auto",
    )

    def draw(self, context):
        col = self.layout.column()
        col.prop(self, "watch_folder")
        col.prop(self, "sweptvol_binary")
        col.prop(self, "auto_start")
        col.prop(self, "backend")


def get(context=None):
    context = context or bpy.context
    return context.preferences.addons[__package__].preferences


def watch_folder(prefs):
    return os.path.abspath(bpy.path.abspath(prefs.watch_folder)) if prefs.watch_folder else ""


def binary_path(prefs):
    """The sweptvol binary to start, or None if it cannot be found."""
    path = bpy.path.abspath(prefs.sweptvol_binary) if prefs.sweptvol_binary else ""
    if path:
        return path if os.path.isfile(path) and os.access(path, os.X_OK) else None
    return shutil.which("sweptvol")


classes = (SWEPTVOL_AP_preferences,)
