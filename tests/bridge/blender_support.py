"""Helpers for the Blender tiers (import after tests/conftest.py set the user folder)."""
import hashlib
import os
import tempfile
import time

import bpy
import numpy as np

import package  # tools/package.py

SS = package.load()
from shapespace.bridge import meshes  # noqa: E402
from shapespace.core.blendshape import bounding_box_diagonal  # noqa: E402
from support import ASSETS  # noqa: E402


def sphere_rig(keys: int = 3, name: str = "Face"):
    """A 12×6 UV sphere named ``name`` with a Basis and ``keys`` shape keys K0, K1, … (each the basis plus
    normal noise of 0.05, seed 0), active; ``keys=0`` gives a sphere without shape keys."""
    bpy.ops.mesh.primitive_uv_sphere_add(segments=12, ring_count=6)
    ob = bpy.context.active_object
    ob.name = name
    if keys:
        ob.shape_key_add(name="Basis")
        base = np.empty(len(ob.data.vertices) * 3, np.float32)
        ob.data.vertices.foreach_get("co", base)
        rng = np.random.default_rng(0)
        for k in range(keys):
            kb = ob.shape_key_add(name=f"K{k}")
            kb.data.foreach_set("co", (base + rng.normal(0, 0.05, base.size)).astype(np.float32))
    return ob


class _OperatorProps:
    """What ``layout.operator`` returns: setting a property checks it exists (and an enum value is allowed)."""

    def __init__(self, idname):
        group, name = idname.split(".")
        self._rna = getattr(getattr(bpy.ops, group), name).get_rna_type()
        self._idname = idname

    def __setattr__(self, name, value):
        if not name.startswith("_"):
            prop = self._rna.properties.get(name)
            assert prop is not None, f"{self._idname} has no property {name!r}"
            if prop.type == "ENUM":
                assert value in {e.identifier for e in prop.enum_items}, f"{self._idname}.{name} = {value!r}"
        object.__setattr__(self, name, value)


class RecordingLayout:
    """Stands in for a panel's ``layout`` (panels only draw in a window redraw, which headless ``bpy`` cannot run).

    Records the calls in ``log`` (``("label", text)``, ``("prop", name)``, ``("operator", idname)`` followed by
    ``("operator_props", props)`` — the properties the panel sets on that button —,
    ``("icon", id)``, ``("list", prop)``; :attr:`labels` the label texts) and checks the names a panel gives
    against the real RNA definitions (a renamed property, a typo in an operator name, an operator property
    or enum value that does not exist fail here, not in the artist's sidebar).  ``strict``: a layout call
    not listed here fails (an attribute error) and an icon must be a real one; else the call is accepted and
    returns a child layout (for drawing damaged or old data, where only the labels matter).  Children share
    the log.
    """

    def __init__(self, log=None, strict=True):
        self.log = [] if log is None else log
        self.strict = strict
        self.enabled = self.active = self.alert = True
        self.use_property_split = self.use_property_decorate = False
        self.scale_x = self.scale_y = 1.0

    @property
    def labels(self) -> list:
        """The texts of every label drawn, in order."""
        return [text for kind, text in self.log if kind == "label"]

    def _child(self, *args, **kwargs):
        return RecordingLayout(self.log, self.strict)

    row = column = box = split = column_flow = grid_flow = _child

    def __getattr__(self, name):
        if self.__dict__.get("strict", True) or name.startswith("__"):
            raise AttributeError(f"the recording layout has no {name!r}")
        return self._child

    def label(self, text="", icon="NONE", **kwargs):
        self.log.append(("label", text))

    def separator(self, **kwargs):
        pass

    def prop(self, data, name, **kwargs):
        assert name in data.bl_rna.properties, f"{data.bl_rna.identifier} has no property {name!r}"
        self.log.append(("prop", name))

    def prop_search(self, data, name, *args, **kwargs):
        assert name in data.bl_rna.properties, f"{data.bl_rna.identifier} has no property {name!r}"
        self.log.append(("prop", name))

    def operator(self, idname, **kwargs):
        group, name = idname.split(".")
        assert hasattr(getattr(bpy.ops, group), name), f"no operator {idname}"
        self.log.append(("operator", idname))
        props = _OperatorProps(idname)
        self.log.append(("operator_props", props))
        return props

    def template_icon(self, icon_value=0, scale=1.0):
        assert icon_value > 0 or not self.strict, "template_icon needs a real icon id"
        self.log.append(("icon", icon_value))

    def template_list(self, list_type, list_id, data, prop, active_data, active_prop, **kwargs):
        assert hasattr(bpy.types, list_type), f"no UIList {list_type}"
        assert prop in data.bl_rna.properties and active_prop in active_data.bl_rna.properties
        self.log.append(("list", prop))


