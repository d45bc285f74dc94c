"""Any face rig as controls → surface (issue #25): control sets and the bounded Gauss–Newton solve on them.

Pure numpy/SciPy; :mod:`bridge.rig` reads the channels from Blender and evaluates the rig through the depsgraph.
"""
from .controls import Channel, ChannelKind, ControlSet, quaternion_from_rotation_vector, rotation_vector_from_quaternion
from .live import LiveRigFrame, LiveRigSolver, ridge_unit
from .solve import RigSolveResult, broyden_update, finite_difference_jacobian, solve_controls
from .take import RigTakeReport, RigTakeResult, solve_take, take_report

__all__ = ["Channel", "ChannelKind", "ControlSet", "LiveRigFrame", "LiveRigSolver", "RigSolveResult",
           "RigTakeReport", "RigTakeResult", "broyden_update", "finite_difference_jacobian",
           "quaternion_from_rotation_vector", "ridge_unit", "rotation_vector_from_quaternion", "solve_controls",
           "solve_take", "take_report"]
