"""Render the README's live-capture picture: FBHead (copy), ICT FaceKit (copy by name) and ICT FaceKit (solve
through the Face Cap template) driven by one frame received over a loopback socket, heads turned by bones.

    python tools/live_picture.py [--out docs/images/live_fbhead_ict.png]

The frame is the shipped Live Link Face recording's widest-open mouth, with a head turn and an eye glance
added (the take's own head channels are zero); it goes through the real receiver, timer tick and writes.
"""
from __future__ import annotations

import argparse
import os
import socket
import sys
import time

TOOLS = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, TOOLS)
import env  # noqa: E402

ASSETS = os.path.join(env.ROOT, "assets")
CSV = os.path.join(ASSETS, "llf_fbhead", "MySlate_3_Jason_Millers_iPhone.csv")
ICT = os.path.join(os.path.dirname(env.ROOT), "shared", "data", "ict_facekit", "ict_facekit_expressions.glb")


def _port() -> int:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def _head_rig(bpy, ob, name):
    """An armature whose head bone (from the bottom to the top of the mesh) carries the mesh (bone parent)."""
    from mathutils import Vector
    corners = [ob.matrix_world @ Vector(c) for c in ob.bound_box]
    centre = sum(corners, Vector()) / 8
    bottom = Vector((centre.x, centre.y, min(c.z for c in corners)))
    top = Vector((centre.x, centre.y, max(c.z for c in corners)))
    bpy.ops.object.armature_add(enter_editmode=True)
    arm = bpy.context.active_object
    arm.name = name
    bone = arm.data.edit_bones[0]
    bone.name, bone.head, bone.tail = "head", bottom, top
    bpy.ops.object.mode_set(mode="OBJECT")
    world = ob.matrix_world.copy()
    ob.parent, ob.parent_type, ob.parent_bone = arm, "BONE", "head"
    bpy.context.view_layer.update()
    ob.matrix_world = world                       # keep it where it was
    arm.hide_render = True
    return arm


def _drive(bpy, live_session, target, settings, packet, port):
    st = bpy.context.scene.shapespace_live
    for k, v in settings.items():
        setattr(st, k, v)
    st.address, st.port, st.target = "127.0.0.1", port, target
    live_session.start(bpy.context.scene, target)
    try:
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.sendto(packet, ("127.0.0.1", port))
        s.close()
        end = time.monotonic() + 5
        while time.monotonic() < end and live_session.status().frames < 1:
            live_session.tick()
            time.sleep(0.005)
        live_session.tick()
    finally:
        live_session.stop()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=os.path.join(env.ROOT, "docs", "images", "live_fbhead_ict.png"))
    args = ap.parse_args(argv)
    env.reexec_in("bpy50", os.path.abspath(__file__), sys.argv[1:] if argv is None else argv)
    sys.path.insert(0, os.path.join(env.ROOT, "tests"))
    import bpy
    import numpy as np

    import conftest  # noqa: F401  (a throw-away Blender user folder)
    import live_replay
    import package
    ss = package.load()
    ss.register()
    from demo import _render, _setup_render
    from shapespace.bridge import assets, retarget
    from shapespace.bridge.live import session

    assets.load(os.path.join(ASSETS, "llf_fbhead", "Live_Link_Face.blend"))
    for ob in [o for o in bpy.data.objects if o.type == "EMPTY"]:
        bpy.data.objects.remove(ob)
    assets.load(os.path.join(ASSETS, "facecap", "facecap_decoded.glb"), replace=False)
    assets.load(ICT, replace=False)
    assets.load(ICT, replace=False)
    fb, tpl = bpy.data.objects["FBHead"], bpy.data.objects["Mesh_2"]
    ict_copy, ict = sorted((o for o in bpy.data.objects if o.name.startswith("ICTFace")), key=lambda o: o.name)
    tpl.data.shape_keys.animation_data.action = None
    for ob in [o for o in bpy.data.objects if o.type in ("MESH", "EMPTY") and o not in (fb, ict, ict_copy)]:
        ob.hide_render = True
    retarget.landmarks_from_shapes(tpl, ict)
    from mathutils import Vector

    def lowest(ob):
        return min((ob.matrix_world @ Vector(c)).z for c in ob.bound_box)

    for k, ob in enumerate((ict_copy, ict), start=1):
        ob.scale = [fb.dimensions.x / ob.dimensions.x] * 3
        bpy.context.view_layer.update()
        ob.location = (fb.location.x + 1.4 * k * fb.dimensions.x, fb.location.y, ob.location.z)
        bpy.context.view_layer.update()
        ob.location.z += lowest(fb) - lowest(ob)
        bpy.context.view_layer.update()
    rigs = [_head_rig(bpy, ob, f"Rig{k}") for k, ob in enumerate((fb, ict_copy, ict))]

    rows = live_replay.read_rows(CSV)[2]
    values = list(rows[int(np.argmax([r[live_replay.LLF_CURVES.index("JawOpen")] for r in rows]))])
    values[52:55] = [0.35, -0.12, 0.06]            # head yaw, pitch, roll (radians)
    values[55:61] = [0.3, 0.1, 0.0, 0.3, 0.1, 0.0]
    packet = live_replay.encode_llf(values, 1000, 0.0)
    bones = dict(head_bone="head", neck_bone="", eye_left_bone="", eye_right_bone="")
    _drive(bpy, session, fb, dict(method="COPY", armature=rigs[0], **bones), packet, _port())
    _drive(bpy, session, ict_copy, dict(method="COPY", armature=rigs[1], **bones), packet, _port())
    _drive(bpy, session, ict, dict(method="SOLVE", template=tpl, armature=rigs[2], **bones), packet, _port())
    bpy.context.view_layer.update()
    _setup_render(bpy, np, [fb, ict_copy, ict], 900)
    scene = bpy.context.scene
    scene.render.resolution_y = 330
    scene.camera.data.ortho_scale *= 1.05
    os.makedirs(os.path.dirname(os.path.abspath(args.out)), exist_ok=True)
    _render(bpy, os.path.abspath(args.out))
    ss.unregister()
    print(args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
