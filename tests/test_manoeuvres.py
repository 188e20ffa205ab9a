"""The manoeuvring target: derivatives against finite differences, the turn limit, the box, seeds.

Tolerances of the finite differences (h the step, |p| ≈ 3 m, speed v = 1 m/s, turn rate
ω = 5 rad/s, so |p'''| = ω²v = 25 m/s³ and |p''''| = ω³v = 125 m/s⁴ in a turn):

- velocity, central difference with h = 1e-5 s: truncation h²|p'''|/6 ≈ 4e-10 m/s, rounding
  ≈ 1e-16 · 3 m / h ≈ 3e-11 m/s; bound 1e-7 m/s;
- acceleration, second central difference with h = 1e-4 s: truncation h²|p''''|/12 ≈ 1e-7 m/s²,
  rounding ≈ 4 · 1e-16 · 3 m / h² ≈ 1e-7 m/s²; bound 1e-5 m/s².
"""

import math

import numpy as np
import pytest

from gimbal_lab.trajectories import R_WORLD_MARKER, ManoeuvringTarget, target_pose

CENTRE = np.array([3.0, 0.0, 2.0])
HALF = np.array([0.5, 1.0, 1.0])


def _away_from_joins(target, t, margin_s):
    """Times of ``t`` at least ``margin_s`` from any join of a leg and a turn (a is discontinuous there)."""
    joins = target.segment_start_s
    i = np.searchsorted(joins, t)
    gap = np.minimum(np.abs(t - joins[np.clip(i - 1, 0, None)]), np.abs(joins[np.clip(i, None, len(joins) - 1)] - t))
    return t[gap > margin_s]


@pytest.mark.parametrize("seed", [0, 7])
def test_velocity_and_acceleration_are_derivatives_of_position(seed):
    target = ManoeuvringTarget(seed=seed)
    t = _away_from_joins(target, np.linspace(0.01, 119.99, 4001), 1e-3)
    assert t.size > 3500 and target.turning(t).any() and (~target.turning(t)).any()
    h = 1e-5
    numeric_v = (target.position(t + h) - target.position(t - h)) / (2 * h)
    assert np.abs(numeric_v - target.velocity(t)).max() < 1e-7
    h = 1e-4
    numeric_a = (target.position(t + h) - 2 * target.position(t) + target.position(t - h)) / h**2
    assert np.abs(numeric_a - target.acceleration(t)).max() < 1e-5


def test_position_and_velocity_are_continuous_at_the_joins():
    target = ManoeuvringTarget(seed=1)
    joins = target.segment_start_s[1:]
    joins = joins[joins < 119.0]  # the last segment may start after duration_s
    eps = 1e-9
    # across a join p moves by v·2ε = 2e-9 m; v by |a|·2ε = 1e-8 m/s at most
    assert np.abs(target.position(joins + eps) - target.position(joins - eps)).max() < 1e-8
    assert np.abs(target.velocity(joins + eps) - target.velocity(joins - eps)).max() < 1e-7


def test_turns_are_coordinated_and_within_the_design_limit():
    target = ManoeuvringTarget(seed=2)
    t = np.linspace(0.0, 120.0, 120_001)  # 1 kHz
    a, v = target.acceleration(t), target.velocity(t)
    a_norm = np.linalg.norm(a, axis=1)
    assert a_norm.max() <= 5.0 + 1e-9  # docs/design.md: coordinated turns up to 5 m/s²
    turning = target.turning(t)
    assert np.allclose(a_norm[turning], target.turn_accel_m_s2, atol=1e-9)  # constant-rate turns
    assert np.all(a_norm[~turning] == 0.0)
    assert np.abs(np.einsum("ij,ij->i", a, v)).max() < 1e-9  # a ⊥ v: the speed does not change
    # the turn rate |v × a| / v² is a/v
    rate = np.linalg.norm(np.cross(v[turning], a[turning]), axis=1) / target.speed_m_s**2
    assert np.allclose(rate, target.turn_rate_rad_s, atol=1e-9)
    assert 0.2 < turning.mean() < 0.7  # both legs and turns take a real share of the time


