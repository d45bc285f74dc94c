"""core.headpose: the head / eye rotation maths shared by live capture and recorded takes.

References are independent: rotations composed from per-axis matrices written out here, Blender's Euler
convention (mode ``'XYZ'`` applies X first: ``R = R_z R_y R_x``), and hand-counted channel lists.
"""
import numpy as np
import pytest

from core.headpose import (
    ROTATION_CHANNELS,
    BoneSpec,
    bone_curves,
    bone_values,
    eye_ypr_from_degrees,
    matrix_to_euler,
    unused_rotation_channels,
    ypr_from_degrees,
)

ORDERS = ("XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX")


def axis_rotation(axis, angle):
    c, s = np.cos(angle), np.sin(angle)
    return {"X": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]),
            "Y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
            "Z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])}[axis]


def compose(order, xyz):
    """Blender's Euler: the first axis of ``order`` applied first."""
    angle = dict(zip("XYZ", xyz))
    R = np.eye(3)
    for axis in order:
        R = axis_rotation(axis, angle[axis]) @ R
    return R


@pytest.mark.parametrize("order", ORDERS)
def test_matrix_to_euler_inverts_blender_euler(order):
    rng = np.random.default_rng(7)
    for _ in range(200):
        xyz = rng.uniform(-np.pi + 1e-3, np.pi - 1e-3, 3)
        middle = "XYZ".index(order[1])
        xyz[middle] = rng.uniform(-np.pi / 2 + 1e-3, np.pi / 2 - 1e-3)
        np.testing.assert_allclose(matrix_to_euler(compose(order, xyz), order), xyz, atol=1e-9)


@pytest.mark.parametrize("order", ORDERS)
def test_matrix_to_euler_at_gimbal_lock_gives_the_same_rotation(order):
    xyz = np.array([0.3, -0.2, 0.5])
    xyz["XYZ".index(order[1])] = np.pi / 2
    R = compose(order, xyz)
    np.testing.assert_allclose(compose(order, matrix_to_euler(R, order)), R, atol=1e-9)


def test_degree_conventions():
    np.testing.assert_allclose(ypr_from_degrees([10.0, 20.0, 30.0]), np.radians([20.0, 10.0, 30.0]))
    np.testing.assert_allclose(eye_ypr_from_degrees([[10.0, 20.0]]), np.radians([[20.0, 10.0, 0.0]]))


def spec(name, part, share=1.0, mode="QUATERNION"):
    return BoneSpec(name, part, share, np.eye(3), mode)


def test_unused_channels_named():
    assert unused_rotation_channels([]) == list(ROTATION_CHANNELS)
    assert unused_rotation_channels([spec("n", "neck", 0.3)]) == list(ROTATION_CHANNELS[3:])
    assert unused_rotation_channels([spec("e", "eye_left")]) == list(ROTATION_CHANNELS[:3] + ROTATION_CHANNELS[6:])
    # mirrored: the character's left eye takes the actor's right eye
    assert unused_rotation_channels([spec("e", "eye_left")], mirror=True) == list(ROTATION_CHANNELS[:6])


def test_bone_curves_are_bone_values_per_frame():
    rng = np.random.default_rng(3)
    rot = rng.uniform(-0.4, 0.4, (20, 9))
    bones = [spec("h", "head", 0.7), spec("n", "neck", 0.3, "XYZ"), spec("l", "eye_left", mode="AXIS_ANGLE"),
             spec("r", "eye_right", mode="ZXY")]
    curves = bone_curves(rot, bones, mirror=True)
    for f in (0, 7, 19):
        values = bone_values(rot[f], bones, mirror=True)
        for b in bones:
            np.testing.assert_array_equal(curves[b.name][f], values[b.name])
    assert curves["h"].shape == (20, 4) and curves["n"].shape == (20, 3)


def test_identity_rest_head_bone_takes_the_face_rotation_on_blender_axes():
    """A head bone resting along the armature axes, yaw only: a turn about Blender's Z (up) by the yaw."""
    yaw = 0.3
    q = bone_values([yaw, 0, 0, 0, 0, 0, 0, 0, 0], [spec("h", "head")])["h"]
    np.testing.assert_allclose(q, [np.cos(yaw / 2), 0, 0, np.sin(yaw / 2)], atol=1e-12)
