"""Trajectories: hand-checked points, finite-difference velocities, the marker's orientation."""

import numpy as np
import pytest

from gimbal_lab.trajectories import R_WORLD_MARKER, Trajectory, target_pose


def test_circle_hand_points():
    circle = Trajectory.circular()
    # phi = 0, pi/2, pi: left of the camera, top, right (world y is left, z is up)
    expected = [[3, 1, 2], [3, 0, 3], [3, -1, 2]]
    assert np.allclose(circle.position([0.0, 0.5, 1.0]), expected, atol=1e-12)
    radii = np.linalg.norm(circle.position(np.linspace(0, 2, 50)) - [3, 0, 2], axis=1)
    assert np.allclose(radii, 1.0)


def test_diagonal_spans_design_depths_and_passes_centre():
    diag = Trajectory.diagonal()
    p = diag.position(np.linspace(0, 2, 2001))
    assert p[:, 0].min() == pytest.approx(2.0) and p[:, 0].max() == pytest.approx(4.0)
    assert np.allclose(diag.position([0.0, 1.0]), [[3, 0, 2], [3, 0, 2]], atol=1e-12)


@pytest.mark.parametrize("traj", [Trajectory.circular(), Trajectory.diagonal()], ids=["circular", "diagonal"])
def test_velocity_is_derivative_of_position(traj):
    t = np.linspace(0, 2, 37)
    h = 1e-6
    numeric = (traj.position(t + h) - traj.position(t - h)) / (2 * h)
    # central differences: truncation ~ h^2 * |p'''|, rounding ~ 1e-16 / h; both far below 1e-6
    assert np.abs(numeric - traj.velocity(t)).max() < 1e-6


def test_marker_faces_home_camera():
    assert np.allclose(R_WORLD_MARKER @ R_WORLD_MARKER.T, np.eye(3))
    assert np.linalg.det(R_WORLD_MARKER) == pytest.approx(1.0)
    assert np.allclose(R_WORLD_MARKER[:, 2], [-1, 0, 0])  # normal towards the camera at the origin
    assert np.allclose(R_WORLD_MARKER[:, 1], [0, 0, 1])  # marker "up" is world up
    T = target_pose(Trajectory.circular(), 0.5)
    assert np.allclose(T[:3, 3], [3, 0, 3]) and np.allclose(T[:3, :3], R_WORLD_MARKER)


@pytest.mark.parametrize(
    "kwargs, field",
    [(dict(kind="square"), "kind"), (dict(period_s=0), "period_s"), (dict(radius_m=-1), "radius_m"),
     (dict(centre_m=(1, 2)), "centre_m"), (dict(amplitude_m=(1, np.nan, 0)), "amplitude_m")],
)
def test_invalid_trajectories(kwargs, field):
    with pytest.raises(ValueError, match=field):
        Trajectory(**kwargs)


def test_stationary_target_stays_at_the_circle_centre_on_the_home_axis():
    still = Trajectory.stationary()
    t = np.linspace(0.0, 5.0, 11)
    assert np.array_equal(still.position(t), np.tile([3.0, 0.0, 2.0], (11, 1)))
    assert np.array_equal(still.velocity(t), np.zeros((11, 3)))
    assert np.array_equal(still.position(0.7), np.array([3.0, 0.0, 2.0]))
    assert still.centre_m == Trajectory.circular().centre_m  # the circle's centre
    # on the home optical axis: straight ahead of the home camera at (0, 0, 2) m
    assert np.array_equal(target_pose(still, 1.3)[:3, 3] - np.array([0.0, 0.0, 2.0]), np.array([3.0, 0.0, 0.0]))


def test_the_target_part_builds_the_stationary_path():
    from gimbal_lab.config import Target

    path = Target(trajectory="stationary").path(seed=0, duration_s=4.0, home_camera_m=np.zeros(3), field_rad=1.0)
    assert path == Trajectory.stationary()
    with pytest.raises(ValueError, match="target.trajectory"):
        Target(trajectory="still")
