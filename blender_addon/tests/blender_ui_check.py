"""The add-on's interactive path (timers, panel, status bar, image editor) in a real Blender
window. Not part of CI (it needs an X server); run it under Xvfb:

    blender_addon/tests/run-ui-check.sh [SWEPTVOL_BINARY]

Presses `sweptvol.compute` without waiting, as the button does, and lets Blender's event loop
run: the timer must follow status.json, show progress in the panel and status bar, import the
result and report; then "Open depth images" must put a depth image into an image editor.
Exits 0 on success (the runner also fails on any Python traceback in Blender's output).
"""

import os
import sys
import time

import bpy

argv = sys.argv[sys.argv.index("--") + 1:]
zip_path, binary, work = argv
bpy.ops.preferences.addon_install(filepath=os.path.abspath(zip_path), overwrite=True)
bpy.ops.preferences.addon_enable(module="sweptvol_addon")
from sweptvol_addon import daemon, exchange, operators  # noqa: E402

prefs = bpy.context.preferences.addons["sweptvol_addon"].preferences
prefs.watch_folder = os.path.join(work, "jobs")
prefs.sweptvol_binary = os.path.abspath(binary)
prefs.backend = "cpu"

cube = bpy.data.objects["Cube"]
for f, x in ((1, 0.0), (12, 2.0)):
    cube.location.x = x
    cube.keyframe_insert("location", frame=f)
scene = bpy.context.scene
scene.frame_start, scene.frame_end = 1, 12
scene.sweptvol.accuracy = "RESOLUTION"
scene.sweptvol.resolution = 160
for o in scene.objects:
    o.select_set(o is cube)

SHOTS = os.environ.get("SWEPTVOL_UI_SCREENSHOTS")  # a folder: save screenshots there
view3d = next(a for a in bpy.context.screen.areas if a.type == "VIEW_3D")
view3d.spaces.active.show_region_ui = True  # the sidebar, so the panel draws
if SHOTS:  # 3.4 cannot pick a sidebar tab from Python: show the panel in the open one
    from sweptvol_addon import panel  # noqa: E402

    bpy.utils.unregister_class(panel.SWEPTVOL_PT_panel)
    panel.SWEPTVOL_PT_panel.bl_category = "Item"
    bpy.utils.register_class(panel.SWEPTVOL_PT_panel)

seen = {"lines": set(), "t0": time.monotonic(), "pressed": False}




def screenshot(name):
    if SHOTS:
        window = bpy.context.window_manager.windows[0]
        with bpy.context.temp_override(window=window, area=view3d, screen=window.screen):
            bpy.ops.wm.redraw_timer(type="DRAW_WIN_SWAP", iterations=1)
            bpy.ops.screen.screenshot(filepath=os.path.join(SHOTS, name + ".png"))


def finish(code, message):
    print(f"ui-check: {'PASS' if code == 0 else 'FAIL'}: {message}", flush=True)
    daemon.stop()
    os._exit(code)


def tick():
    try:
        if not seen["pressed"]:
            window = bpy.context.window_manager.windows[0]
            with bpy.context.temp_override(window=window, area=view3d):
                bpy.ops.sweptvol.compute()  # the button: returns at once
            seen["pressed"] = True
            return 0.1
        if time.monotonic() - seen["t0"] > 120:
            finish(1, f"timed out; lines seen {seen['lines']}")
        job = operators.JOBS[-1]
        seen["lines"].add(job["line"])
        if job["state"] not in exchange.FINISHED:
            if job["line"].startswith("running") and "running" not in seen:
                seen["running"] = True
                screenshot("running")
            return 0.1
        if job["state"] != "done":
            finish(1, f"job ended {job['state']}: {job['line']}")
        swept = bpy.data.collections["Swept Volumes"].objects[0]
        screenshot("done")
        window = bpy.context.window_manager.windows[0]
        with bpy.context.temp_override(window=window, area=view3d, screen=window.screen):
            bpy.ops.sweptvol.open_depth_images()
        editors = [a for w in bpy.context.window_manager.windows for a in w.screen.areas
                   if a.type == "IMAGE_EDITOR"]
        shown = [a.spaces.active.image.name for a in editors if a.spaces.active.image]
        if not any("depth-" in n for n in shown):
            finish(1, f"no depth image in an image editor (editors show {shown})")
        screenshot("depth")
        finish(0, f"imported {swept.name} ({len(swept.data.polygons)} faces) by the timer; "
                  f"progress lines seen: {sorted(seen['lines'])}; image editor shows {shown}")
    except Exception as e:  # a failure inside a timer must fail the check, not just print
        import traceback
        traceback.print_exc()
        finish(1, f"{type(e).__name__}: {e}")


bpy.app.timers.register(tick, first_interval=1.0)
