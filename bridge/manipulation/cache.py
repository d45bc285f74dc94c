"""The rig cache: a mesh's blendshape model, read once and kept while its shape keys stay the same.

Reading a production face's shape keys is the expensive part of a drag — every
coordinate of every key, float64 deltas for the solve (26,719 vertices × 58 keys
on ICT FaceKit: 45 ms; 105,569 × 151 on its subdivided variant: 1.3 s) — while
a solve and the slider write take well under a millisecond.
So the model is read once and kept in :data:`RIGS`, a :class:`RigCache`: one
:class:`RigEntry` per object, keyed by the object's ``session_uid`` (stable
across renames, never reused for another object), holding numbers only — the
model, the fingerprints it was read at, and what the drag derives from it
(crazy-space maps, see :mod:`.surface`) — never a Blender datablock, so
neither undo nor loading a file can leave a dangling reference behind.

When is an entry still right?  Blender keeps no counter of shape-key edits
that Python can read, so the cache combines three checks:

- a *structure* fingerprint read at every use (:func:`structure`, ~0.1 ms at
  150 keys): the object's mesh and key datablocks, the vertex count, key names,
  reference and relative keys, vertex-group masks, slider ranges, mute flags,
  the drivers and the stored in-between metadata;
- a *coordinate* checksum of every key (:func:`coordinate_checksum`: each key's
  coordinates read with the bulk ``ShapeKey.points`` accessor into one reused
  buffer, summed as 64-bit words — exact for any change of any bit — and a
  CRC of the reference key, which also catches a reordering of the vertices;
  1.7 ms at 27k vertices × 58 keys, 16 ms at 105k × 151), which a sample of
  coordinates could not replace: an edit of one vertex of one key must be seen;
- the depsgraph: :meth:`RigCache.on_depsgraph_update` (a
  ``depsgraph_update_post`` handler) marks an entry *suspect* when its Key or
  Mesh datablock was updated by anything but ShapeSpace's own slider writes
  (:func:`write_sliders` writes inside :meth:`RigCache.own_write` and
  evaluates the depsgraph at once, so no other edit can share that update;
  a live frame's writes on a cached rig go through :meth:`RigCache.own_update`,
  which evaluates what was pending first).
  Only a suspect entry pays for the checksum; an entry whose checksum and
  structure still match is kept (a slider moved in the UI), any other is read
  again.  Every use first evaluates the depsgraph (nothing to do when nothing
  changed), so an edit a script made just before — not yet evaluated, so not
  yet reported — is seen too.

So a drag, the next drag and every Solve Pins call reuse the model as long as
only ShapeSpace touched the rig, a slider moved by hand costs one checksum at
the next use, and an edited, added, deleted, renamed, re-ranged or muted key
— by the UI, an operator or a script — is never missed.  While the handlers
are not installed (:attr:`RigCache.tracking` false, e.g. the bridge used
without registering the add-on), for an object outside the active view layer
(whose edits no evaluated depsgraph reports), and on Blender before 4.5
(:data:`EDITS_REPORTED`: a script's ``foreach_set`` of key coordinates tags
nothing there), every use — each mouse move included — verifies the checksum.  Undo, redo
and loading a file empty the cache (:meth:`RigCache.clear`).  Deform weights
are not in the checksum: a rig whose keys use vertex-group masks is read again
instead of checksummed, and what is derived from the mesh for the deformers
(the crazy-space maps of :mod:`.surface`) carries its own fingerprint — pose,
modifier settings, the pinned vertices' deform weights — since it does not
depend on the key coordinates at all.
"""
from __future__ import annotations

import contextlib
import zlib
from collections import OrderedDict
from dataclasses import dataclass, field

import bpy
import numpy as np

from ...core.blendshape import BlendshapeModel
from .. import driven, shapekeys

__all__ = ["RigCache", "RigEntry", "RIGS", "EDITS_REPORTED", "structure", "coordinate_checksum", "write_sliders",
           "rig_model"]

#: Whether this Blender reports every edit of key coordinates to the depsgraph: from 4.5 a ``foreach_set`` on
#: ``ShapeKey.data``/``points`` tags the Key as a single-point edit always did; 4.2 tags nothing for it.
EDITS_REPORTED = bpy.app.version >= (4, 5, 0)


