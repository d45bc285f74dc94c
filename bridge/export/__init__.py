"""Export for engines (glTF, FBX, Alembic): bake drivers and pose-space correctives into plain data on a
temporary copy, call Blender's exporter, leave the user's file untouched.

- :mod:`.collect` — the chosen objects, their armatures, the actions that animate them;
- :mod:`.sample` — per-frame effective shape-key weights and pose-space outputs (read only);
- :mod:`.copy` — the temporary scene of copies and what is baked into it;
- :mod:`.write` — the export itself (:func:`export`) and the exporters' settings;
- :mod:`.roundtrip` — re-import and compare (tests, benchmarks).
"""
from .collect import EXPORTED_TYPES, animating_actions, driven_keys, resolve_objects, with_dependencies
from .copy import FRAME_KEY_PREFIX, SCENE_NAME, ExportScene
from .sample import MeshSamples, sample_meshes
from .write import export

__all__ = ["EXPORTED_TYPES", "resolve_objects", "with_dependencies", "animating_actions", "driven_keys",
           "MeshSamples", "sample_meshes", "SCENE_NAME", "FRAME_KEY_PREFIX", "ExportScene", "export"]
