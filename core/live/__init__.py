"""Live capture: decode a phone's face capture per packet and solve it onto any rig (issue #14).

- :mod:`.frames` — the decoded frame and the sources' channel orders (mapped by name, never by index);
- :mod:`.packets` — Live Link Face v6 and iFacialMocap decoders (and encoders for replays), the Face Cap
  message assembler (its OSC parsing is python-osc's, in the bridge);
- :mod:`.filter` — the One-Euro filter;
- :mod:`.calibration` — the rest face and head pose as zero, head / neck / eye bone rotations;
- :mod:`.solvers` — copy, learned matrix and the bounded geometric fit through a template, precomputed;
- :mod:`.take` — a stream resampled onto scene frames as it arrives (what Record keys).

Pure numpy/scipy and the standard library: the bridge runs the sockets, threads and Blender writes.
"""
from .calibration import (
                          FACE_TO_ARMATURE,
                          CalibratedInput,
                          Neutral,
                          bone_local,
                          calibrate,
                          euler_matrix,
                          face_to_armature,
                          matrix_euler,
                          matrix_quaternion,
                          rotation_power,
)
from .filter import OneEuroFilter
from .frames import (
                          FACECAP_52,
                          LLF_BLENDSHAPES,
                          LLF_CURVES,
                          LLF_ROTATIONS,
                          MAX_ABS_ANGLE,
                          LiveFrame,
                          format_timecode,
                          implausible_channel,
)
from .packets import (
                          FACECAP_PORT,
                          IFM_PORT,
                          LLF_PORT,
                          LLF_VERSION,
                          MAX_DATAGRAM,
                          MAX_OSC_DEPTH,
                          FaceCapAssembler,
                          check_osc_message,
                          decode_ifacialmocap,
                          decode_llf,
                          encode_ifacialmocap,
                          encode_llf,
                          osc_bundle_messages,
                          quaternion_to_yaw_pitch_roll,
)
from .solvers import CopySolver, GeometricSolver, LearnedSolver, dense_box_qp
from .take import SceneResampler

__all__ = [
    # frames and sources
    "LiveFrame", "LLF_CURVES", "LLF_BLENDSHAPES", "LLF_ROTATIONS", "FACECAP_52", "format_timecode",
    "MAX_ABS_ANGLE", "implausible_channel",
    "LLF_PORT", "LLF_VERSION", "IFM_PORT", "FACECAP_PORT", "MAX_DATAGRAM", "MAX_OSC_DEPTH",
    "encode_llf", "decode_llf", "encode_ifacialmocap", "decode_ifacialmocap", "FaceCapAssembler",
    "quaternion_to_yaw_pitch_roll", "osc_bundle_messages", "check_osc_message",
    # filtering and calibration
    "OneEuroFilter", "CalibratedInput", "Neutral",
    "calibrate", "euler_matrix", "matrix_euler", "matrix_quaternion", "rotation_power",
    "face_to_armature", "bone_local", "FACE_TO_ARMATURE",
    # solvers and takes
    "CopySolver", "LearnedSolver", "GeometricSolver", "dense_box_qp", "SceneResampler",
]