def _ids(obj) -> tuple:
    """``(object, mesh, key)`` pointers and the mesh's and key's ``session_uid``: which datablocks a model is of."""
    me = obj.data
    key = me.shape_keys
    return (obj.as_pointer(), me.as_pointer(), key.as_pointer() if key else 0, me.session_uid,
            key.session_uid if key else 0)


def _drivers(key) -> tuple:
    """The Key's drivers as plain values (in-betweens and combinations are re-derived from them)."""
    ad = key.animation_data
    if ad is None:
        return ()
    out = []
    for fc in ad.drivers:
        drv = fc.driver
        out.append((fc.data_path, fc.array_index, drv.type, drv.expression, len(fc.modifiers),
                    tuple((v.name, v.type, v.targets[0].data_path,
                           v.targets[0].id.session_uid if v.targets[0].id else 0) for v in drv.variables)))
    return tuple(out)


def structure(obj) -> tuple:
    """Everything the model is read from except the key coordinates, as a comparable tuple (~0.1 ms).

    Vertex count, key names, reference and relative keys, vertex-group masks (and the object's group names
    when a key uses one), slider ranges, mute flags, drivers and the stored in-between metadata.
    """
    me = obj.data
    key = me.shape_keys
    blocks = key.key_blocks
    n = len(blocks)
    ranges = np.empty(2 * n, dtype=np.float32)
    blocks.foreach_get("slider_min", ranges[:n])
    blocks.foreach_get("slider_max", ranges[n:])
    mute = np.empty(n, dtype=bool)
    blocks.foreach_get("mute", mute)
    groups = tuple(kb.vertex_group for kb in blocks)
    meta = key.get(driven.PROP)
    ref = key.reference_key
    return (len(me.vertices), key.use_relative, ref.name if ref else None, tuple(blocks.keys()),
            tuple(kb.relative_key.name for kb in blocks), groups,
            tuple(g.name for g in obj.vertex_groups) if any(groups) else (), ranges.tobytes(), mute.tobytes(),
            _drivers(key), None if meta is None else str(meta))


class _Scratch:
    """One reused float32 buffer for reading key coordinates (grown when a larger mesh comes along)."""

    def __init__(self):
        self._buf = np.zeros(0, dtype=np.float32)

    def get(self, size: int) -> np.ndarray:
        """A zero-padded buffer of at least ``size`` floats and even length (it is summed as 64-bit words)."""
        need = size + (size % 2)
        if self._buf.size < need or self._buf.size > 4 * need:
            self._buf = np.zeros(need, dtype=np.float32)
        buf = self._buf[:need]
        buf[size:] = 0.0
        return buf


def coordinate_checksum(key, n_vertices: int, scratch: _Scratch) -> tuple:
    """Per key, the 64-bit sum of its coordinates' bit patterns, and a CRC of the reference key's.

    A change of any bit of any coordinate changes its key's sum (unless another change cancels it exactly
    in the same 64-bit word sum); the CRC orders the vertices, so a reordering of the mesh is seen too.
    """
    size = 3 * n_vertices
    buf = scratch.get(size)
    view, words = buf[:size], buf.view(np.uint64)
    sums = []
    for kb in key.key_blocks:
        kb.points.foreach_get("co", view)
        sums.append(int(np.add.reduce(words, dtype=np.uint64)))
    if key.reference_key is None:
        return tuple(sums)
    key.reference_key.points.foreach_get("co", view)
    return tuple(sums) + (zlib.crc32(view),)


