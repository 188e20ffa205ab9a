"""Predictive outer loop: the filter against exact polynomial motion, pointing against look_at."""

import math

import numpy as np
import pytest

from gimbal_lab.camera import Intrinsics, project
from gimbal_lab.kinematics import GimbalKinematics
from gimbal_lab.tracking import LineOfSightFilter, PredictiveLoop

KIN = GimbalKinematics.default()
CAM = Intrinsics.default()


def test_filter_locks_onto_constant_acceleration():
    f = LineOfSightFilter(meas_std_rad=1e-6)
    t = np.arange(0, 2, 1 / 30)
    az = 0.1 + 0.5 * t + 0.3 * t**2
    el = -0.2 - 0.4 * t + 0.1 * t**2
    for ti, a, e in zip(t, az, el):
        f.update(ti, a, e)
    # noise-free measurements of a motion inside the model: the prediction converges to it
    angle, rate = f.predict(2.1)
    assert np.allclose(angle, [0.1 + 0.5 * 2.1 + 0.3 * 2.1**2, -0.2 - 0.4 * 2.1 + 0.1 * 2.1**2], atol=1e-4)
    assert np.allclose(rate, [0.5 + 0.6 * 2.1, -0.4 + 0.2 * 2.1], atol=1e-3)


def test_filter_rejects_bad_input():
    with pytest.raises(ValueError, match="meas_std_rad"):
        LineOfSightFilter(meas_std_rad=0)
    f = LineOfSightFilter()
    with pytest.raises(RuntimeError):
        f.predict(0.0)
    f.update(1.0, 0, 0)
    with pytest.raises(ValueError, match="decrease"):
        f.update(0.5, 0, 0)


def test_loop_points_camera_at_a_static_target():
    loop = PredictiveLoop(CAM, KIN)
    target = np.array([3.0, 0.8, 0.4])  # base frame, left of and above the home axis
    q = np.zeros(3)
    dt = 1 / 30
    for k in range(60):
        T = KIN.forward(q)
        p_cam = T[:3, :3].T @ (target - T[:3, 3])
        loop.observe(k * dt, project(p_cam, CAM)[0], q, range_m=float(np.linalg.norm(p_cam)))
        q = q + loop.command(k * dt, q) * dt
    T = KIN.forward(q)
    axis = T[:3, 2]
    to_target = (target - T[:3, 3]) / np.linalg.norm(target - T[:3, 3])
    # 2 s of 30 Hz updates with kp = 15/s: the residual decays like (1 - 0.5)^60, far below 1e-6 rad
    assert math.acos(min(1.0, axis @ to_target)) < 1e-6
    assert np.allclose(q, KIN.look_at(target), atol=1e-6)


def test_loop_holds_without_detections():
    loop = PredictiveLoop(CAM, KIN, coast_s=0.2)
    assert np.array_equal(loop.command(0.0, np.zeros(3)), np.zeros(3))
    with pytest.raises(ValueError, match="range"):
        loop.observe(0.0, (400.0, 200.0), np.zeros(3))  # no range yet: the loop has no default
    loop.observe(0.0, (400.0, 200.0), np.zeros(3), range_m=3.0)
    assert np.any(loop.command(0.1, np.zeros(3)) != 0)
    assert np.array_equal(loop.command(0.5, np.zeros(3)), np.zeros(3))  # past the coast time: hold
