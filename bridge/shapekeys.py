"""Shape keys ↔ :class:`core.BlendshapeModel`."""
from __future__ import annotations

import numpy as np

from ..core.blendshape import BlendshapeModel, Combination, InBetween
from ..core.result import Issue, ShapeSpaceError
from ..core.validate import ABSURD_COORDINATE, ABSURD_MOVE, bad_coordinate, coordinates
from . import driven
from .arrays import read_float, write_float
from .meshes import group_weight_vector, vertex_groups


def shape_key_container(obj):
    """The object's ``Key`` datablock, or ``None``."""
    if obj is None or obj.type != "MESH":
        return None
    return obj.data.shape_keys


def check_shape_keys(obj) -> list:
    """Structural problems that make reading the rig impossible, as :class:`core.Issue` errors."""
    if obj is None:
        return [Issue("error", "no_object", "no object is selected")]
    if obj.type != "MESH":
        return [Issue("error", "not_mesh", f"{obj.name!r} is a {obj.type.lower()}, not a mesh")]
    key = obj.data.shape_keys
    if key is None or len(key.key_blocks) == 0:
        return [Issue("error", "no_shape_keys", f"mesh {obj.name!r} has no shape keys")]
    issues = []
    if len(key.key_blocks) == 1:
        issues.append(Issue("error", "no_targets",
                            f"mesh {obj.name!r} has only the basis key {key.key_blocks[0].name!r}, no targets"))
    if not key.use_relative:
        issues.append(Issue("error", "absolute_keys",
                            f"mesh {obj.name!r} uses absolute shape keys; ShapeSpace needs relative keys"))
    p = len(obj.data.vertices)
    if p == 0:
        return [Issue("error", "empty", f"mesh {obj.name!r} has no vertices")]
    wrong = [kb.name for kb in key.key_blocks if len(kb.data) != p]
    if wrong:
        issues.append(Issue("error", "vertex_count_mismatch",
                            f"mesh {obj.name!r} has {p} vertices but shape keys {', '.join(wrong[:5])} have "
                            f"{len(key.key_blocks[wrong[0]].data)}: the topology changed after the keys were made",
                            tuple(wrong)))
    return issues


def slider_names(obj, meta: dict = None) -> list:
    """Names of the object's sliders, in key order: the one definition of "which keys are sliders".

    A slider is a non-reference shape key that no ShapeSpace driver sets (in-betweens and combination
    shapes are driven by their primaries, see :mod:`bridge.driven`).  ``meta`` is the pruned driven-key
    metadata when the caller already has it.
    """
    key = obj.data.shape_keys
    if key is None:
        return []
    meta = driven.prune(key) if meta is None else meta
    driven_keys = set(meta["inbetweens"]) | set(meta["combinations"])
    return [kb.name for kb in key.key_blocks if kb != key.reference_key and kb.name not in driven_keys]


def _check_finite(obj, blocks, coords: dict) -> None:
    """Refuse NaN/inf coordinates or slider ranges, naming the key, the vertex and the field."""
    for kb in blocks:
        coordinates(coords[kb.name], f"shape key {kb.name!r} of {obj.name!r}",
                    fix="fix or delete the key (Check Rig lists every one)")
        for field in ("slider_min", "slider_max", "value"):
            value = getattr(kb, field)
            if not np.isfinite(value):
                raise ShapeSpaceError(f"shape key {kb.name!r} of {obj.name!r} has {field} = {value}",
                                      "non_finite")


def check_coordinates(obj, coords: dict, reference: str, role: str) -> None:
    """Refuse a rig with a NaN, infinite or absurd coordinate, naming ``role``, the object, the key, the vertex and
    the axis: every coordinate within :data:`~core.validate.ABSURD_COORDINATE`, and no key moving a vertex
    more than :data:`~core.validate.ABSURD_MOVE` head sizes (the reference key's bounding-box diagonal) from it.

    ``coords``: ``{key name: (p, 3) float64}``, ``reference`` among them.
    """
    for name, co in coords.items():
        coordinates(co, f"{role} {obj.name!r}: shape key {name!r}", ABSURD_COORDINATE)
    base = coords[reference]
    size = float(np.linalg.norm(np.ptp(base, axis=0))) if len(base) else 0.0
    for name, co in coords.items():
        found = bad_coordinate(co - base, ABSURD_MOVE * size) if size > 0 else None
        if found is not None:
            v, axis, move = found
            raise ShapeSpaceError(f"{role} {obj.name!r}: shape key {name!r} moves vertex {v} by {move:g} along "
                                  f"{'xyz'[axis]}, {abs(move) / size:.3g} head sizes; fix or delete the key",
                                  "non_finite")


