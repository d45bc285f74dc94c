"""Helpers for the Blender tiers (import after tests/conftest.py set the user folder)."""
import hashlib

import numpy as np
import bpy

import package  # tools/package.py

SS = package.load()
from shapespace.bridge import meshes  # noqa: E402
from shapespace.core.blendshape import bounding_box_diagonal  # noqa: E402


def import_file(path):
    """Import with Blender's own importer through the bridge; returns new object names."""
    from shapespace.bridge import assets
    return assets.load(path, replace=False)


def evaluated(obj):
    """Blender's own evaluated object-space positions (depsgraph), float64 (p, 3)."""
    bpy.context.view_layer.update()
    return meshes.evaluated_positions(obj, bpy.context.evaluated_depsgraph_get()).astype(np.float64)


def rel_error(a, b, ref=None):
    diag = bounding_box_diagonal(ref if ref is not None else b)
    return float(np.abs(np.asarray(a) - np.asarray(b)).max() / diag)


def blend_fingerprint() -> str:
    """Hash of the data a ShapeSpace operator could change: objects, keys, values, weights, actions."""
    h = hashlib.sha256()
    for ob in sorted(bpy.data.objects, key=lambda o: o.name):
        h.update(ob.name.encode())
        h.update(np.array(ob.matrix_world, dtype=np.float64).tobytes())
        if ob.type == "MESH":
            me = ob.data
            co = np.empty(len(me.vertices) * 3, np.float32)
            if co.size:
                me.vertices.foreach_get("co", co)
            h.update(co.tobytes())
            for v in me.vertices:
                for g in v.groups:
                    h.update(np.array([g.group, g.weight], np.float64).tobytes())
            if me.shape_keys:
                for kb in me.shape_keys.key_blocks:
                    h.update(kb.name.encode())
                    h.update(np.array([kb.value, kb.slider_min, kb.slider_max, kb.mute], np.float64).tobytes())
                    # len(kb.data) is unreliable on a 0-vertex mesh (Blender reports garbage there)
                    kco = np.empty(len(me.vertices) * 3 if len(kb.data) == len(me.vertices) else 0, np.float32)
                    if kco.size:
                        kb.data.foreach_get("co", kco)
                    h.update(kco.tobytes())
    h.update(",".join(sorted(a.name for a in bpy.data.actions)).encode())
    return h.hexdigest()
