"""Live preview of pose-space correctives while posing and scrubbing (a depsgraph / frame handler).

Training a deformer is far slower than evaluating it, so the handler keeps the
trained models in :data:`CACHE`, a :class:`PreviewCache`: numbers only (core
models, example names, the last pose read), keyed by object name and checked
against the examples' revision and method, never Blender datablocks — so undo
or loading a file cannot leave stale references behind.  The cache is emptied
after undo, redo and file loads (a revision number can repeat across them) and
when the add-on is unregistered.
"""
from __future__ import annotations

from dataclasses import dataclass

import bpy
import numpy as np
from bpy.app.handlers import persistent

from ..bridge import posespace
from ..core.posespace import GPConfidence, PoseSpaceDeformer, ScalarDriver
from ..core.result import ShapeSpaceError


@dataclass
class TrainedPreview:
    """What the live preview of one mesh needs between updates (numbers only).

    Attributes
    ----------
    revision : int
        The examples' revision it was trained at (``shapespace_psd.revision``).
    method : str
        The method it was trained with (``shapespace_psd.method``).
    deformer : PoseSpaceDeformer
    names : list of str
        Example key names, in the deformer's order.
    driver : ScalarDriver or None
        The driven targets' interpolant.
    confidence : GPConfidence
        For the panel's live variance.
    last_pose : ndarray or None, shape (d,)
        The pose last written (nothing is written while it does not change).
    """

    revision: int
    method: str
    deformer: PoseSpaceDeformer
    names: list
    driver: ScalarDriver | None
    confidence: GPConfidence
    last_pose: np.ndarray | None = None

    def same_pose(self, pose: np.ndarray) -> bool:
        return (self.last_pose is not None and self.last_pose.shape == pose.shape
                and bool(np.allclose(self.last_pose, pose, atol=1e-9)))


class PreviewCache:
    """Trained live-preview models keyed by object name (see the module docstring).

    ``busy`` guards against re-entrance: writing key values from the handler triggers another
    depsgraph update.  ``stopped`` holds the names of objects whose preview failed but could not be
    turned off (linked data): they are skipped until the cache is cleared, so a failure is reported once.
    """

    def __init__(self):
        self._entries: dict[str, TrainedPreview] = {}
        self.stopped: set[str] = set()
        self.busy = False

    def get(self, name: str, revision: int, method: str) -> TrainedPreview | None:
        """The entry of object ``name`` if it was trained at this revision and method, else None."""
        entry = self._entries.get(name)
        if entry is None or entry.revision != revision or entry.method != method:
            return None
        return entry

    def put(self, name: str, entry: TrainedPreview) -> None:
        self._entries[name] = entry

    def invalidate(self, name: str) -> None:
        """Forget object ``name``'s models (retrained on its next update)."""
        self._entries.pop(name, None)

    def clear(self) -> None:
        """Forget every model (and every stopped object)."""
        self._entries.clear()
        self.stopped.clear()

    def __len__(self) -> int:
        return len(self._entries)

    def __contains__(self, name: str) -> bool:
        return name in self._entries


#: The live preview's cache (module-level on purpose: handlers are plain functions).
CACHE = PreviewCache()


def _train(obj) -> TrainedPreview:
    st = obj.shapespace_psd
    deformer, names = posespace.trained_deformer(obj)
    return TrainedPreview(st.revision, posespace.model_method(obj), deformer, names, posespace.target_driver(obj),
                          posespace.confidence_model(deformer))


def refresh(obj) -> bool:
    """Update ``obj``'s correctives if its pose changed; True when it wrote new values."""
    st = obj.shapespace_psd
    entry = CACHE.get(obj.name, st.revision, posespace.model_method(obj))
    if entry is None:
        entry = _train(obj)
        CACHE.put(obj.name, entry)
    pose = posespace.read_pose(obj)
    if entry.same_pose(pose):
        return False
    posespace.preview(obj, entry.deformer, entry.names, entry.driver, pose=pose)
    posespace.show_variance(obj, float(entry.confidence.variance(pose)))    # the panel's live confidence
    posespace.clear_preview_message(obj)
    entry.last_pose = pose
    return True


def _one_line(exc: Exception) -> str:
    """The first line of an error's message; unexpected errors (not ShapeSpaceError) named by type."""
    lines = str(exc).splitlines()
    text = lines[0] if lines else type(exc).__name__
    return text if isinstance(exc, ShapeSpaceError) else f"unexpected {type(exc).__name__}: {text}"


def _stop(obj, name: str, exc: Exception) -> None:
    """Stop previewing ``obj`` after a failure: Live Preview off, one line on the console, never a raise."""
    CACHE.invalidate(name)
    detail = _one_line(exc)
    try:
        posespace.stop_live_preview(obj, detail)
    except Exception:       # linked data cannot be changed: skip it from now on instead
        CACHE.stopped.add(name)
    print(f"ShapeSpace: Live Preview of {name!r} stopped: {detail}")


def _previewed(scene) -> list:
    """The meshes of ``scene`` with Live Preview on and examples to preview (not while in Edit Mode, where
    what the preview writes would be overwritten on leaving it)."""
    out = []
    for obj in scene.objects:
        if obj.type == "MESH" and obj.mode != "EDIT" and obj.name not in CACHE.stopped:
            st = obj.shapespace_psd
            if st.live_preview and len(st.examples):
                out.append(obj)
    return out


@persistent
def _on_update(scene, depsgraph=None):
    if CACHE.busy:
        return
    CACHE.busy = True
    try:
        for obj in _previewed(scene):
            name = obj.name
            try:
                refresh(obj)
            except Exception as exc:    # a handler must never raise: stop this object's preview, say why once
                _stop(obj, name, exc)
    except Exception as exc:            # the scene itself could not be read (never expected)
        print(f"ShapeSpace: Live Preview paused: {_one_line(exc)}")
    finally:
        CACHE.busy = False


@persistent
def _forget(*_args):
    CACHE.clear()


_UPDATE_HANDLERS = ("depsgraph_update_post", "frame_change_post")
_RESET_HANDLERS = ("undo_post", "redo_post", "load_post")


def register():
    for name in _UPDATE_HANDLERS:
        getattr(bpy.app.handlers, name).append(_on_update)
    for name in _RESET_HANDLERS:
        getattr(bpy.app.handlers, name).append(_forget)


def unregister():
    for names, fn in ((_UPDATE_HANDLERS, _on_update), (_RESET_HANDLERS, _forget)):
        for name in names:
            handlers = getattr(bpy.app.handlers, name)
            while fn in handlers:
                handlers.remove(fn)
    CACHE.clear()
