"""Setting the correctives (and driven targets) for the current pose.

Only the active method's correctives are ever on: PSD and Shape-by-Example set the example keys (weighted
PSD's key and muted examples' keys go to 0); weighted PSD sets its own key (every example key goes to 0).
Switching methods in any order therefore gives the method's own result.

Update Correctives at 30 fps: training is far slower than evaluating, so :func:`cached_model` keeps the
trained model of each mesh (numbers only, keyed by the object's ``session_uid``) with a fingerprint of
everything it was trained from — the examples' revision, method and distance option, readers, example
records, driven targets, armature and Armature modifiers, vertex and group counts — and a 64-bit checksum
of the basis and every corrective key's coordinates (read with the bulk ``ShapeKey.points`` accessor: a key
sculpted directly is seen).  Deform *weights* are not in the fingerprint (Blender has no bulk accessor for
them): after re-weighting, weighted PSD retrains at the next example change, like the Live Preview.
"""
from __future__ import annotations

import numpy as np

from ...core.cache import BoundedCache
from ...core.errors import ErrorCode
from ...core.result import ShapeSpaceError
from .. import shapekeys
from ..arrays import read_float, write_float
from .correctives import basis_positions, check_finite_positions, check_not_editing, example_keys, shape_keys
from .pose import read_pose, settings
from .stored import WPSD_KEY, wpsd_distance
from .targets import target_driver, write_targets
from .training import trained_deformer


def model_method(obj) -> str:
    """The method a trained model is for: ``st.method``, with weighted PSD's distance option (``WPSD:BLEND``)."""
    st = settings(obj)
    distance = wpsd_distance(st)
    return f"{st.method}:{distance}" if st.method == "WPSD" and distance != "SKIN" else st.method


class _Scratch:
    buf = np.zeros(0, dtype=np.float32)


def _checksum(key, names, n_vertices: int) -> tuple:
    """Per key (the reference key first), the 64-bit sum of its coordinates' bit patterns."""
    size = 3 * n_vertices + (3 * n_vertices) % 2
    if _Scratch.buf.size != size:
        _Scratch.buf = np.zeros(size, dtype=np.float32)
    buf = _Scratch.buf
    view, words = buf[:3 * n_vertices], buf.view(np.uint64)
    blocks = key.key_blocks
    out = []
    for kb in [key.reference_key] + [blocks[n] for n in names if n in blocks]:
        if len(kb.points) != n_vertices:
            return ("vertex count", kb.name, len(kb.points))
        kb.points.foreach_get("co", view)
        out.append(int(np.add.reduce(words, dtype=np.uint64)))
    return tuple(out)


def _fingerprint(obj) -> tuple:
    """Everything a trained model depends on except deform weights (see the module docstring)."""
    st = settings(obj)
    key = obj.data.shape_keys
    arm = st.armature
    mods = tuple((m.name, m.object.session_uid if m.object else 0, m.use_deform_preserve_volume, m.vertex_group,
                  m.invert_vertex_group, m.show_viewport) for m in obj.modifiers if m.type == "ARMATURE")
    examples = tuple((ex.name, ex.pose, ex.pseudo_pose, ex.mute, ex.target_values) for ex in st.examples)
    return (obj.data.session_uid, key.session_uid if key else 0, st.revision, model_method(obj),
            tuple((r.kind, r.source, r.scale) for r in st.readers), examples,
            tuple((t.owner.session_uid if t.owner else 0, t.data_path, t.index) for t in st.targets),
            arm.session_uid if arm else 0, mods, len(obj.data.vertices), len(obj.vertex_groups),
            tuple(g.name for g in obj.vertex_groups),
            _checksum(key, [ex.name for ex in st.examples], len(obj.data.vertices)) if key else ())


#: Trained models by object ``session_uid``: (fingerprint, deformer, names, driver); models of 30k vertices are
#: tens of MB, so four are kept.
MODELS = BoundedCache("trained pose-space models", capacity=4)


def forget_models() -> None:
    """Forget every cached model (they are retrained at their next use)."""
    MODELS.clear()


def cached_model(obj) -> tuple:
    """``(deformer, names, driver)`` of ``obj``, trained only when its fingerprint changed."""
    fp = _fingerprint(obj)
    entry = MODELS.get(obj.session_uid, valid=lambda e: e[0] == fp)
    if entry is not None:
        return entry[1:]
    deformer, names = trained_deformer(obj)
    driver = target_driver(obj)
    MODELS.put(obj.session_uid, (fp, deformer, names, driver))
    return deformer, names, driver