def test_each_turn_changes_heading_by_30_to_180_degrees_and_legs_last_their_bounds():
    target = ManoeuvringTarget(seed=8)
    starts = target.segment_start_s
    durations = np.diff(starts)
    in_turn = target.turning(starts[:-1] + 1e-9)
    assert np.array_equal(in_turn, np.arange(len(durations)) % 2 == 1)  # leg, turn, leg, ...
    turn_rad = durations[in_turn] * target.turn_rate_rad_s
    assert turn_rad.min() >= math.radians(30.0) - 1e-9 and turn_rad.max() <= math.pi + 1e-9
    # heading change from the velocities either side of each turn
    v_in, v_out = target.velocity(starts[:-1][in_turn]), target.velocity(starts[1:][in_turn])
    cos = np.einsum("ij,ij->i", v_in, v_out) / target.speed_m_s**2
    assert np.allclose(np.arccos(np.clip(cos, -1, 1)), turn_rad, atol=1e-6)
    legs = durations[~in_turn]
    assert legs.min() >= 0.4 - 1e-12 and legs.max() <= 1.5 + 1e-12


def test_speed_is_constant_and_legs_are_straight():
    target = ManoeuvringTarget(seed=3)
    t = np.linspace(0.0, 120.0, 24_001)
    assert np.allclose(np.linalg.norm(target.velocity(t), axis=1), target.speed_m_s, atol=1e-12)
    joins = target.segment_start_s
    joins = np.append(joins[joins < 120.0], 120.0)
    legs = 0
    for start, end in zip(joins[:-1], joins[1:]):
        inside = np.linspace(start, end, 7)[1:-1]
        if not target.turning(inside).any():
            v = target.velocity(inside)
            assert np.abs(v - v[0]).max() == 0.0  # one velocity along the whole leg
            legs += 1
    assert legs > 40


@pytest.mark.parametrize("seed", range(12))
def test_stays_inside_the_study_box_for_120_s(seed):
    target = ManoeuvringTarget(seed=seed)
    p = target.position(np.linspace(0.0, 120.0, 12_001))
    assert np.all(np.abs(p - CENTRE) <= HALF + 1e-12)
    # and uses it across the view and in depth (legs end within ±0.1 m of the centre's depth and
    # turns reach up to 2r = 0.4 m beyond, so the depth span is smaller than the box's 1 m)
    span = p.max(axis=0) - p.min(axis=0)
    assert span[0] > 0.2 and span[1] > 1.2 and span[2] > 1.2


def test_same_seed_same_path_other_seed_other_path():
    t = np.linspace(0.0, 120.0, 1201)
    a, b, c = ManoeuvringTarget(seed=5), ManoeuvringTarget(seed=5), ManoeuvringTarget(seed=6)
    assert np.array_equal(a.position(t), b.position(t))
    assert np.abs(a.position(t) - c.position(t)).max() > 0.1
    g1, g2 = np.random.default_rng(11), np.random.default_rng(11)
    assert np.array_equal(ManoeuvringTarget(seed=g1).position(t), ManoeuvringTarget(seed=g2).position(t))


def test_shapes_and_target_pose():
    target = ManoeuvringTarget(seed=4)
    assert target.position(1.0).shape == (3,) and target.velocity(1.0).shape == (3,)
    assert target.acceleration(np.array([0.5, 1.0])).shape == (2, 3)
    assert target.turning(1.0).shape == ()
    T = target_pose(target, 1.0)
    assert np.array_equal(T[:3, 3], target.position(1.0)) and np.array_equal(T[:3, :3], R_WORLD_MARKER)
    assert target.turn_radius_m == pytest.approx(0.2) and target.turn_rate_rad_s == pytest.approx(5.0)


@pytest.mark.parametrize(
    "kwargs, error, field",
    [
        (dict(seed=-1), ValueError, "seed"),
        (dict(seed=1.5), TypeError, "seed"),
        (dict(speed_m_s=0.0), ValueError, "speed_m_s"),
        (dict(speed_m_s="fast"), TypeError, "speed_m_s"),
        (dict(turn_accel_m_s2=6.0), ValueError, "turn_accel_m_s2"),
        (dict(min_leg_s=-1.0), ValueError, "min_leg_s"),
        (dict(min_leg_s=2.0, max_leg_s=1.0), ValueError, "max_leg_s"),
        (dict(min_turn_rad=2.0), ValueError, "min_turn_rad"),
        (dict(centre_m=(1.0, 2.0)), ValueError, "centre_m"),
        (dict(half_extent_m=(0.3, 1.0, 1.0)), ValueError, "half_extent_m"),  # 0.3 m < two turn radii
        (dict(duration_s=math.inf), ValueError, "duration_s"),
    ],
)
def test_bad_input_names_the_field(kwargs, error, field):
    with pytest.raises(error, match=field):
        ManoeuvringTarget(**kwargs)


def test_times_outside_the_plan_are_refused():
    target = ManoeuvringTarget(seed=0, duration_s=10.0)
    for t in (-0.1, 10.5, math.nan):
        with pytest.raises(ValueError, match="t_s"):
            target.position(t)
