"""Runs inside a fresh Python with bpy: install the built zip with Blender's extensions API,
enable it, run an operator and the CLI handler.  Prints one JSON line with what it saw.

    python installed_session.py ZIP ASSET_GLB
The environment must already point BLENDER_USER_RESOURCES at a temporary folder.
"""
import contextlib
import importlib.util
import io
import json
import os
import sys

import numpy as np

zip_path, asset = sys.argv[1], sys.argv[2]
import bpy  # noqa: E402

seen = {"user_resources": bpy.utils.user_resource("EXTENSIONS"), "python": "%d.%d" % sys.version_info[:2],
        "blender": bpy.app.version_string,
        # before the install: can this Python import scipy without the extension's wheel?
        "venv_has_scipy": importlib.util.find_spec("scipy") is not None}
result = bpy.ops.extensions.package_install_files(filepath=zip_path, repo="user_default", enable_on_install=True)
seen["install"] = sorted(result)
seen["addons"] = [a.module for a in bpy.context.preferences.addons if "shapespace" in a.module]
ext = sys.modules.get("bl_ext.user_default.shapespace")
seen["module_file"] = getattr(ext, "__file__", None)
seen["cli_registered"] = bool(ext and ext.cli._registered)

site = os.path.join(bpy.utils.user_resource("EXTENSIONS"), ".local", "lib",
                    f"python{sys.version_info[0]}.{sys.version_info[1]}", "site-packages")
seen["wheel_dirs"] = sorted(d for d in os.listdir(site) if d.startswith("scipy")) if os.path.isdir(site) else []
seen["site_on_path"] = any(os.path.realpath(p) == os.path.realpath(site) for p in sys.path)
seen["site"] = os.path.realpath(site)
# which of the bundled wheels Blender installed: the compiled modules name their CPython (cpython-313)
lib = os.path.join(site, "scipy", "_lib")
seen["scipy_abis"] = sorted({n.split(".")[1].split("-")[1] for n in os.listdir(lib) if n.endswith(".so")}
                            if os.path.isdir(lib) else [])

bpy.ops.import_scene.gltf(filepath=asset)
head = bpy.data.objects["Mesh_2"]
bpy.context.view_layer.objects.active = head
seen["check_rig"] = sorted(bpy.ops.shapespace.check_rig())
bpy.context.scene.frame_set(10)
seen["key_sliders"] = sorted(bpy.ops.shapespace.key_sliders())

capture = head.data.shape_keys.animation_data.action
head.data.shape_keys.animation_data.action = None
seen["add_pin"] = sorted(bpy.ops.shapespace.add_pin(vertices=(100, 0, 0)))
target = tuple(head.shapespace.pins[0].target)
seen["solve_pins"] = sorted(bpy.ops.shapespace.solve_pins(pin=0, target=(target[0], target[1] - 800.0, target[2])))

# retargeting, smooth key reduction and the face-space tools run on the installed scipy wheel
seen["retarget"] = sorted(bpy.ops.shapespace.retarget(action=capture.name, method="spacetime", key_tolerance=0.01))
seen["analyse_rig"] = sorted(bpy.ops.shapespace.analyse_rig())
seen["learn_face_prior"] = sorted(bpy.ops.shapespace.learn_face_prior())
seen["prior_stored"] = "shapespace_face_prior" in head.data.shape_keys

scipy = sys.modules.get("scipy")
seen["scipy_file"] = os.path.realpath(scipy.__file__) if scipy is not None else None

# key reduction in a child process of this Blender (long takes): the installed core, the SciPy this process found
keyreduce = importlib.import_module("bl_ext.user_default.shapespace.core.keyreduce")
workers = importlib.import_module("bl_ext.user_default.shapespace.core.workers")
t = np.arange(400.0)
V = np.vstack([np.sin(t / s) * 0.3 + 0.01 * np.cos(t * 1.7) for s in (7.0, 19.0, 40.0)])
M = np.vstack([keyreduce.curve_slopes(t, v) for v in V])
got = workers.ChildCall("keyreduce", "_reduce_group", (t, V, M, 0.01, 128, True, None, 1)).result()
here = keyreduce._reduce_group(t, V, M, 0.01, 128, True)
seen["child_keys_usable"] = keyreduce._usable(got, V.shape[0], t.size)
seen["child_keys_equal"] = seen["child_keys_usable"] and all(
    all(np.array_equal(a, b) for a, b in zip(x, y)) for x, y in zip(got, here))
seen["child_core_root"] = os.path.realpath(workers._ROOT)

buf = io.StringIO()
with contextlib.redirect_stdout(buf):
    seen["cli_exit"] = ext.cli.main(["info"])
text = buf.getvalue()
seen["cli_json"] = json.loads(text[text.index("{"):])

bpy.ops.preferences.addon_disable(module="bl_ext.user_default.shapespace")
seen["after_disable_registered"] = hasattr(bpy.types, "SHAPESPACE_OT_check_rig")
print("E2E-RESULT " + json.dumps(seen))