def preview(obj, deformer=None, names=None, driver=None, pose=None) -> np.ndarray:
    """Set the correctives (and driven targets) for the current pose.

    ``deformer``/``names`` (from :func:`trained_deformer`) and ``driver`` (from :func:`target_driver`) come
    from :func:`cached_model` when not given; ``pose``: the current pose when the caller has just read it
    (:func:`read_pose`).  Everything is computed before anything is written.  Returns the applied weights
    (PSD/SbE) or displacement (weighted PSD).
    """
    check_not_editing(obj)
    if deformer is None:
        deformer, names, cached_driver = cached_model(obj)
        driver = driver if driver is not None else cached_driver
    pose = read_pose(obj) if pose is None else np.asarray(pose, dtype=np.float64)
    driver = driver if driver is not None else target_driver(obj)
    targets = list(driver(pose).values()) if driver is not None else None
    if targets is not None and not np.isfinite(targets).all():
        raise _non_finite(obj, "driven target values")
    basis = None
    if deformer.method == "wpsd":
        if not deformer.fast_ready:
            basis = _basis(obj)
            deformer.prepare_fast(size=float(np.linalg.norm(np.ptp(basis, axis=0))) if len(basis) else None)
        disp = deformer.evaluate_fast(pose)
        check_finite_positions(disp, f"the weighted PSD corrective of {obj.name!r}")
        result = disp
    else:
        result = deformer.weights(pose)
        if not np.isfinite(result).all():
            raise _non_finite(obj, "example weights")
    if targets is not None:
        write_targets(obj, targets)
    if deformer.method == "wpsd":
        write_wpsd_preview(obj, result, basis)
    else:
        write_example_weights(obj, names, result)
    return result


def _non_finite(obj, what: str) -> ShapeSpaceError:
    return ShapeSpaceError(f"the pose-space {what} of {obj.name!r} are not finite", ErrorCode.NON_FINITE)


def _other_correctives(obj, names) -> list:
    """The correctives' keys that exist but are not among ``names`` (muted examples, weighted PSD's key)."""
    blocks = shape_keys(obj).key_blocks
    keep = set(names)
    return sorted(n for n in example_keys(obj) if n in blocks and n not in keep)


def write_example_weights(obj, names, weights) -> None:
    """PSD / Shape-by-Example: the example keys at ``weights``, every other corrective key at 0."""
    others = _other_correctives(obj, names)
    shapekeys.write_slider_values(obj, list(names) + others, np.concatenate([np.ravel(weights),
                                                                             np.zeros(len(others))]))


def _basis(obj) -> np.ndarray:
    """The reference key's positions (p, 3) float32, read with the bulk accessor; refused when non-finite."""
    key = shape_keys(obj)
    ref = key.reference_key
    if len(ref.points) != len(obj.data.vertices):
        return basis_positions(obj)                      # refuses with the vertex counts named
    co = read_float(ref.points, "co", 3)
    if not np.isfinite(co).all():
        return basis_positions(obj)                      # refuses naming the key and vertex
    return co


def write_wpsd_preview(obj, disp, basis=None) -> None:
    """Weighted PSD is per vertex: its result lives in one key; every example key stays at 0.

    ``basis``: the reference key's positions when the caller has them (read here otherwise).
    """
    key = shape_keys(obj)
    basis = _basis(obj) if basis is None else basis
    if WPSD_KEY not in key.key_blocks:
        obj.shape_key_add(name=WPSD_KEY, from_mix=False)
    key = obj.data.shape_keys
    kb = key.key_blocks[WPSD_KEY]
    write_float(kb.points if len(kb.points) == len(basis) else kb.data, "co", basis + disp)
    key.key_blocks[WPSD_KEY].value = 1.0
    zero = sorted(n for n in example_keys(obj) if n in key.key_blocks and n != WPSD_KEY)
    shapekeys.write_slider_values(obj, zero, np.zeros(len(zero)))


def stop_live_preview(obj, message: str) -> None:
    """Turn Live Preview off for ``obj`` and keep why (the panel shows it until the preview runs again)."""
    st = settings(obj)
    st.live_preview = False
    st.preview_message = message[:1000]


def clear_preview_message(obj) -> None:
    """Forget why Live Preview last stopped (written only when there is something to forget)."""
    st = settings(obj)
    if st.preview_message:
        st.preview_message = ""