@dataclass(eq=False)
class RigEntry:
    """One object's cached model and what it was read at (numbers only; see the module docstring).

    Attributes
    ----------
    uid : int
        The object's ``session_uid``.
    ids : tuple
        Object, mesh and key pointers and the mesh's and key's ``session_uid`` (:func:`_ids`).
    structure : tuple
        :func:`structure` when the model was read or last verified.
    checksum : tuple
        :func:`coordinate_checksum` when the model was read or last verified.
    model : BlendshapeModel
        Its ``values`` are refreshed from the sliders at every use.
    slider_pos : ndarray of int, shape (n,)
        Index of each model slider in the key's ``key_blocks``.
    masked : bool
        Some key uses a vertex-group mask (deform weights are not in the checksum: verify by reading again).
    suspect : bool
        The depsgraph reported an update of the mesh or key that ShapeSpace did not make.
    writing : bool
        Inside :meth:`RigCache.own_write`.
    derived : dict
        What other modules derive from the object (e.g. the crazy-space map), each checked against its own
        fingerprint; dropped with the entry when the model is read again.
    """

    uid: int
    ids: tuple
    structure: tuple
    checksum: tuple
    model: BlendshapeModel
    slider_pos: np.ndarray
    masked: bool
    suspect: bool = False
    writing: bool = False
    derived: dict = field(default_factory=dict)

    @property
    def data_uids(self) -> tuple:
        """``session_uid`` of the mesh and of the key."""
        return self.ids[3], self.ids[4]


