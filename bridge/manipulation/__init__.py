"""Direct manipulation in Blender: pins stored on a mesh, prior training from actions, drag solves to sliders.

- :mod:`.pins` — pins in ``Object.shapespace.pins`` and every verb that writes them (:func:`add_pin`,
  :func:`remove_pin`, :func:`clear_pins`, :func:`set_pin_target`, :func:`set_active_pin`, :func:`undo_drag`),
  read in bulk (:func:`read_pin_state`); targets in :data:`SPACES` (:func:`to_shape_space`); what the viewport
  overlay draws (:func:`overlay_points`);
- :mod:`.cache` — :data:`RIGS`, the rig cache: each mesh's blendshape model read once and kept while its
  shape keys stay the same (checked by fingerprint, checksum and the depsgraph; emptied by undo and file
  loads; :func:`rig_model`), and :func:`write_sliders`, ShapeSpace's own slider write with its one depsgraph
  update;
- :mod:`.surface` — the evaluated surface: world ↔ shape-key space, crazy-space maps cached per pose,
  pin positions read from Blender's evaluated mesh, ray picking (:func:`surface_pin`);
- :mod:`.drag` — the solves: :func:`solve_pins` (the core solve :func:`core.manipulation.solve_drag`, then the
  write), :class:`Drag` (one interactive drag: the Drag Pins tool and scripted drags make the same calls
  per mouse move), :func:`solve_to_target` (the Solve Pins operator);
- here — the package's public names, re-exported; the pure geometry of picking and mirroring
  (:func:`ray_hit`, :func:`reflect_point`, :func:`mirror_pin`, …) is :mod:`core.manipulation.geometry`.

Targets given by a caller are in one of :data:`SPACES`: ``"LOCAL"``, the
mesh's own undeformed coordinates (shape-key space, how pins store them), or
``"WORLD"``, where the point should appear in the scene — on the evaluated
surface, after the object's (and its parents') transform and deform
modifiers — which is what the 3D cursor or an empty gives.

Every verb validates and computes first and writes last: a refused solve
leaves sliders and pin targets exactly as they were, and no slider is ever
written with a non-finite value.
"""
from __future__ import annotations

from ...core.manipulation.geometry import mirror_pin, reflect_point, symmetric_target
from .cache import RIGS, RigCache, RigEntry, rig_model, write_sliders
from .drag import (
                   Drag,
                   current_sliders,
                   drag_status_line,
                   drag_step,
                   key_changed,
                   prior_from_settings,
                   report_text,
                   solve_pins,
                   solve_to_target,
                   symmetric_move,
)
from .pins import (
                   SPACES,
                   PinState,
                   add_pin,
                   check_pins,
                   clear_pins,
                   deformed_pin_positions,
                   deformed_to_shape_space,
                   mirror_links,
                   mirror_partner,
                   mirror_pins,
                   mirror_plane,
                   overlay_points,
                   pin_target,
                   read_pin_state,
                   read_pins,
                   remove_pin,
                   set_active_pin,
                   set_pin_target,
                   settings,
                   stored_pin,
                   to_shape_space,
                   undo_drag,
)
from .surface import surface_pin, world_to_local

__all__ = ["SPACES", "RIGS", "RigCache", "RigEntry", "PinState", "Drag", "rig_model", "write_sliders",
           "settings", "stored_pin", "read_pin_state", "read_pins", "check_pins", "add_pin", "remove_pin",
           "clear_pins", "set_pin_target", "set_active_pin", "pin_target", "undo_drag", "to_shape_space",
           "world_to_local", "deformed_to_shape_space", "deformed_pin_positions", "overlay_points", "surface_pin",
           "prior_from_settings", "solve_pins", "drag_step", "solve_to_target",
           "drag_status_line", "report_text", "current_sliders", "key_changed", "mirror_links", "mirror_partner",
           "mirror_pin", "mirror_pins", "mirror_plane", "reflect_point", "symmetric_target", "symmetric_move"]