def draw_panel(cls, context=None, strict=True, bl_idname=None) -> RecordingLayout:
    """Run panel class ``cls``'s ``draw`` on a :class:`RecordingLayout`; returns the layout (its ``log``)."""
    layout = RecordingLayout(strict=strict)
    call = type("PanelCall", (), {"layout": layout, "bl_idname": bl_idname or getattr(cls, "bl_idname", "")
                                  or cls.__name__})()
    cls.draw(call, context if context is not None else bpy.context)
    return layout


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


_CSV = os.path.join(ASSETS, "llf_fbhead", "MySlate_3_Jason_Millers_iPhone.csv")

#: every ShapeSpace operator → keyword arguments for an EXEC_DEFAULT call (what a script would pass).
OPERATOR_CALLS = {
    "check_rig": {}, "key_sliders": {},
    "add_inbetween": {"primary": "K0", "weight": 0.5}, "add_combination": {"first": "K0", "second": "K1"},
    "build_mirror_map": {}, "mirror_shape": {}, "split_shape": {}, "combine_shapes": {"other": "K0"},
    "update_mirrored": {},
    "add_pin": {"vertices": (3, 0, 0)}, "remove_pin": {"index": 0}, "clear_pins": {}, "mirror_pins": {},
    "solve_pins": {"pin": 0, "target": (0.0, 0.0, 1.0)},
    "psd_add_example": {}, "psd_apply_example": {}, "psd_remove_example": {}, "psd_update": {},
    "psd_bake": {"frame_start": 1, "frame_end": 2}, "psd_bake_cache": {"frame_start": 1, "frame_end": 2},
    "psd_move_example": {}, "psd_mirror_example": {}, "psd_add_target": {"data_path": '["x"]'},
    "psd_record_targets": {}, "psd_confidence": {},
    "reinvert_example": {}, "reinvert_all": {}, "capture_final_shape": {}, "push_sculpt_masked": {"groups": "G"},
    "apply_post_deform": {},
    "retarget": {"filepath": _CSV, "method": "copy"}, "discard_retarget": {},
    "set_mapping": {"source": "JawOpen", "target": "K0"}, "remove_mapping": {"source": "JawOpen"},
    "add_landmark": {"name": "chin", "vertex": 0}, "landmarks_from_shapes": {"source_object": "Other"},
    "transfer_shapes": {}, "propose_landmarks": {}, "add_landmark_pair": {"source_vertex": 0, "target_vertex": 0},
    "remove_landmark_pair": {}, "clear_landmark_pairs": {}, "preview_registration": {},
    "clear_registration_preview": {},
    "use_named_landmarks": {}, "place_named_landmark": {"name": "chin", "vertex": 0}, "mirror_named_landmarks": {},
    "clear_named_landmarks": {}, "add_transfer_example": {}, "remove_transfer_example": {"index": 0},
    "find_transfer_parts": {}, "select_transfer_part": {},
    "suggest_key_poses": {"filepath": _CSV},
    "analyse_rig": {}, "compression_report": {}, "convert_rig": {}, "make_convex": {},
    "fill_between": {"frame_start": 1, "frame_end": 3}, "find_implausible_frames": {}, "go_to_frame": {"frame": 2},
    "inpaint_gap": {"data_path": 'key_blocks["K0"].value', "frame_start": 2, "frame_end": 3},
    "learn_face_prior": {},
    # live capture (live_start opens a socket: it has its own loopback tests in test_live_stream.py)
    "live_stop": {}, "live_calibrate": {}, "live_record": {}, "live_stop_recording": {}, "live_play_take": {},
    "live_remove_take": {},
    # any rig's control sets (issue #25)
    "propose_controls": {}, "add_control_bones": {}, "add_control_property": {"data_path": '["x"]'},
    "remove_control": {"index": 0}, "toggle_control": {"index": 0, "enabled": False},
    "set_control_bounds": {"index": 0, "use_min": True, "min": -0.5}, "clear_controls": {}, "mirror_controls": {},
    "retarget_controls": {"filepath": _CSV},
    "export_for_engines": {"filepath": os.path.join(tempfile.mkdtemp(prefix="ss-export-"), "face.fbx"),
                           "format": "FBX"},
}

