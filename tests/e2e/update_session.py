"""Runs inside a fresh Python with bpy: a studio's update channel, end to end.

    python update_session.py REPO_DIR OLD_ZIP NEW_ZIP

Publishes OLD_ZIP into the static repository REPO_DIR (``tools/build.py``'s publish: Blender's
``extension server-generate``), adds it to Blender as a ``file://`` remote repository, installs ShapeSpace
from it with Blender's extensions API and enables it; then publishes NEW_ZIP (a higher version), syncs and
runs Install Available Updates (``extensions.package_upgrade_all``).  Prints one JSON line with what it saw.
The environment must already point BLENDER_USER_RESOURCES at a temporary folder.
"""
import contextlib
import importlib.util
import io
import json
import os
import sys
import tomllib

repo_dir, old_zip, new_zip = sys.argv[1:4]
ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
spec = importlib.util.spec_from_file_location("shapespace_build_tool", os.path.join(ROOT, "tools", "build.py"))
build = importlib.util.module_from_spec(spec)
spec.loader.exec_module(build)

import bpy  # noqa: E402

MODULE = "bl_ext.studio.shapespace"
seen = {"blender": bpy.app.version_string}
KEPT = []          # every module object seen stays alive, so a new one can never reuse an old one's id()


def state(tag):
    """What Blender has installed and enabled now: the manifest on disk, the loaded module's version, the CLI."""
    ext = sys.modules.get(MODULE)
    folder = os.path.join(bpy.utils.user_resource("EXTENSIONS"), "studio", "shapespace")
    manifest = os.path.join(folder, "blender_manifest.toml")
    seen[tag + "_enabled"] = [a.module for a in bpy.context.preferences.addons if "shapespace" in a.module]
    if os.path.isfile(manifest):
        with open(manifest, "rb") as fh:
            seen[tag + "_manifest"] = tomllib.load(fh)["version"]
    seen[tag + "_module_version"] = ext.core.version.version() if ext is not None else None
    seen[tag + "_module_file"] = getattr(ext, "__file__", None)
    KEPT.append(ext)
    seen[tag + "_module_id"] = id(ext) if ext is not None else None       # a new object once reloaded
    seen[tag + "_operator"] = hasattr(bpy.types, "SHAPESPACE_OT_check_rig")
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        seen[tag + "_cli_exit"] = ext.cli.main(["--version"]) if ext is not None else None
    seen[tag + "_cli_version"] = buf.getvalue().strip()


prefs = bpy.context.preferences
prefs.system.use_online_access = True          # a studio's Blender: installing from any remote repository needs it
index = build.publish([old_zip], repo_dir)
repo = prefs.extensions.repos.new(name="Studio", module="studio", remote_url="file://" + index)
seen["repo_url"] = repo.remote_url
repo_index = list(prefs.extensions.repos).index(repo)
seen["sync"] = sorted(bpy.ops.extensions.repo_sync(repo_index=repo_index))
seen["install"] = sorted(bpy.ops.extensions.package_install(repo_index=repo_index, pkg_id="shapespace",
                                                            enable_on_install=True))
state("installed")

build.publish([new_zip], repo_dir)               # the higher build: the old zip moves to previous/
seen["repo_files"] = sorted(os.listdir(repo_dir))
seen["previous_files"] = sorted(os.listdir(os.path.join(repo_dir, "previous")))
seen["resync"] = sorted(bpy.ops.extensions.repo_sync(repo_index=repo_index))
seen["upgrade"] = sorted(bpy.ops.extensions.package_upgrade_all())
state("upgraded")
print("E2E-RESULT " + json.dumps(seen))
