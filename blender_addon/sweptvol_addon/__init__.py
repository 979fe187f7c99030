"""sweptvol: one button from animated objects to their conservative swept volume.

Talks to `sweptvol watch` only through its folder exchange protocol
(docs/exchange-protocol.md in the sweptvol repository).
"""

bl_info = {
    "name": "sweptvol: swept volumes",
    "author": "sweptvol contributors",
    "version": (0, 1, 0),
    "blender": (3, 4, 0),
    "location": "3D View > Sidebar > Sweptvol",
    "description": "Conservative swept volume of animated objects, computed by `sweptvol watch`",
    "category": "Object",
}

import bpy  # noqa: E402

from . import daemon, operators, panel, prefs  # noqa: E402

_classes = prefs.classes + panel.classes + operators.classes


def register():
    for cls in _classes:
        bpy.utils.register_class(cls)
    panel.register()


def unregister():
    daemon.stop()
    if bpy.app.timers.is_registered(operators._poll_timer):
        bpy.app.timers.unregister(operators._poll_timer)
    panel.unregister()
    for cls in reversed(_classes):
        bpy.utils.unregister_class(cls)