#: ShapeSpace operators not in :data:`OPERATOR_CALLS`, and where their bad input is tested instead.
NOT_CALLED = {
    "live_start": "opens a socket: its own loopback tests (test_live_stream.py, test_rig_live.py)",
    "drag_pins": "a modal tool driven by mouse events: its bridge functions (test_direct_manipulation.py)",
}


def _non_finite_count():
    bad = 0
    for ob in bpy.data.objects:
        if ob.type != "MESH" or ob.data.shape_keys is None:
            continue
        for kb in ob.data.shape_keys.key_blocks:
            co = np.empty(len(ob.data.vertices) * 3 if len(kb.data) == len(ob.data.vertices) else 0, np.float32)
            if co.size:
                kb.data.foreach_get("co", co)
            bad += int((~np.isfinite(co)).sum()) + int(not np.isfinite(kb.value))
    return bad


def _linked_state():
    out = []
    for ob in bpy.data.objects:
        if ob.library is None:
            continue
        pins = len(ob.shapespace.pins) if hasattr(ob, "shapespace") else 0
        keys = [(kb.name, kb.value) for kb in ob.data.shape_keys.key_blocks] if ob.data.shape_keys else []
        props = sorted(ob.data.shape_keys.keys()) if ob.data.shape_keys else []
        action = None
        if ob.data.shape_keys is not None and ob.data.shape_keys.animation_data is not None:
            action = getattr(ob.data.shape_keys.animation_data.action, "name", None)
        out.append((ob.name, pins, keys, props, action, len(ob.vertex_groups)))
    return out


def classify_operator_call(op_name: str, kwargs: dict):
    """Run ``bpy.ops.shapespace.<op_name>(**kwargs)`` and classify what happened (the reliability suites' rule).

    ``refused`` (poll with a specific message), ``cancelled`` (one-line report, file unchanged), ``finished``
    (nothing finite became NaN, linked data unchanged), else ``traceback``, ``refused_without_message``,
    ``silent_change``, ``nan_written`` or ``linked_changed``.
    """
    before, nan_before, linked_before = blend_fingerprint(), _non_finite_count(), _linked_state()
    op = getattr(bpy.ops.shapespace, op_name)
    try:
        result = op("EXEC_DEFAULT", **kwargs)
        message = ""
    except RuntimeError as exc:
        result, message = None, str(exc)
    except TypeError as exc:                  # an operator property the test passed does not exist
        raise AssertionError(f"{op_name}: {exc}") from None
    if "Traceback" in message or "Python:" in message:
        return "traceback", message
    if result is None and ".poll()" in message:
        return ("refused" if "context is incorrect" not in message else "refused_without_message"), message
    changed = blend_fingerprint() != before
    if result is None or result == {"CANCELLED"}:
        return ("cancelled" if not changed else "silent_change"), message
    if _non_finite_count() > nan_before:
        return "nan_written", message
    if _linked_state() != linked_before:
        return "linked_changed", message
    return "finished", message


def esc_mid_way(job, fraction: float, timeout: float) -> bool:
    """Poll a background job as the modal timer does until it reported ``fraction``, check it is still running,
    then press Esc (``job.cancel()``); returns whether the worker stopped within ``timeout`` seconds."""
    deadline = time.perf_counter() + 300.0
    while job.fraction < fraction and not job.done and time.perf_counter() < deadline:
        time.sleep(0.002)
    assert not job.done, "the job ended before it could be cancelled mid-way"
    job.cancel()
    return job.wait(timeout)
