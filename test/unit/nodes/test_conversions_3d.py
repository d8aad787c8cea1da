"""Message <-> numpy conversions in a 3-D vessel tree: (3,) arrays travel bit for bit, y included; planar ones as before."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("rclpy")

from vesselbot_ros.nodes import conversions as cv


def _through_cdr(flat, msg_cls):
    """A flat form through the wire and back: packed to CDR (as published), unpacked (as received)."""
    c = cv.codec(msg_cls)
    return c.unpack(c.pack(flat))


def _odd_doubles(rng, n):
    """Doubles that lose bits in any conversion but an exact one: random mantissas, tiny and huge exponents, -0."""
    v = rng.normal(size=n) * 10.0 ** rng.integers(-300, 300, size=n)
    v[0], v[-1] = -0.0, np.nextafter(1e-3, 1.0)
    return v


def _bits(a):
    """The bytes of an array of doubles: equal bits, not equal values (-0.0 differs from 0.0)."""
    return np.asarray(a, dtype=np.float64).tobytes()


class _Out:  # a three-axis CoilLimiter output's fields
    def __init__(self, applied, slew):
        self.applied, self.k_scale, self.saturated, self.slew_limited, self.rejected = applied, 1.25, True, slew, False


class _Limits:
    saturation_T_per_m, slew_rate_T_per_m_per_s = 0.08, 100.0


@pytest.mark.parametrize("seed", range(5))
def test_three_axis_vectors_survive_the_wire_bit_for_bit(seed):
    from geometry_msgs.msg import PointStamped, Vector3Stamped
    from nav_msgs.msg import Odometry
    from vesselbot_msgs.msg import CoilState, PlantState, ReferenceSample

    rng = np.random.default_rng(seed)
    v = _odd_doubles(rng, 64)
    t, k = 0.123, 123
    p = _through_cdr(cv.measurement_flat(t, v[0:3], dims=3), PointStamped)
    assert _bits(cv.vector_array(p.point_x, p.point_y, p.point_z, 3)) == _bits(v[0:3])
    g = _through_cdr(cv.gradient_flat(t, v[3:6], dims=3), Vector3Stamped)
    assert _bits((g.vector_x, g.vector_y, g.vector_z)) == _bits(v[3:6])
    e = _through_cdr(cv.estimate_flat(t, v[6:9], v[9:12], 0.02, 0.97, dims=3), Odometry)
    x_hat, z_hat, age = cv.estimate_arrays(e, dims=3)
    assert _bits(x_hat) == _bits(v[6:9])
    assert _bits(z_hat) == _bits(v[9:12])
    assert (age, cv.estimate_flow_scale(e)) == (0.02, 0.97)
    r = _through_cdr(cv.reference_flat(k, t, v[12:15], v[15:18], v[18:21], dims=3), ReferenceSample)
    for got, want in zip(cv.reference_arrays(r, dims=3), (v[12:15], v[15:18], v[18:21]), strict=True):
        assert got.shape == (3,)
        assert _bits(got) == _bits(want)
    slew = np.array([False, True, False])
    c = _through_cdr(cv.coil_state_flat(k, t, v[21:24], _Out(v[24:27], slew), _Limits, False, dims=3), CoilState)
    assert _bits((c.commanded_x, c.commanded_y, c.commanded_z, c.applied_x, c.applied_y, c.applied_z)) == _bits(v[21:27])
    assert (c.slew_limited_x, c.slew_limited_y, c.slew_limited_z) == (False, True, False)
    forces = v[30:54].reshape(8, 3)
    s = _through_cdr(cv.plant_state_flat(k, t, v[54:57], v[57:60], tuple(v[60:63]), 2e-3, 5e-4, 6e-4, -4e-4, False, 0,
                                         v[27:30], forces, dims=3), PlantState)
    assert _bits((s.position_x, s.position_y, s.position_z)) == _bits(v[54:57])
    assert _bits((s.velocity_x, s.velocity_y, s.velocity_z)) == _bits(v[57:60])
    assert _bits((s.blood_velocity_x, s.blood_velocity_y, s.blood_velocity_z)) == _bits(v[60:63])
    assert _bits((s.applied_gradient_x, s.applied_gradient_y, s.applied_gradient_z)) == _bits(v[27:30])
    from vesselbot_ros.physics.kernel import TERM_NAMES

    got = np.array([[getattr(s, f"forces_{n}_{a}") for a in "xyz"] for n in TERM_NAMES])
    assert _bits(got) == _bits(forces)


def test_planar_messages_are_what_they_were_and_keep_y_zero():
    from vesselbot_msgs.msg import CoilState

    t = 0.5
    default, planar = cv.measurement_flat(t, (1e-3, 2e-4)), cv.measurement_flat(t, (1e-3, 2e-4), dims=2)
    assert default == planar and planar.point_y == 0.0 and (planar.point_x, planar.point_z) == (1e-3, 2e-4)
    msg = cv.coil_state_msg(3, t, np.array([0.2, -0.4]), _Out(np.array([0.1, -0.2]), np.array([True, True])), _Limits,
                            False)
    assert (msg.commanded.y, msg.applied.y, msg.slew_limited_y) == (0.0, 0.0, False)
    assert (msg.slew_limited_x, msg.slew_limited_z) == (True, True)
    back = _through_cdr(cv.codec(CoilState).flatten(msg), CoilState)
    assert back.slew_limited_y is False
    x_hat, z_hat, _age = cv.estimate_arrays(cv.estimate_flat(t, np.array([1.0, 2.0]), np.array([3.0, 4.0]), 0.0))
    assert x_hat.shape == z_hat.shape == (2,) and x_hat.tolist() == [1.0, 2.0]
    assert [a.shape for a in cv.reference_arrays(cv.reference_flat(0, t, (1, 2), (3, 4), (5, 6)))] == [(2,)] * 3


@pytest.mark.parametrize("dims, vec", [(2, (1.0, 2.0, 3.0)), (3, (1.0, 2.0))])
def test_a_vector_of_the_other_dimension_is_refused_not_silently_packed(dims, vec):
    with pytest.raises(TypeError):
        cv.gradient_flat(0.0, vec, dims=dims)
    with pytest.raises(TypeError):
        cv.plant_state_flat(0, 0.0, vec, vec, vec, 2e-3, 0.0, 0.0, 0.0, False, 0, vec, np.zeros((8, len(vec))), dims=dims)


def test_a_path_in_space_keeps_y_and_a_planar_one_has_y_zero():
    pts3 = np.array([[0.0, 1e-4, 1e-3], [1e-3, -2e-4, 9e-4]])
    msg = cv.path_msg(pts3)
    assert [(p.pose.position.x, p.pose.position.y, p.pose.position.z) for p in msg.poses] == [tuple(r) for r in pts3]
    planar = cv.path_msg(pts3[:, [0, 2]])
    assert [(p.pose.position.x, p.pose.position.y, p.pose.position.z) for p in planar.poses] == [
        (r[0], 0.0, r[2]) for r in pts3]
