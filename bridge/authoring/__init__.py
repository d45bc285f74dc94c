"""Rig authoring by model transfer (thesis 3.4.1) in Blender: a source rig's shape keys onto any other head.

The only package that touches Blender for *Transfer Shapes*.  It reads the source rig (neutral, triangles,
every key's delta, slider ranges, vertex-group masks, driven in-betweens and combinations — see
:mod:`bridge.driven`) and the target mesh (any topology), keeps the landmark pairs per target object, shows the
registration as a preview object, and writes the transferred shapes onto the target in one step after
everything is computed: validate → compute → write, and on any failure the file is as before.  The middle step
(registration, deformation transfer, checks) is pure and lives in :mod:`core.authoring.job`; the maths is
:mod:`core.authoring`.

- :mod:`.reading` — the source rig and the target as arrays; the target's signature;
- :mod:`.landmarks` — the landmark pairs per target object (stored, placed, proposed); the openings;
- :mod:`.examples` — target keys given as examples of the source's shapes (panel list, command-line file);
- :mod:`.parts` — the target's facial parts (panel list, the kinds set there) and the parts their rig moves;
- :mod:`.registration` — the registration and its preview object;
- :mod:`.transfer` — read, write and the background job of a transfer; the last transfer's verdict;
- :mod:`.source_file` — a source rig appended from another .blend (command line).

Level order (each imports only those above it): reading → examples, landmarks, parts → registration →
transfer; source_file stands alone.
"""
from ...core.authoring.job import (
                                   PreviewOutcome,
                                   PreviewPlan,
                                   SourceRig,
                                   TargetMesh,
                                   TransferOutcome,
                                   TransferPlan,
                                   compute_preview,
                                   compute_transfer,
)
from ...core.authoring.report import TransferReport
from .examples import add_example, load_example_file, remove_example, stored_examples
from .landmarks import (
                                   LANDMARKS_PROP,
                                   LANDMARKS_SCHEMA,
                                   MIN_LANDMARKS,
                                   add_landmark,
                                   clear_landmarks,
                                   landmark_count,
                                   landmark_list,
                                   landmark_pairs,
                                   propose_landmarks,
                                   remove_landmark,
                                   selected_vertex,
                                   set_landmarks,
                                   use_named_landmarks,
)
from .parts import (
                                   compute_find_parts,
                                   find_parts,
                                   finish_find_parts_job,
                                   moved_by_rig,
                                   part_kinds,
                                   read_find_parts,
                                   select_part,
                                   start_find_parts_job,
                                   write_find_parts,
)
from .reading import read_source_rig, read_target
from .registration import (
                                   PREVIEW_PROP,
                                   clear_preview,
                                   finish_preview_job,
                                   preview_object,
                                   read_preview,
                                   register_source,
                                   show_preview,
                                   start_preview_job,
                                   write_preview,
)
from .source_file import append_object, remove_appended
from .transfer import (
                                   EXISTING,
                                   LAST_PROP,
                                   LAST_SCHEMA,
                                   NAMINGS,
                                   finish_transfer_job,
                                   last_verdict,
                                   read_transfer,
                                   start_transfer_job,
                                   transfer_shapes,
                                   verdict_status,
                                   write_transfer,
)

__all__ = ["MIN_LANDMARKS", "PREVIEW_PROP", "LANDMARKS_PROP", "LANDMARKS_SCHEMA", "NAMINGS", "EXISTING",
           "LAST_PROP", "LAST_SCHEMA", "SourceRig", "TargetMesh", "TransferReport", "read_source_rig", "read_target",
           "landmark_pairs", "landmark_count", "landmark_list", "add_landmark", "remove_landmark", "set_landmarks",
           "clear_landmarks", "use_named_landmarks", "propose_landmarks", "register_source", "show_preview",
           "clear_preview", "preview_object", "PreviewPlan", "PreviewOutcome", "read_preview", "compute_preview",
           "write_preview", "start_preview_job", "finish_preview_job", "transfer_shapes", "selected_vertex",
           "append_object", "remove_appended", "TransferPlan", "TransferOutcome", "read_transfer",
           "compute_transfer", "write_transfer", "start_transfer_job", "finish_transfer_job", "last_verdict",
           "verdict_status", "load_example_file", "stored_examples", "add_example",
           "remove_example", "find_parts", "moved_by_rig", "part_kinds", "select_part", "read_find_parts",
           "compute_find_parts", "write_find_parts", "start_find_parts_job", "finish_find_parts_job"]
