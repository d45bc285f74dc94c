"""The face-space blobs on a rig's Key datablock (versioned JSON, read and written through :mod:`bridge.storage`):
what a converted copy is, the learnt face prior, and the last compression report and rig analysis."""
from __future__ import annotations

import json

from ...core import blobs
from ...core import schema as _schema
from ...core.errors import ErrorCode
from ...core.facespace.job import coherence_problem
from ...core.result import ShapeSpaceError, to_jsonable
from ...core.schema import Schema
from .. import storage

REPRESENTATION_PROP = "shapespace_representation"
PRIOR_PROP = "shapespace_face_prior"
ANALYSIS_PROP = "shapespace_analysis"
#: What a converted copy is (Key custom property :data:`REPRESENTATION_PROP`): ``form`` "whole_face" (with
#: ``convex`` and ``neutral_keys``, the keys sharing the neutral's weight; absent in files of 0.1.0: one key
#: :data:`.conversions.NEUTRAL_KEY`) or "pca" (with the source ``sliders`` and the slider map ``A`` (m, n), ``a`` (m,)).
REPRESENTATION_SCHEMA = blobs.REPRESENTATION.schema
#: The learnt face Gaussian (Key custom property :data:`PRIOR_PROP`), see :class:`core.facespace.FaceGaussian`.
PRIOR_SCHEMA = blobs.FACE_PRIOR.schema
#: The last compression report and rig analysis (Key custom property :data:`ANALYSIS_PROP`), for the panel.
ANALYSIS_SCHEMA = blobs.ANALYSIS.schema
_SCHEMAS = {REPRESENTATION_PROP: REPRESENTATION_SCHEMA, PRIOR_PROP: PRIOR_SCHEMA, ANALYSIS_PROP: ANALYSIS_SCHEMA}
#: The two reports inside :data:`ANALYSIS_SCHEMA` (what :func:`compression` and :func:`analyse` write).
COMPRESSION_SCHEMA = blobs.ANALYSIS.sections["compression"]
COHERENCE_SCHEMA = blobs.ANALYSIS.sections["coherence"]


def damaged(id_block, prop: str, what: str) -> ShapeSpaceError:
    """The one-line error for a blob that reads as JSON but does not fit the rig (code ``corrupt_metadata``)."""
    return ShapeSpaceError(f"damaged ShapeSpace data in {storage.where(id_block, prop)}: {what}",
                           ErrorCode.CORRUPT_METADATA)


def stored(obj, prop: str) -> dict:
    """The blob ``prop`` (one of the ``*_PROP`` keys) on ``obj``'s shape keys, checked and migrated; an empty
    blob (only ``schema_version``) when absent or when ``obj`` is not a mesh."""
    key = obj.data.shape_keys if obj is not None and obj.type == "MESH" else None
    return storage.read_id_blob(key, prop, _SCHEMAS[prop])


def store(obj, prop: str, data: dict) -> None:
    """Write the blob ``prop`` on ``obj``'s shape keys (NaN and infinities become ``null``)."""
    storage.write_id_blob(obj.data.shape_keys, prop, _SCHEMAS[prop], to_jsonable(data))


def _check_report(key, section: str, data: dict, schema: Schema) -> None:
    """Check one report of the analysis blob against ``schema`` (same messages as the blob itself)."""
    where = f"{storage.where(key, ANALYSIS_PROP)} ▸ {section}"
    _schema.loads(json.dumps(data), schema, where)


def stored_analysis(obj) -> dict:
    """The analysis blob (:data:`ANALYSIS_PROP`) with its two reports checked field by field: what the panel
    may show and :func:`compression` / :func:`analyse` may extend."""
    data = stored(obj, ANALYSIS_PROP)
    key = obj.data.shape_keys
    if "compression" in data:
        _check_report(key, "compression", data["compression"], COMPRESSION_SCHEMA)
    if "coherence" in data:
        _check_report(key, "coherence", data["coherence"], COHERENCE_SCHEMA)
        problem = coherence_problem(data["coherence"])
        if problem:
            raise damaged(key, ANALYSIS_PROP, problem)
    return data

