"""Every error code ShapeSpace raises, in one place.

:class:`~core.result.ShapeSpaceError` takes one of these codes (a ``str``
enum: ``err.code == "shape"`` works).  Codes are stable: tests, the command
line's JSON errors and scripts match them.  ``tests/core/test_architecture.py``
checks that every code raised anywhere in the add-on is listed here.
"""
from __future__ import annotations

import enum

__all__ = ["ErrorCode", "DESCRIPTIONS"]


class ErrorCode(str, enum.Enum):
    """Stable identifiers of bad-input errors (value = the code)."""

    INVALID = "invalid"
    SHAPE = "shape"
    RANGE = "range"
    NON_FINITE = "non_finite"
    TYPE = "type"
    DTYPE = "dtype"
    TOO_FEW = "too_few"
    TOO_SHORT = "too_short"
    SINGULAR = "singular"
    METHOD = "method"
    KERNEL = "kernel"
    DEGREE = "degree"
    ORDER = "order"
    UNSORTED = "unsorted"
    RAGGED = "ragged"
    EMPTY = "empty"
    DEGENERATE = "degenerate"
    COLLINEAR = "collinear"
    STATIC_LANDMARKS = "static_landmarks"
    TOO_FEW_LANDMARKS = "too_few_landmarks"
    INFEASIBLE = "infeasible"
    NOT_SYMMETRIC = "not_symmetric"
    NOT_ORTHONORMAL = "not_orthonormal"
    NOT_NUMBER = "not_number"
    NONLINEAR = "nonlinear"
    TOLERANCE_NOT_MET = "tolerance_not_met"
    FPS = "fps"
    TIMECODE = "timecode"
    NO_TIMECODE = "no_timecode"
    CORRUPT_FILE = "corrupt_file"
    CORRUPT_METADATA = "corrupt_metadata"
    UNSUPPORTED_FILE = "unsupported_file"
    MISSING_FILE = "missing_file"
    USAGE = "usage"
    AMBIGUOUS_OBJECT = "ambiguous_object"
    MISSING_OBJECT = "missing_object"
    MISSING_KEY = "missing_key"
    MISSING_BONE = "missing_bone"
    MISSING_PROPERTY = "missing_property"
    MISSING_CURVE = "missing_curve"
    MISSING_CHANNEL = "missing_channel"
    MISSING_SOURCE = "missing_source"
    MISSING_TARGET = "missing_target"
    MISSING_EXAMPLE = "missing_example"
    MISSING_GROUP = "missing_group"
    UNCOVERED = "uncovered"
    SAME_KEY = "same_key"
    DUPLICATE_INBETWEEN = "duplicate_inbetween"
    DRIVEN_PRIMARY = "driven_primary"
    COMBINATION_INPUTS = "combination_inputs"
    KEY_SHAPE = "key_shape"
    VERTEX_COUNT = "vertex_count"
    VERTEX_COUNT_MISMATCH = "vertex_count_mismatch"
    TOPOLOGY_MODIFIERS = "topology_modifiers"
    MODE = "mode"
    NO_ACTION = "no_action"
    NO_ARMATURE = "no_armature"
    NOT_ARMATURE = "not_armature"
    ARMATURE_PARENT = "armature_parent"
    ENVELOPES = "envelopes"
    MULTI_MODIFIER = "multi_modifier"
    ABSOLUTE_KEYS = "absolute_keys"
    NO_VERTEX_GROUPS = "no_vertex_groups"
    NO_OBJECT = "no_object"
    NOT_MESH = "not_mesh"
    NO_CHANNELS = "no_channels"
    NO_EXAMPLES = "no_examples"
    NO_KEY_POSES = "no_key_poses"
    NO_KEYS = "no_keys"
    NO_KNOWN = "no_known"
    NO_MAPPING = "no_mapping"
    NO_MIRROR = "no_mirror"
    NO_PINS = "no_pins"
    PIN = "pin"
    NO_PRIOR = "no_prior"
    PRIOR_CONSTANT = "prior_constant"
    PRIOR_FRAMES = "prior_frames"
    PRIOR_STALE = "prior_stale"
    STALE_PRIOR = "stale_prior"
    NO_READERS = "no_readers"
    READER = "reader"
    NO_RESULT = "no_result"
    NO_RIGS = "no_rigs"
    NO_SCULPT = "no_sculpt"
    NO_SHAPE_KEYS = "no_shape_keys"
    NO_TARGETS = "no_targets"
    NO_VALUES = "no_values"
    NOT_WHOLE_FACE = "not_whole_face"
    STALE_EXAMPLE = "stale_example"
    STALE_TARGETS = "stale_targets"
    WPSD_INPUTS = "wpsd_inputs"
    EMPTY_CURVE = "empty_curve"
    NOT_A_FILE = "not_a_file"
    TOO_LARGE = "too_large"
    OVERWRITE = "overwrite"
    UNWRITABLE = "unwritable"
    MALFORMED_PACKET = "malformed_packet"
    PORT_IN_USE = "port_in_use"
    NETWORK = "network"
    LIVE_STATE = "live_state"
    MISSING_LIBRARY = "missing_library"
    FORMAT = "format"
    NOTHING_TO_EXPORT = "nothing_to_export"
    RESERVED_NAME = "reserved_name"
    DUPLICATE_NAME = "duplicate_name"
    CENTRE_EDGE = "centre_edge"
    NO_MIRROR_MAP = "no_mirror_map"
    STALE_MIRROR_MAP = "stale_mirror_map"
    STALE_LANDMARKS = "stale_landmarks"
    STALE_PART = "stale_part"
    LINKED = "linked"
    RIG_CHANGED = "rig_changed"
    TRANSFER_EXAMPLE_RESIDUAL = "transfer_example_residual"

    def __str__(self) -> str:
        return self.value