class RigCache:
    """The models of the meshes being dragged, keyed by object ``session_uid`` (see the module docstring).

    The one module-level instance is :data:`RIGS`.  At most ``capacity`` entries are kept (least recently
    used dropped first): a 105k-vertex, 150-key model holds about 380 MB of float64 deltas.

    Attributes
    ----------
    tracking : bool
        The depsgraph handler is installed (:meth:`install`); without it every use verifies the checksum.
    reads, verifications : int
        How many models were read and how many checksums were computed (for tests and benchmarks).
    """

    def __init__(self, capacity: int = 4):
        self.capacity = capacity
        self._entries: OrderedDict[int, RigEntry] = OrderedDict()
        self._scratch = _Scratch()
        self.tracking = False
        self.reads = 0
        self.verifications = 0

    def __len__(self) -> int:
        return len(self._entries)

    def clear(self) -> None:
        """Forget every entry (after undo, redo, loading a file, unregistering)."""
        self._entries.clear()

    def forget(self, obj) -> None:
        """Forget ``obj``'s entry."""
        self._entries.pop(obj.session_uid, None)

    # ------------------------------------------------------------------ lookups
    def peek(self, obj) -> RigEntry | None:
        """``obj``'s entry if there is one for these datablocks (not verified, never read): a place to keep
        data derived from the object that is checked against its own fingerprint."""
        entry = self._entries.get(obj.session_uid)
        if entry is None or obj.type != "MESH" or entry.ids != _ids(obj):
            return None
        return entry

    def entry(self, obj, trust: bool = False) -> RigEntry:
        """``obj``'s entry, verified (or read) as the module docstring says.

        ``trust`` skips the structure fingerprint when the depsgraph reported nothing since the last use
        (the per-mouse-move path of a drag); the key and vertex counts are still compared.

        Raises
        ------
        core.ShapeSpaceError
            When the rig cannot be read (no shape keys, NaN, …; see :func:`bridge.shapekeys.read_blendshape_model`).
        """
        uid = obj.session_uid
        entry = self._entries.get(uid)
        if entry is not None and self._tracked(obj):
            bpy.context.evaluated_depsgraph_get()       # edits not yet evaluated are reported (suspect) first
        me = obj.data if obj.type == "MESH" else None
        key = me.shape_keys if me is not None else None
        if entry is not None and key is not None and entry.ids == _ids(obj):
            if trust and self._tracked(obj) and not entry.suspect and \
                    len(key.key_blocks) == len(entry.structure[3]) and len(me.vertices) == entry.structure[0]:
                return self._refreshed(entry, key)
            if self._still_valid(obj, entry):
                self._entries.move_to_end(uid)
                return self._refreshed(entry, key)
        self._entries.pop(uid, None)
        return self._refreshed(self._read(obj), obj.data.shape_keys)

    def model(self, obj) -> BlendshapeModel:
        """``obj``'s model (verified), its ``values`` the sliders as they are now."""
        return self.entry(obj).model

    def _still_valid(self, obj, entry: RigEntry) -> bool:
        st = structure(obj)
        if st != entry.structure:
            return False
        if self._tracked(obj) and not entry.suspect:
            return True
        if entry.masked:
            return False
        self.verifications += 1
        if coordinate_checksum(obj.data.shape_keys, entry.structure[0], self._scratch) != entry.checksum:
            return False
        entry.suspect = False
        return True

    def _tracked(self, obj) -> bool:
        """The depsgraph handler would have reported an edit of ``obj`` (installed, object in the view layer)."""
        return self.tracking and EDITS_REPORTED and bpy.context.view_layer.objects.get(obj.name) == obj

    def _read(self, obj) -> RigEntry:
        model = shapekeys.read_blendshape_model(obj)            # refuses a bad rig before anything is kept
        key = obj.data.shape_keys
        st = structure(obj)
        checksum = coordinate_checksum(key, st[0], self._scratch)
        index = {name: i for i, name in enumerate(st[3])}
        entry = RigEntry(uid=obj.session_uid, ids=_ids(obj), structure=st, checksum=checksum, model=model,
                         slider_pos=np.array([index[n] for n in model.names], dtype=np.int64),
                         masked=any(st[5]))
        self.reads += 1
        self._entries[entry.uid] = entry
        while len(self._entries) > self.capacity:
            self._entries.popitem(last=False)
        return entry

    @staticmethod
    def _refreshed(entry: RigEntry, key) -> RigEntry:
        """The entry with its model's ``values`` set to the sliders now (one bulk read)."""
        values = np.empty(len(key.key_blocks), dtype=np.float32)
        key.key_blocks.foreach_get("value", values)
        entry.model.values = values[entry.slider_pos].astype(np.float64)
        return entry

    # ------------------------------------------------------------------ writes and the depsgraph
    @contextlib.contextmanager
    def own_write(self, obj):
        """Around a ShapeSpace write of ``obj``'s sliders: the depsgraph update it causes is not suspicious.

        The block must end by evaluating the depsgraph (so the update is reported while the flag is set).
        """
        entry = self._entries.get(obj.session_uid)
        if entry is None:
            yield
            return
        entry.writing = True
        try:
            yield
        finally:
            entry.writing = False

    @contextlib.contextmanager
    def own_update(self, obj):
        """Around ShapeSpace's writes of ``obj``'s sliders outside a drag (a live frame): its own update too.

        Only when this cache holds ``obj`` and would be told of edits (:meth:`_tracked`): whatever is pending
        is evaluated first, so an edit someone else made is still reported as theirs, then the block's writes
        are evaluated at once inside :meth:`own_write` — the next drag or Solve Pins pays no checksum of every
        key coordinate.  Otherwise nothing is evaluated here: the viewport evaluates the writes as before.
        """
        if self.peek(obj) is None or not self._tracked(obj):
            yield
            return
        bpy.context.evaluated_depsgraph_get()
        with self.own_write(obj):
            yield
            bpy.context.evaluated_depsgraph_get()

    def on_depsgraph_update(self, depsgraph) -> None:
        """``depsgraph_update_post``: mark entries whose mesh or key was updated by someone else suspect."""
        if not self._entries:
            return
        touched = set()
        for update in depsgraph.updates:
            id_ = update.id
            if isinstance(id_, (bpy.types.Key, bpy.types.Mesh)):
                touched.add(id_.original.session_uid)
        if not touched:
            return
        for entry in self._entries.values():
            if not entry.writing and touched.intersection(entry.data_uids):
                entry.suspect = True

    def install(self) -> None:
        """Start tracking (the add-on's ``register`` installs the handlers that call this cache)."""
        self.clear()
        self.tracking = True

    def uninstall(self) -> None:
        """Stop tracking and forget everything."""
        self.clear()
        self.tracking = False


def rig_model(obj) -> BlendshapeModel:
    """``obj``'s blendshape model from the rig cache (read once, verified; ``values``: the sliders now)."""
    return RIGS.model(obj)


def write_sliders(obj, names, values) -> None:
    """Write sliders (one bulk write) and evaluate the depsgraph at once, as ShapeSpace's own update.

    The one depsgraph update of a mouse move; :meth:`RigCache.own_write` keeps it from marking the cached
    model suspect.  Refuses a non-finite value, naming the key, before writing anything.
    """
    with RIGS.own_write(obj):
        shapekeys.write_slider_values(obj, names, values)
        bpy.context.evaluated_depsgraph_get()


#: The rig cache of this Blender session (the one module-level cache of pin-and-drag; see :class:`RigCache`).
RIGS = RigCache()
