"""The registry of stored data: every versioned JSON blob ShapeSpace keeps in a .blend, declared once.

Each :class:`Blob` names its owner (the kind of Blender data it lives on), its property and its
:class:`~core.schema.Schema`.  :mod:`bridge.storage` walks :data:`BLOBS` to upgrade older blobs before a save
and to find damaged ones for Check Rig; the module that reads and writes a blob takes its schema from here
(this module imports nothing but :mod:`core.schema`, so nothing imports back).  A new blob is one
:class:`Blob` added to :data:`BLOBS` (``tests/core/test_blobs.py`` fails on a :class:`Schema` made anywhere
else).

Owners (:data:`OWNERS`): ``"Object"``, ``"Mesh"``, ``"Key"`` (the shape-key datablock) and ``"Action"`` keep
the blob as an ID custom property (``id[prop]``); ``"Example"`` is a pose-space example
(``SHAPESPACE_PG_example``), which keeps it in its string property ``prop``.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

from .schema import Schema

__all__ = ["OWNERS", "ID_OWNERS", "Blob", "BLOBS", "schemas"]

#: ID types that keep blobs as custom properties.
ID_OWNERS = ("Object", "Mesh", "Key", "Action")
#: Every kind of owner a blob can have.
OWNERS = ID_OWNERS + ("Example",)


@dataclass(frozen=True)
class Blob:
    """One stored blob.

    Attributes
    ----------
    owner : str
        One of :data:`OWNERS`.
    prop : str
        The ID custom property (``key["shapespace_mapping"]``) or, for an ``"Example"``, the string property.
    schema : Schema
    sections : mapping of str to Schema
        Reports nested in the blob (``{field: schema}``), each checked against its own schema.
    """

    owner: str
    prop: str
    schema: Schema
    sections: Mapping[str, Schema] = field(default_factory=dict)

    @property
    def on_id(self) -> bool:
        """Whether the blob is an ID custom property (else a PropertyGroup's string property)."""
        return self.owner in ID_OWNERS


# ------------------------------------------------------------------ shape keys (Key)
def _driven_v0(data: dict) -> dict:
    data.setdefault("inbetweens", {})
    data.setdefault("combinations", {})
    return data


#: ``{"inbetweens": {key: {"primary": str, "at": float}}, "combinations": {key: {"inputs": [str]}}}``
#: (:mod:`bridge.driven`).
DRIVEN = Blob("Key", "shapespace_driven", Schema(
    "driven in-betweens and combinations", 1, fields={"inbetweens": "object", "combinations": "object"},
    migrations={0: _driven_v0}))

#: The retarget channel-mapping overrides ``{source channel: {target, gain, offset}}`` (:mod:`bridge.retarget`).
RETARGET_MAPPING = Blob("Key", "shapespace_mapping", Schema("retarget channel mapping", 1, values="object"))

#: The last retarget's report (:mod:`bridge.retarget`).
RETARGET_LAST = Blob("Key", "shapespace_last_retarget", Schema(
    "last retarget result", 1,
    fields={"source": "string", "method": "string", "frames": "int", "position_error_rms": "number?",
            "velocity_error_rms": "number?", "clipping_frames": "int", "action": "string",
            "previous_action": "string"},
    optional={"mapped_channels": "int", "keys_kept_frac": "number?", "converged": "bool",
              "position_error_mm": "number?", "velocity_error_mm": "number?",
              "previous_fake_user": "bool", "clipped_frames": "list", "frame_range": "list",
              "scene_range_extended": "bool", "scene_range_before": "list", "bones": "list",
              "bones_action": "string", "armature": "string", "armature_previous": "list"}))

#: The last transfer's verdict on a target (:mod:`bridge.authoring`).
TRANSFER_LAST = Blob("Key", "shapespace_last_transfer", Schema(
    "last transfer checks", 1,
    fields={"source": "string", "status": "string", "failed": "list", "parts": "list", "openings": "list"}))

#: What a converted copy is: ``form`` "whole_face" (with ``convex`` and ``neutral_keys``, the keys sharing the
#: neutral's weight; absent in files of 0.1.0) or "pca" (with the source ``sliders`` and the slider map ``A``
#: (m, n), ``a`` (m,)) (:mod:`bridge.facespace`).
REPRESENTATION = Blob("Key", "shapespace_representation", Schema(
    "face-space representation", version=1, fields={"form": "string", "source": "string"},
    optional={"convex": "bool", "neutral_keys": "list", "sliders": "list", "A": "list", "a": "list"}))

#: The learnt face Gaussian, see :class:`core.facespace.FaceGaussian` (:mod:`bridge.facespace`).
FACE_PRIOR = Blob("Key", "shapespace_face_prior", Schema(
    "face prior", version=1,
    fields={"names": "list", "mean": "list", "eigvecs": "list", "eigvals": "list", "dimension": "number",
            "ridge": "number", "regularised": "bool", "message": "string"},
    optional={"frames": "int"}))

#: The last compression report and rig analysis, for the panel (:mod:`bridge.facespace`); each report is a
#: section with its own schema.
ANALYSIS = Blob("Key", "shapespace_analysis", Schema(
    "face-space analysis", version=1, optional={"compression": "object", "coherence": "object"}),
    sections={
        "compression": Schema("compression report", version=1,
                              fields={"components": "int?", "targets": "int", "tol": "number", "ratio": "number?"},
                              optional={"frames": "int", "animation_rank": "int", "rig_rank": "int",
                                        "message": "string"}),
        "coherence": Schema("rig analysis", version=1,
                            fields={"image": "string", "mutual_coherence": "number?", "empty_targets": "list",
                                    "similar_pairs": "list"},
                            optional={"targets": "int", "png": "string", "sparsity": "object",
                                      "sparsity_message": "string"})})

# ------------------------------------------------------------------ meshes (Mesh)
#: ``{"mirror": [int], "axis": int, "offset": float, "method": str, "tolerance": float,
#: "topology": {"vertices", "edges", "faces", "edge_hash"}, "coverage": float}`` (:mod:`bridge.symmetry`).
MIRROR_MAP = Blob("Mesh", "shapespace_mirror_map", Schema(
    "mirror map", 1, fields={"mirror": "list", "axis": "int", "offset": "number", "method": "string",
                             "tolerance": "number", "topology": "object", "coverage": "number"},
    optional={"centre_edge": "list?"}))

#: ``{"landmarks": {name: vertex index}, "vertices": vertex count when placed}``
#: (:mod:`bridge.named_landmarks`).
NAMED_LANDMARKS = Blob("Mesh", "shapespace_named_landmarks", Schema(
    "named landmarks", 1, fields={"landmarks": "object", "vertices": "int"}))

# ------------------------------------------------------------------ objects (Object)
#: A transfer target's landmark pairs ``{"pairs": [[source vertex, target vertex], …], "source_vertices": int,
#: "target_vertices": int}``: the vertex counts the pairs were placed on (:mod:`bridge.authoring`).
LANDMARK_PAIRS = Blob("Object", "shapespace_landmarks", Schema(
    "transfer landmark pairs", 1, fields={"pairs": "list", "source_vertices": "int", "target_vertices": "int"}))

#: A face's stored control set (issue #25): the armature and, per channel, kind, object, owner (bone, property,
#: key), data path, axis, bounds override and enabled (:mod:`bridge.rig.stored`; entries: :mod:`core.rig.stored`).
CONTROL_SET = Blob("Object", "shapespace_controls", Schema(
    "control set", 1, fields={"armature": "string", "channels": "list"}))

#: The last retarget onto a face's rig controls (issue #25): what *Discard Result* needs to give every keyed
#: datablock back its action and every channel its value (:mod:`bridge.rig.last_take`).
RIG_RETARGET_LAST = Blob("Object", "shapespace_last_rig_retarget", Schema(
    "last rig retarget", 1, fields={"channels": "list", "actions": "list", "values_before": "list",
                                    "summary": "string"}))

# ------------------------------------------------------------------ actions (Action)
#: A live take's metadata (:mod:`bridge.live.recording`).
LIVE_TAKE = Blob("Action", "shapespace_live_take", Schema(
    "live take", 1,
    fields={"source": "string", "target": "string", "method": "string", "start_timecode": "string",
            "start_seconds": "number", "scene_fps": "number", "start_frame": "number", "frames": "int",
            "complete": "bool"},
    optional={"subject": "string", "armature": "string", "bones_action": "string", "clean_action": "string",
              "clean_bones_action": "string"}))

# ------------------------------------------------------------------ pose-space examples (Example)
#: Where in pose space an example was sculpted (:mod:`bridge.posespace.stored`); 0.1.0 stored a bare list.
EXAMPLE_POSE = Blob("Example", "pose", Schema(
    "pose-space example pose", 1, fields={"values": "list"}, list_blob=True))
#: Where a moved example is interpolated (Shape-by-Example pseudo-example), empty otherwise.
EXAMPLE_PSEUDO_POSE = Blob("Example", "pseudo_pose", Schema(
    "pose-space pseudo-example pose", 1, fields={"values": "list"}, list_blob=True))
#: The driven targets' values recorded at an example.
EXAMPLE_TARGET_VALUES = Blob("Example", "target_values", Schema(
    "driven target values of an example", 1, fields={"values": "list"}, list_blob=True))
#: An example's final shape (thesis 7.2.1): its sculpted posed positions where it moves the mesh (float32,
#: base64), the rig pose it was sculpted at and the fingerprint of the inputs its corrective was inverted from.
#: Absent (empty) on examples made by ShapeSpace 0.1.0 and on examples not applied yet.
EXAMPLE_FINAL_SHAPE = Blob("Example", "final_shape", Schema(
    "pose-space example final shape", 1,
    fields={"vertex_count": "int", "indices": "string", "positions": "string", "pose": "object",
            "fingerprint": "object"}))

#: Every stored blob, by owner.
BLOBS = (DRIVEN, RETARGET_MAPPING, RETARGET_LAST, TRANSFER_LAST, REPRESENTATION, FACE_PRIOR, ANALYSIS,
         MIRROR_MAP, NAMED_LANDMARKS, LANDMARK_PAIRS, CONTROL_SET, RIG_RETARGET_LAST, LIVE_TAKE,
         EXAMPLE_POSE, EXAMPLE_PSEUDO_POSE, EXAMPLE_TARGET_VALUES, EXAMPLE_FINAL_SHAPE)


def schemas() -> list:
    """Every registered schema: each blob's and its sections'."""
    return [s for blob in BLOBS for s in (blob.schema, *blob.sections.values())]
