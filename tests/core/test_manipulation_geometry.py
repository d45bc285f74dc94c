"""core.manipulation.geometry: ray picking, pin positions and mirroring, against analytic answers."""
import numpy as np
import pytest

from core.errors import ErrorCode
from core.manipulation import Pin
from core.manipulation.geometry import mirror_pin, pin_surface_positions, ray_hit, reflect_point, symmetric_target
from core.result import ShapeSpaceError
from core.symmetry import position_map

# Two unit right triangles in the planes z = 0 and z = −1, and one far off to the side.
CO = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0],
               [0, 0, -1], [1, 0, -1], [0, 1, -1],
               [5, 5, 0], [6, 5, 0], [5, 6, 0]], dtype=np.float64)
TRIS = np.array([[3, 4, 5], [0, 1, 2], [6, 7, 8]])


def test_a_ray_down_the_z_axis_hits_the_nearest_triangle_at_its_barycentric_point():
    hit = ray_hit((0.25, 0.25, 1.0), (0.0, 0.0, -3.0), CO, TRIS)        # direction need not be unit length
    assert hit is not None
    index, bary, point = hit
    assert index == 1                                                   # z = 0 is in front of z = −1
    np.testing.assert_allclose(bary, [0.5, 0.25, 0.25], atol=1e-12)
    np.testing.assert_allclose(point, [0.25, 0.25, 0.0], atol=1e-12)


def test_an_oblique_ray_hits_where_the_line_meets_the_plane():
    # origin (0, 0, 2) + t (0.3, 0.2, −2) meets z = 0 at t = 1: (0.3, 0.2, 0) = 0.5 a + 0.3 b + 0.2 c.
    index, bary, point = ray_hit((0.0, 0.0, 2.0), (0.3, 0.2, -2.0), CO, TRIS)
    assert index == 1
    np.testing.assert_allclose(bary, [0.5, 0.3, 0.2], atol=1e-12)
    np.testing.assert_allclose(point, [0.3, 0.2, 0.0], atol=1e-12)


def test_a_ray_from_between_the_planes_hits_the_one_ahead():
    index, _, point = ray_hit((0.2, 0.2, -0.5), (0.0, 0.0, -1.0), CO, TRIS)
    assert index == 0
    np.testing.assert_allclose(point, [0.2, 0.2, -1.0], atol=1e-12)


@pytest.mark.parametrize("origin,direction", [
    ((0.25, 0.25, 1.0), (0.0, 0.0, 1.0)),        # pointing away: both triangles behind the origin
    ((2.0, 2.0, 1.0), (0.0, 0.0, -1.0)),         # passes beside every triangle
    ((0.25, 0.25, 1.0), (0.0, 0.0, 0.0)),        # no direction
    ((0.25, 0.25, 1.0), (np.nan, 0.0, -1.0)),    # not finite
])
def test_a_ray_that_hits_nothing_gives_none(origin, direction):
    assert ray_hit(origin, direction, CO, TRIS) is None


def test_no_triangles_give_no_hit():
    assert ray_hit((0, 0, 1), (0, 0, -1), CO, np.zeros((0, 3), dtype=np.int64)) is None


def test_pin_positions_are_the_barycentric_combinations():
    idx = np.array([[0, 1, 2], [6, 7, 8]])
    bary = np.array([[0.5, 0.25, 0.25], [0.0, 1.0, 0.0]])
    np.testing.assert_allclose(pin_surface_positions(idx, bary, CO), [[0.25, 0.25, 0.0], [6.0, 5.0, 0.0]])
    verts = np.array([0, 1, 2, 6, 7, 8])                                # positions of these vertices only
    np.testing.assert_allclose(pin_surface_positions(idx, bary, CO[verts], verts), [[0.25, 0.25, 0.0],
                                                                                    [6.0, 5.0, 0.0]])


@pytest.mark.parametrize("point,plane,expected", [
    ((1.0, 2.0, 3.0), (0, 0.0), (-1.0, 2.0, 3.0)),
    ((1.0, 2.0, 3.0), (0, 0.5), (0.0, 2.0, 3.0)),
    ((1.0, 2.0, 3.0), (2, -1.0), (1.0, 2.0, -5.0)),
    ((0.5, 7.0, 0.0), (0, 0.5), (0.5, 7.0, 0.0)),                       # on the plane: itself
])
def test_reflection_across_a_plane(point, plane, expected):
    out = reflect_point(point, plane)
    np.testing.assert_allclose(out, expected)
    np.testing.assert_allclose(reflect_point(out, plane), point)       # an involution
    assert np.asarray(point).tolist() == list(point)                    # the input is not changed


def test_a_centre_line_target_moves_to_the_midpoint_of_itself_and_its_reflection():
    target, plane = np.array([1.0, 2.0, 3.0]), (0, 0.25)
    np.testing.assert_allclose(symmetric_target(target, plane), (target + reflect_point(target, plane)) / 2)
    np.testing.assert_allclose(symmetric_target(target, plane), [0.25, 2.0, 3.0])
    assert target.tolist() == [1.0, 2.0, 3.0]


# Five points symmetric across x = 0: 0 ↔ 1, 3 ↔ 4, 2 on the centre line; point 5 has no mirror.
MIRROR_CO = np.array([[-1, 0, 0], [1, 0, 0], [0, 1, 0], [-1, 1, 0], [1, 1, 0], [3, 3, 3]], dtype=np.float64)


def test_the_mirror_pin_has_the_same_weights_on_the_mirror_vertices():
    mmap = position_map(MIRROR_CO)
    assert mmap.mirror.tolist() == [1, 0, 2, 4, 3, -1]
    pin = Pin((0, 2, 3), (0.2, 0.3, 0.5))
    twin = mirror_pin(pin, mmap)
    assert twin == Pin((1, 2, 4), (0.2, 0.3, 0.5))
    weights = np.array([pin.weights])
    point = pin_surface_positions(np.array([pin.vertices]), weights, MIRROR_CO)[0]
    mirrored = pin_surface_positions(np.array([twin.vertices]), weights, MIRROR_CO)[0]
    np.testing.assert_allclose(mirrored, reflect_point(point, (mmap.axis, mmap.offset)))


def test_a_pin_on_the_centre_line_is_its_own_mirror():
    mmap = position_map(MIRROR_CO)
    assert mirror_pin(Pin((2,)), mmap) is None
    assert mirror_pin(Pin((0, 1), (0.5, 0.5)), mmap) is None           # the midpoint of a mirrored pair
    assert mirror_pin(Pin((0, 1), (0.4, 0.6)), mmap) == Pin((1, 0), (0.4, 0.6))


def test_a_pin_without_a_mirror_is_refused_naming_the_vertex():
    mmap = position_map(MIRROR_CO)
    with pytest.raises(ShapeSpaceError, match=r"pin 7 sits on vertex 5") as err:
        mirror_pin(Pin((2, 5), (0.5, 0.5)), mmap, "pin 7")
    assert err.value.code == ErrorCode.NO_MIRROR
    with pytest.raises(ShapeSpaceError, match=r"outside the mirror map's 6 vertices") as err:
        mirror_pin(Pin((9,)), mmap)
    assert err.value.code == ErrorCode.STALE_MIRROR_MAP
