import math

import numpy as np
import pytest

from cliport.env import transforms as tf


def test_quat_matrix_roundtrip_and_yaw():
    rng = np.random.default_rng(1)
    for _ in range(50):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        q2 = tf.matrix_to_quat(tf.quat_to_matrix(q))
        assert abs(abs(np.dot(q, q2)) - 1) < 1e-9
    for yaw in (-3.0, -1.0, 0.0, 0.5, 3.1):
        assert tf.quat_to_yaw(tf.yaw_to_quat(yaw)) == pytest.approx(yaw)
        assert tf.quat_to_yaw(tf.euler_to_quat(0, 0, yaw)) == pytest.approx(yaw)


def test_multiply_invert():
    a = ((0.1, 0.2, 0.3), tf.euler_to_quat(0.3, -0.2, 1.0))
    b = ((-0.4, 0.0, 0.5), tf.yaw_to_quat(0.7))
    ident = tf.multiply(a, tf.invert(a))
    assert np.allclose(ident[0], 0, atol=1e-12)
    ab = tf.multiply(a, b)
    assert np.allclose(tf.apply(a, b[0]), ab[0])
    assert tf.quat_to_yaw(tf.multiply(((0, 0, 0), tf.yaw_to_quat(0.5)), b)[1]) == pytest.approx(1.2)
    assert tf.apply(((0, 0, 0), tf.yaw_to_quat(math.pi / 2)), (1, 0, 0)) == pytest.approx([0, 1, 0])


def test_quat_to_matrix_is_pybullets_bit_for_bit():
    """The camera-to-world matrix of the fusion is the one the reference gets from pybullet."""
    import pybullet as p

    rng = np.random.default_rng(3)
    for _ in range(2000):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        np.testing.assert_array_equal(tf.quat_to_matrix(q), np.array(p.getMatrixFromQuaternion(q)).reshape(3, 3))


def test_quat_to_yaw_is_the_reference_z_angle_of_tilted_rotations():
    """quat_to_yaw reads the z angle of R = Ry(b) Rx(a) Rz(yaw) (the reference's quatXYZW_to_eulerXYZ),
    not the yaw of R = Rz Ry Rx: for a tilted object the two differ."""
    rng = np.random.default_rng(4)
    for _ in range(200):
        a, b, yaw = rng.normal(0, 0.3), rng.normal(0, 0.3), rng.uniform(-math.pi, math.pi)
        rx = tf.quat_to_matrix((math.sin(a / 2), 0, 0, math.cos(a / 2)))
        ry = tf.quat_to_matrix((0, math.sin(b / 2), 0, math.cos(b / 2)))
        q = tf.matrix_to_quat(ry @ rx @ tf.quat_to_matrix(tf.yaw_to_quat(yaw)))
        assert math.remainder(tf.quat_to_yaw(q) - yaw, 2 * math.pi) == pytest.approx(0, abs=1e-9)