def read_blendshape_model(obj, finite: bool = True) -> BlendshapeModel:
    """Read an object's relative shape keys as a :class:`core.BlendshapeModel`.

    ``finite`` (the default) refuses a rig with a NaN or infinite coordinate, slider range or value,
    naming the key and vertex; diagnostics (Check Rig) read with ``finite=False`` to report them.

    Raises
    ------
    core.ShapeSpaceError
        For the structural problems of :func:`check_shape_keys` and, with ``finite``, non-finite data.
    """
    errors = [i for i in check_shape_keys(obj) if i.severity == "error"]
    if errors:
        raise ShapeSpaceError(errors[0].message, errors[0].code)
    key = obj.data.shape_keys
    blocks = key.key_blocks
    ref = key.reference_key
    neutral = read_float(ref.points, "co", 3).astype(np.float64)   # points: the bulk accessor (~100x .data)
    meta = driven.prune(key)
    sliders = set(slider_names(obj, meta))
    targets = [kb for kb in blocks if kb.name in sliders]
    coords = {kb.name: read_float(kb.points, "co", 3).astype(np.float64) for kb in blocks}
    if finite:
        _check_finite(obj, blocks, coords)
    need_groups = any(kb.vertex_group for kb in targets)
    groups = vertex_groups(obj) if need_groups else None
    masks = {}

    def delta_of(kb):
        rel = kb.relative_key if kb.relative_key is not None else ref
        if rel == kb:  # a key relative to itself contributes nothing in Blender
            return np.zeros_like(neutral)
        d = coords[kb.name] - coords[rel.name]
        if kb.vertex_group:
            mask = group_weight_vector(obj, kb.vertex_group, groups)
            if mask is not None:  # Blender ignores a mask naming a missing group
                masks[kb.name] = mask
                d = d * mask[:, None]
        return d

    deltas = np.stack([delta_of(kb) for kb in targets]) if targets else np.zeros((0,) + neutral.shape)
    free = [kb.name for kb in targets]
    inbetweens = []
    for prim in sorted({v["primary"] for v in meta["inbetweens"].values()}):
        for name, knots in driven.knots_for(meta, prim).items():
            inbetweens.append(InBetween(name, free.index(prim), knots, delta_of(blocks[name])))
    combinations = [Combination(name, tuple(free.index(i) for i in v["inputs"]), delta_of(blocks[name]))
                    for name, v in sorted(meta["combinations"].items())]
    return BlendshapeModel(
        neutral=neutral,
        deltas=deltas,
        names=[kb.name for kb in targets],
        slider_min=np.array([kb.slider_min for kb in targets]),
        slider_max=np.array([kb.slider_max for kb in targets]),
        mute=np.array([kb.mute for kb in targets], dtype=bool),
        relative_to=[(kb.relative_key or ref).name for kb in targets],
        masks=masks,
        values=np.array([kb.value for kb in targets]),
        reference_name=ref.name,
        inbetweens=inbetweens,
        combinations=combinations,
    )


def read_slider_values(obj, names=None) -> np.ndarray:
    """Current ``value`` of the named keys (all non-reference keys by default), float64 (n,)."""
    key = obj.data.shape_keys
    if names is None:
        names = [kb.name for kb in key.key_blocks if kb != key.reference_key]
    blocks = key.key_blocks
    missing = [n for n in names if n not in blocks]
    if missing:
        raise ShapeSpaceError(f"{obj.name!r} has no shape keys named {', '.join(missing)}", "missing_key")
    return np.array([blocks[n].value for n in names], dtype=np.float64)


def write_slider_values(obj, names, values) -> None:
    """Set ``value`` of the named keys in one bulk write; clamped to each slider range as Blender does.

    Refuses (before writing anything) a non-finite value, naming the key: no solver can put NaN in a file.
    """
    key = obj.data.shape_keys
    blocks = key.key_blocks
    values = np.asarray(values, dtype=np.float64).ravel()
    if len(values) != len(names):
        raise ShapeSpaceError(f"{len(values)} values for {len(names)} shape keys", "shape")
    index = {name: i for i, name in enumerate(blocks.keys())}      # names in one call, not one RNA read per key
    missing = [n for n in names if n not in index]
    if missing:
        raise ShapeSpaceError(f"{obj.name!r} has no shape keys named {', '.join(missing)}", "missing_key")
    bad = np.flatnonzero(~np.isfinite(values))
    if bad.size:
        raise ShapeSpaceError(f"refusing to write {values[bad[0]]} into shape key {names[bad[0]]!r} of "
                              f"{obj.name!r}: nothing was changed", "non_finite")
    current = read_float(blocks, "value", 1).astype(np.float64)
    lo = read_float(blocks, "slider_min", 1)
    hi = read_float(blocks, "slider_max", 1)
    pos = np.fromiter((index[n] for n in names), dtype=np.int64, count=len(names))
    current[pos] = np.clip(values, lo[pos], hi[pos])
    write_float(blocks, "value", current)
    key.update_tag()
    obj.data.update_tag()


def add_shape_key(obj, name: str, positions, relative_to: str = None, from_mix: bool = False):
    """Create a shape key holding ``positions`` (p, 3) and return its name."""
    if obj.data.shape_keys is None:
        obj.shape_key_add(name="Basis", from_mix=False)
    kb = obj.shape_key_add(name=name, from_mix=from_mix)
    write_float(kb.data, "co", positions)
    if relative_to:
        kb.relative_key = obj.data.shape_keys.key_blocks[relative_to]
    obj.data.update()
    return kb.name