#: One line per code: what it means.
DESCRIPTIONS = {
    ErrorCode.INVALID: "generic bad input (prefer a specific code)",
    ErrorCode.SHAPE: "an array argument has the wrong shape or number of dimensions",
    ErrorCode.RANGE: "a scalar or array value lies outside its allowed range",
    ErrorCode.NON_FINITE: "NaN or infinity in input data (coordinates, weights, settings)",
    ErrorCode.TYPE: "an argument has the wrong type",
    ErrorCode.DTYPE: "an array has a dtype that cannot be converted to float",
    ErrorCode.TOO_FEW: "too few items (frames, examples, components, points) for the computation",
    ErrorCode.TOO_SHORT: "a curve or take is too short",
    ErrorCode.SINGULAR: "a system is singular or numerically rank deficient where it must not be",
    ErrorCode.METHOD: "an unknown method name",
    ErrorCode.KERNEL: "an unknown or unsuitable RBF kernel",
    ErrorCode.DEGREE: "an unsuitable polynomial degree",
    ErrorCode.ORDER: "values are not in the required order",
    ErrorCode.UNSORTED: "times or frames are not sorted",
    ErrorCode.RAGGED: "rows of different lengths",
    ErrorCode.EMPTY: "an empty input",
    ErrorCode.DEGENERATE: "degenerate geometry (zero area, zero size)",
    ErrorCode.COLLINEAR: "landmarks lie on one line (or coincide)",
    ErrorCode.STATIC_LANDMARKS: "landmarks on vertices that never move",
    ErrorCode.TOO_FEW_LANDMARKS: "fewer landmark pairs than the warp needs",
    ErrorCode.INFEASIBLE: "bounds that no value can satisfy (lower above upper)",
    ErrorCode.NOT_SYMMETRIC: "a matrix that must be symmetric is not",
    ErrorCode.NOT_ORTHONORMAL: "a basis that must be orthonormal is not",
    ErrorCode.NOT_NUMBER: "a value that must be a number is not",
    ErrorCode.NONLINEAR: "the rig has in-betweens or combinations the method cannot model linearly",
    ErrorCode.TOLERANCE_NOT_MET: "no result meets the requested tolerance",
    ErrorCode.FPS: "a frame rate that is not positive and finite",
    ErrorCode.TIMECODE: "an unreadable or impossible timecode",
    ErrorCode.NO_TIMECODE: "a capture file without a timecode column",
    ErrorCode.CORRUPT_FILE: "a file whose contents cannot be parsed",
    ErrorCode.CORRUPT_METADATA: "ShapeSpace data stored in the .blend is damaged (invalid JSON, wrong type, "
                                "missing field)",
    ErrorCode.UNSUPPORTED_FILE: "a file type ShapeSpace cannot read",
    ErrorCode.MISSING_FILE: "a file that does not exist (or is not a regular file)",
    ErrorCode.USAGE: "bad command-line usage",
    ErrorCode.AMBIGUOUS_OBJECT: "several objects match where one is needed",
    ErrorCode.MISSING_OBJECT: "a named object does not exist",
    ErrorCode.MISSING_KEY: "a named shape key does not exist",
    ErrorCode.MISSING_BONE: "a named bone does not exist",
    ErrorCode.MISSING_PROPERTY: "a named custom property does not exist",
    ErrorCode.MISSING_CURVE: "a named F-Curve does not exist",
    ErrorCode.MISSING_CHANNEL: "a capture channel the method needs is missing",
    ErrorCode.MISSING_SOURCE: "a retarget source that does not exist",
    ErrorCode.MISSING_TARGET: "a retarget or driven target that does not exist",
    ErrorCode.MISSING_EXAMPLE: "a pose-space example that does not exist",
    ErrorCode.MISSING_GROUP: "a named vertex group does not exist",
    ErrorCode.UNCOVERED: "sculpted vertices that no mask covers",
    ErrorCode.SAME_KEY: "an operation that needs two different keys got the same one",
    ErrorCode.DUPLICATE_INBETWEEN: "an in-between at a weight that already has one",
    ErrorCode.DRIVEN_PRIMARY: "the primary key of an in-between or combination is itself driven",
    ErrorCode.COMBINATION_INPUTS: "a combination shape with the wrong number of inputs",
    ErrorCode.KEY_SHAPE: "an unknown key interpolation shape",
    ErrorCode.VERTEX_COUNT: "vertex counts that do not match",
    ErrorCode.VERTEX_COUNT_MISMATCH: "a mesh whose vertex count changed after the keys were made",
    ErrorCode.TOPOLOGY_MODIFIERS: "modifiers that change topology where a fixed topology is needed",
    ErrorCode.MODE: "an object in a mode the operation cannot use (e.g. Edit Mode)",
    ErrorCode.NO_ACTION: "no action where one is needed",
    ErrorCode.NO_ARMATURE: "no Armature modifier or armature where one is needed",
    ErrorCode.NOT_ARMATURE: "an object that must be an armature is not",
    ErrorCode.ARMATURE_PARENT: "an armature-parented mesh ShapeSpace does not model",
    ErrorCode.ENVELOPES: "envelope deformation ShapeSpace does not model",
    ErrorCode.MULTI_MODIFIER: "Armature modifier Multi Modifier setting ShapeSpace does not model",
    ErrorCode.ABSOLUTE_KEYS: "absolute (non-relative) shape keys",
    ErrorCode.NO_VERTEX_GROUPS: "a skinned mesh without vertex groups",
    ErrorCode.NO_OBJECT: "no object where one is needed",
    ErrorCode.NOT_MESH: "an object that must be a mesh is not",
    ErrorCode.NO_CHANNELS: "no channels could be matched",
    ErrorCode.NO_EXAMPLES: "no pose-space examples",
    ErrorCode.NO_KEY_POSES: "no key poses for learned cloning",
    ErrorCode.NO_KEYS: "no keys on a curve",
    ErrorCode.NO_KNOWN: "no known values to inpaint from",
    ErrorCode.NO_MAPPING: "no channel mapping",
    ErrorCode.NO_MIRROR: "no mirror counterpart found",
    ErrorCode.NO_PINS: "no pins",
    ErrorCode.PIN: "a pin that is invalid for the current mesh",
    ErrorCode.NO_PRIOR: "no learned prior",
    ErrorCode.PRIOR_CONSTANT: "the prior's training animation is constant",
    ErrorCode.PRIOR_FRAMES: "too few training frames for the prior",
    ErrorCode.PRIOR_STALE: "the learned prior no longer matches the rig",
    ErrorCode.STALE_PRIOR: "the stored prior no longer matches the rig",
    ErrorCode.NO_READERS: "a pose space without readers",
    ErrorCode.READER: "an invalid pose-space reader",
    ErrorCode.NO_RESULT: "no retarget result to act on",
    ErrorCode.NO_RIGS: "no rigs found",
    ErrorCode.NO_SCULPT: "an example without a sculpt",
    ErrorCode.NO_SHAPE_KEYS: "a mesh without shape keys",
    ErrorCode.NO_TARGETS: "a rig without targets",
    ErrorCode.NO_VALUES: "no values",
    ErrorCode.NOT_WHOLE_FACE: "a rig that is not in whole-face form",
    ErrorCode.STALE_EXAMPLE: "an example whose stored data no longer matches the mesh",
    ErrorCode.STALE_TARGETS: "driven targets that no longer match the examples",
    ErrorCode.WPSD_INPUTS: "weighted PSD inputs that do not match",
    ErrorCode.EMPTY_CURVE: "an F-Curve without keys",
    ErrorCode.NOT_A_FILE: "a directory, FIFO or device where a regular file is needed",
    ErrorCode.TOO_LARGE: "a file, take or resampled stream beyond its size or memory limit",
    ErrorCode.OVERWRITE: "an output that would overwrite an input or a file of another kind",
    ErrorCode.UNWRITABLE: "an output path that cannot be written",
    ErrorCode.MALFORMED_PACKET: "a live capture datagram that does not decode (truncated, wrong version or "
                                "count, bad values)",
    ErrorCode.PORT_IN_USE: "a network port another program (or receiver) already uses",
    ErrorCode.NETWORK: "a socket that cannot be opened or used",
    ErrorCode.LIVE_STATE: "a live-capture action that does not fit the receiver's state (not running, "
                          "already recording, …)",
    ErrorCode.MISSING_LIBRARY: "a library the feature needs is not installed",
    ErrorCode.FORMAT: "an unknown export format, or an output file whose extension does not match it",
    ErrorCode.NOTHING_TO_EXPORT: "no chosen object has anything an export can write (a mesh or an armature)",
    ErrorCode.RESERVED_NAME: "a shape key named like a key ShapeSpace must create (e.g. a whole-face copy's Zero "
                             "or Neutral)",
    ErrorCode.DUPLICATE_NAME: "a list of names that must be distinct repeats one",
    ErrorCode.CENTRE_EDGE: "a symmetry centre edge that is not an edge of the mesh or has no face on "
                           "each side",
    ErrorCode.NO_MIRROR_MAP: "a mesh without a stored mirror map (Build Mirror Map first)",
    ErrorCode.STALE_MIRROR_MAP: "a stored mirror map built for a different topology (vertex, edge or face "
                                "counts or the edge list changed): rebuild it",
    ErrorCode.RIG_CHANGED: "a rig changed (mode, mesh, shape keys or slider ranges) while a long computation for "
                           "it ran in the background, so its result no longer applies",
    ErrorCode.STALE_PART: "a part set in the Parts list that the mesh no longer has as it was (edited since): find "
                          "the parts again or set the row to Auto",
    ErrorCode.STALE_LANDMARKS: "landmark pairs placed on meshes whose vertex count has changed since: place them "
                               "again",
    ErrorCode.LINKED: "data linked from a library that would have to be changed (the change would be lost on save)",
    ErrorCode.TRANSFER_EXAMPLE_RESIDUAL: "a transfer's example is not reproduced (examples that contradict each "
                                         "other: the transferred keys were written, the report says which)",
}
