"""Tracking filters against independent oracles, and their consistency by Monte Carlo.

Oracles
-------
- filterpy's ``KalmanFilter`` with F written out by hand and Q from filterpy's
  ``Q_continuous_white_noise``: the CV and CA filters must agree to 1e-9 (relative) on the same
  data, missed frames and per-update R included.
- ``scipy.linalg.expm``: the turn model's F = e^{A dt} and, by Van Loan's block exponential,
  Q = ∫ e^{Aτ} G q Gᵀ e^{Aᵀτ} dτ.
- filterpy's ``IMMEstimator`` with two ``KalmanFilter`` modes built from the same F, Q and Π:
  the IMM's state, covariance and mode probabilities must agree to 1e-9.

Consistency (Bar-Shalom et al. 2001, §5.4): over 50 seeded runs, the run-average NEES and NIS at
each time step should lie in the two-sided 95 % interval of χ²(dof·50)/50. The steps of one run
are correlated, so the share of steps inside is not binomial; the tests ask for at least 85 % of
the steps (95 % expected) and for the mean over steps to lie inside the interval. Over 60 other
blocks of 50 seeds (1000 onwards) the share stayed at 0.89 or above for the CV and CA filters;
the IMM's NEES, of an approximate posterior, fell below 0.85 in 2 blocks of 60 (0.94 here).
Draws go through Cholesky factors (``_gaussian``), so a seed gives the same sample on every CPU.

The measurement noise of every test follows the detector's geometry: along the line of sight
from the camera at (0, 0, 2) m, σ = 2 cm · (d / 3 m)²; across it, σ = 3 mm · (d / 3 m).
"""

from __future__ import annotations

import math

import filterpy.common as filterpy_common  # the [test] extra's oracle
import filterpy.kalman as filterpy_kalman
import numpy as np
import pytest
import scipy.linalg
from scipy.stats import chi2, gamma

from gimbal_lab.filters import IMM, ConstantAcceleration, ConstantVelocity, chi2_bounds, nees
from gimbal_lab.trajectories import ManoeuvringTarget

CAMERA_M = np.array([0.0, 0.0, 2.0])
FRAME_S = 1.0 / 30.0
N_RUNS = 50


def detector_noise(p_m) -> np.ndarray:
    """Covariance of a position measured at ``p_m`` (see the module docstring), m²."""
    d = float(np.linalg.norm(p_m - CAMERA_M))
    e = (p_m - CAMERA_M) / d
    along, across = 0.02 * (d / 3.0) ** 2, 0.003 * d / 3.0
    return across**2 * (np.eye(3) - np.outer(e, e)) + along**2 * np.outer(e, e)


def _gaussian(rng, mean, cov) -> np.ndarray:
    """One draw from N(mean, cov) through the Cholesky factor of cov: a seed gives the same numbers
    on every CPU (to rounding). ``Generator.multivariate_normal`` factors cov by SVD, and R's two
    equal variances across the line of sight leave its singular vectors free to turn: another
    BLAS kernel turns them, and the same seed draws another sample. Variables of zero variance
    (the CV mode's acceleration) are drawn at their mean."""
    out = np.array(mean, dtype=float)
    keep = np.diag(cov) > 0
    out[keep] += np.linalg.cholesky(cov[np.ix_(keep, keep)]) @ rng.standard_normal(int(keep.sum()))
    return out


def _allclose(a, b, rtol=1e-9):
    """|a − b| ≤ rtol · max|b|: agreement to 1e-9 of the matrix's scale."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    return np.abs(a - b).max() <= rtol * max(np.abs(b).max(), 1e-300)


def _kinematic_F(dt, order):
    """Transition of p (order 2: p, v; order 3: p, v, a), written out by hand, blocks of I₃."""
    I, Z = np.eye(3), np.zeros((3, 3))
    if order == 2:
        return np.block([[I, dt * I], [Z, I]])
    return np.block([[I, dt * I, 0.5 * dt * dt * I], [Z, I, dt * I], [Z, Z, I]])


def _filterpy_kf(order, x0, P0):
    kf = filterpy_kalman.KalmanFilter(dim_x=3 * order, dim_z=3)
    kf.x, kf.P = x0.reshape(-1, 1).copy(), P0.copy()
    kf.H = np.hstack([np.eye(3), np.zeros((3, 3 * order - 3))])
    return kf


# ----------------------------------------------------------------------------------------------
# oracles


@pytest.mark.parametrize("order", [2, 3], ids=["CV", "CA"])
def test_cv_and_ca_equal_filterpy_kalman_filter(order):
    rng = np.random.default_rng(0)
    q, v_std, a_std = 0.7, 1.5, 4.0
    ours = (ConstantVelocity(q_accel_m2_s3=q, velocity_std_m_s=v_std, gate_probability=1.0) if order == 2 else
            ConstantAcceleration(q_jerk_m2_s5=q, velocity_std_m_s=v_std, accel_std_m_s2=a_std, gate_probability=1.0))
    # irregular times: frames at 30 Hz with some missed (2 or 3 frames apart)
    times = np.cumsum(rng.choice([1, 1, 1, 2, 3], size=60)) * FRAME_S
    truth = np.array([3.0, 0.0, 2.0]) + np.outer(times, [0.3, -0.8, 0.5]) + 0.4 * np.sin(times)[:, None]
    ref = None
    for k, t in enumerate(times):
        R = detector_noise(truth[k])
        z = _gaussian(rng, truth[k], R)
        assert ours.update(t, z, R)
        if ref is None:  # one-point start, as documented
            x0 = np.zeros(3 * order)
            x0[:3] = z
            P0 = np.diag(np.r_[np.zeros(3), np.full(3, v_std**2), np.full(3 * order - 6, a_std**2)])
            P0[:3, :3] = R
            ref, t_ref = _filterpy_kf(order, x0, P0), t
            assert math.isnan(ours.nis)
            continue
        dt = t - t_ref
        ref.predict(F=_kinematic_F(dt, order), Q=filterpy_common.Q_continuous_white_noise(
            order, dt=dt, spectral_density=q, block_size=3, order_by_dim=False))
        ref.update(z, R=R)
        t_ref = t
        assert _allclose(ours.x, ref.x[:, 0]) and _allclose(ours.P, ref.P)
        y = ref.y[:, 0]  # filterpy's innovation and its covariance S
        assert ours.nis == pytest.approx(y @ np.linalg.solve(ref.S, y), rel=1e-9)
    # prediction 0.4 s ahead against filterpy's
    ref.predict(F=_kinematic_F(0.4, order), Q=filterpy_common.Q_continuous_white_noise(
        order, dt=0.4, spectral_density=q, block_size=3, order_by_dim=False))
    x_pred, P_pred = ref.x, ref.P
    mean, cov = ours.predict(times[-1] + 0.4)
    assert _allclose(mean, x_pred[:6, 0]) and _allclose(cov, P_pred[:6, :6])
    assert np.array_equal(ours.position(times[-1] + 0.4), mean[:3])
    assert np.array_equal(ours.velocity(times[-1] + 0.4), mean[3:])


def _van_loan(A, G, q, dt):
    """F = e^{A dt} and Q = ∫₀^dt e^{Aτ} G q Gᵀ e^{Aᵀτ} dτ from one block exponential."""
    n = len(A)
    M = np.zeros((2 * n, 2 * n))
    M[:n, :n], M[:n, n:], M[n:, n:] = -A, q * G @ G.T, A.T
    E = scipy.linalg.expm(M * dt)
    F = E[n:, n:].T
    return F, F @ E[:n, n:]


@pytest.mark.parametrize("dt", [FRAME_S, 0.25, 1.7])
@pytest.mark.parametrize("w", [5.0, 0.8])
def test_turn_model_equals_matrix_exponential(dt, w):
    q = 30.0
    A1 = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, -w * w, 0.0]])  # ṗ = v, v̇ = a, ȧ = −ω² v
    F_ref, Q_ref = _van_loan(np.kron(A1, np.eye(3)), np.kron([[0.0], [0.0], [1.0]], np.eye(3)), q, dt)
    (F_cv, Q_cv), (F_ct, Q_ct) = IMM(q_jerk_m2_s5=q, turn_rate_rad_s=w, q_accel_m2_s3=0.3).models(dt)
    assert _allclose(F_ct, F_ref) and _allclose(Q_ct, Q_ref)
    # the CV mode: p' = p + v dt, v' = v, a' = 0; white acceleration only on (p, v)
    assert np.array_equal(F_cv[6:], np.zeros((3, 9))) and np.array_equal(Q_cv[6:], np.zeros((3, 9)))
    assert _allclose(Q_cv[:6, :6], filterpy_common.Q_continuous_white_noise(
        2, dt=dt, spectral_density=0.3, block_size=3, order_by_dim=False))


def test_turn_model_tends_to_constant_acceleration_and_composes():
    q, dt = 30.0, 0.4
    (_, _), (F, Q) = IMM(q_jerk_m2_s5=q, turn_rate_rad_s=1e-6).models(dt)
    F_ca = _kinematic_F(dt, 3)
    Q_ca = filterpy_common.Q_continuous_white_noise(3, dt=dt, spectral_density=q, block_size=3, order_by_dim=False)
    assert _allclose(F, F_ca, 1e-9) and _allclose(Q, Q_ca, 1e-9)  # ω² dt² ≈ 2e-13: CA to rounding
    # exact discretisation: predicting over 0.1 s then 0.3 s equals predicting over 0.4 s
    imm = IMM(q_jerk_m2_s5=q)
    (_, _), (F1, Q1) = imm.models(0.1)
    (_, _), (F2, Q2) = imm.models(0.3)
    (_, _), (F12, Q12) = imm.models(0.4)
    assert _allclose(F2 @ F1, F12) and _allclose(F2 @ Q1 @ F2.T + Q2, Q12)


def test_imm_equals_filterpy_imm_estimator():
    target = ManoeuvringTarget(seed=3, duration_s=10.0)
    imm = IMM(gate_probability=1.0)
    rng = np.random.default_rng(1)
    times = np.arange(0.0, 6.0, FRAME_S)
    truth = target.position(times)
    (F_cv, Q_cv), (F_ct, Q_ct) = imm.models(FRAME_S)
    ref = None
    for k, t in enumerate(times):
        R = detector_noise(truth[k])
        z = _gaussian(rng, truth[k], R)
        imm.update(t, z, R)
        if ref is None:
            # one-point start: p = z, P_pp = R, velocity σ 2 m/s; acceleration 0, σ 5 m/s² in the
            # CT mode and exactly 0 in the CV mode; modes at the chain's stationary (1.0 : 0.4)
            modes = []
            for F, Q, a_var in ((F_cv, Q_cv, 0.0), (F_ct, Q_ct, 25.0)):
                P0 = np.diag(np.r_[np.zeros(3), np.full(3, 4.0), np.full(3, a_var)])
                P0[:3, :3] = R
                kf = _filterpy_kf(3, np.r_[z, np.zeros(6)], P0)
                kf.F, kf.Q = F, Q
                modes.append(kf)
            ref = filterpy_kalman.IMMEstimator(modes, np.array([1.0, 0.4]) / 1.4, imm.transition_matrix(FRAME_S))
            continue
        ref.predict()
        for kf in ref.filters:
            kf.R = R
        ref.update(z)
        assert _allclose(imm.x, ref.x_post[:, 0]) and _allclose(imm.P, ref.P_post)
        assert _allclose(imm.mode_probability, ref.mu)
    assert ref.mu[1] > 0.5 or ref.mu[0] > 0.5  # the run exercised the mixing: modes were told apart
    assert np.ptp([kf.x[6:, 0] for kf in ref.filters]) > 0.1


def test_transition_matrix_is_a_markov_chain_in_time():
    imm = IMM(sojourn_s=(1.0, 0.4))
    P1, P2, P3 = imm.transition_matrix(0.1), imm.transition_matrix(0.2), imm.transition_matrix(0.3)
    assert np.allclose(P1.sum(axis=1), 1.0, atol=1e-15)
    assert _allclose(P1 @ P2, P3, 1e-12)  # Chapman–Kolmogorov
    # leaving CV at rate 1/1.0 s: over a short dt, probability ≈ dt / 1.0 s
    assert imm.transition_matrix(1e-6)[0, 1] == pytest.approx(1e-6, rel=1e-5)
    stationary = np.array([1.0, 0.4]) / 1.4
    assert _allclose(stationary @ imm.transition_matrix(5.0), stationary, 1e-12)
    assert _allclose(imm.mode_probability, stationary, 1e-15)


# ----------------------------------------------------------------------------------------------
# evaluation helpers


def test_nees_by_hand_and_batched():
    assert nees([1.0, 2.0], [0.0, 0.0], np.diag([1.0, 4.0])) == pytest.approx(2.0, abs=1e-15)
    P = np.array([[2.0, 1.0], [1.0, 2.0]])  # P⁻¹ = [[2, −1], [−1, 2]] / 3
    assert nees([1.0, 1.0], [0.0, 0.0], P) == pytest.approx(2.0 / 3.0, abs=1e-15)
    batch = nees(np.ones((4, 2)), np.zeros((4, 2)), np.broadcast_to(P, (4, 2, 2)))
    assert batch.shape == (4,) and np.allclose(batch, 2.0 / 3.0)


def test_chi2_bounds_against_gamma_and_simulation():
    lo, hi = chi2_bounds(3, 50)
    # χ²(k) is Gamma(k/2, scale 2)
    assert lo == pytest.approx(gamma.ppf(0.025, 75, scale=2) / 50, rel=1e-12)
    assert hi == pytest.approx(gamma.ppf(0.975, 75, scale=2) / 50, rel=1e-12)
    # 20 000 simulated averages of 50 χ²(3): 95 % inside (binomial σ 0.15 %, bound ±0.6 %)
    means = np.random.default_rng(0).chisquare(3, size=(20_000, 50)).mean(axis=1)
    assert abs(np.mean((means >= lo) & (means <= hi)) - 0.95) < 0.006
    lo99, hi99 = chi2_bounds(6, 10, p=0.99)
    assert lo99 < chi2_bounds(6, 10)[0] and hi99 > chi2_bounds(6, 10)[1]


# ----------------------------------------------------------------------------------------------
# consistency by Monte Carlo


def _truth_from_model(order, q, rng, n_steps, v_std, a_std):
    """A motion drawn from the filter's own model with filterpy's Q and the hand F, x₀ from its prior."""
    F = _kinematic_F(FRAME_S, order)
    Q = filterpy_common.Q_continuous_white_noise(order, dt=FRAME_S, spectral_density=q, block_size=3,
                                                 order_by_dim=False)
    x = np.r_[3.0, 0.0, 2.0, rng.normal(0.0, v_std, 3), rng.normal(0.0, a_std, 3 * order - 6)]
    states = [x]
    for _ in range(n_steps - 1):
        x = F @ x + _gaussian(rng, np.zeros(3 * order), Q)
        states.append(x)
    return np.array(states)


def _run_single(make_filter, order, q, seed, n_steps=90, v_std=2.0, a_std=5.0):
    """NEES of the full state and NIS at each frame, and the rejections, of one seeded run."""
    rng = np.random.default_rng(seed)
    states = _truth_from_model(order, q, rng, n_steps, v_std, a_std)
    f = make_filter()
    out_nees, out_nis = [], []
    for k, x in enumerate(states):
        R = detector_noise(x[:3])
        f.update(k * FRAME_S, _gaussian(rng, x[:3], R), R)
        out_nees.append(nees(x, f.x, f.P) if f.t_s == k * FRAME_S else math.nan)  # x is at f.t_s
        out_nis.append(f.nis)
    return np.array(out_nees), np.array(out_nis), f.n_rejected


def _check_consistent(per_step, dof, label):
    """Average over runs at each step against the 95 % χ² interval; returns the numbers."""
    lo, hi = chi2_bounds(dof, per_step.shape[0])
    avg = per_step.mean(axis=0)
    inside = float(np.mean((avg >= lo) & (avg <= hi)))
    summary = f"{label}: mean {avg.mean():.3f} in [{lo:.3f}, {hi:.3f}], {inside:.0%} of steps inside"
    assert inside >= 0.85 and lo <= avg.mean() <= hi, summary
    return summary


def _make(order, q, **kwargs):
    if order == 2:
        return lambda: ConstantVelocity(q_accel_m2_s3=q, **kwargs)
    return lambda: ConstantAcceleration(q_jerk_m2_s5=q, **kwargs)


@pytest.mark.parametrize("order", [2, 3], ids=["CV on CV truth", "CA on CA truth"])
def test_single_model_filters_are_consistent_on_their_own_motion(order):
    """Full-state NEES (6 or 9 dof) and NIS (3 dof); the gate is off: consistency is a property
    of the recursion, and a gate trims the NIS tail it is tested on."""
    q = 1.0 if order == 2 else 10.0
    runs = [_run_single(_make(order, q, gate_probability=1.0), order, q, seed) for seed in range(N_RUNS)]
    all_nees = np.array([r[0] for r in runs])
    all_nis = np.array([r[1][1:] for r in runs])  # the first update starts the track: no NIS
    print(_check_consistent(all_nees, 3 * order, "NEES"), "|", _check_consistent(all_nis, 3, "NIS"))


#: χ²₀.₉₉(3), the default gate, from χ²(3) = Gamma(3/2, scale 2) rather than the filter's own call
GATE_NIS = gamma.ppf(0.99, 1.5, scale=2.0)
#: standard normal draws for _rejection_probability, fixed so that a seed gives the same numbers
_UNIT_DRAWS = np.random.default_rng(12345).standard_normal((20_000, 3))
#: two-sided 0.1 % quantile of the standard normal: the statistical bounds below fail 1 run in 1000
Z_999 = 3.29


def _rejection_probability(z_mean, z_cov, prior_mean, S):
    """P(NIS > GATE_NIS) for a filter that predicts the measurement at ``prior_mean`` with
    innovation covariance ``S`` when the measurement is truly N(z_mean, z_cov); by 20 000 draws
    (standard error below 0.004, far below the σ of the sums it enters)."""
    y = (z_mean - prior_mean) + _UNIT_DRAWS @ np.linalg.cholesky(z_cov).T
    nis = np.einsum("ij,ji->i", y, np.linalg.solve(S, y.T))
    return float(np.mean(nis > GATE_NIS))


def _gate_run(order, q, seed, n_steps=90):
    """The default gate on one seeded run of the filter's own motion, beside the same filter with
    the gate off (the exact filter). Per gated frame: (probability of a rejection given the past,
    1 if rejected, 1 if no measurement was rejected before), and the run's restarts."""
    rng = np.random.default_rng(seed)
    states = _truth_from_model(order, q, rng, n_steps, v_std=2.0, a_std=5.0)
    gated, exact = _make(order, q)(), _make(order, q, gate_probability=1.0)()
    held, out = 0, []  # measurements the gated track holds since it (re)started
    for k, x in enumerate(states):
        t, R = k * FRAME_S, detector_noise(x[:3])
        z = _gaussian(rng, x[:3], R)
        if held < order:  # the gate does not apply yet (filters module docstring)
            held += gated.update(t, z, R)
        else:
            clean = gated.n_rejected == 0  # then the gated filter has fused what the exact one has
            if clean:
                p = 1.0 - 0.99
            else:
                mean, cov = gated.predict(t)
                mean_exact, cov_exact = exact.predict(t)
                p = _rejection_probability(mean_exact[:3], cov_exact[:3, :3] + R, mean[:3], cov[:3, :3] + R)
            rejected, restarts = gated.n_rejected, gated.n_restarts
            accepted = gated.update(t, z, R)
            out.append((p, gated.n_rejected - rejected, clean))
            held = 1 if gated.n_restarts > restarts else held + accepted
        exact.update(t, z, R)
    return np.array(out, dtype=float), gated.n_restarts


@pytest.mark.parametrize("order", [2, 3], ids=["CV", "CA"])
def test_default_gate_rejects_what_the_exact_filter_predicts(order):
    """The default gate, χ²₀.₉₉(3), on 50 runs of a target moving as the filter models it.

    Until a run's first rejection the gated filter equals the exact one (gate off), whose NIS is
    χ²(3) and independent from frame to frame: each frame is rejected with probability 1 %.
    After a rejection it is not: the rejected measurement's information is lost, while the
    state error that made its innovation large stays in the prior, which P does not know. So
    rejections cascade (about 40 % of the frames after a rejection are rejected, and now and
    then ten in a row restart the track), and the count of a run of 50 is not binomial around
    1 %: with the same seeds, BLAS builds that drew other samples gave 46 to 90 rejections of
    about 4400 gated frames (the old bound, 0.5 % < rate < 2 %, failed at 90).

    Theory gives every gated frame's rejection probability p_k given the past: 1 % while the
    run is clean; after, the probability that the gated filter's NIS exceeds the gate when the
    measurement follows the exact filter's prediction, N(exact prior, P_exact + R). Rejections
    minus Σ p_k are a martingale with variance Σ p_k (1 − p_k), and the clean frames alone one
    with variance Σ 0.01 · 0.99: both asserted within 3.29 σ (two-sided 0.1 %). Measured here:
    CV 85 rejections for 77.3 ± 7.3 predicted (30 on 2822 clean frames), CA 48 for 50.2 ± 6.9
    (32 on 2735).
    """
    q = 1.0 if order == 2 else 10.0
    runs = [_gate_run(order, q, seed) for seed in range(N_RUNS)]
    p, rejected, clean = np.concatenate([r[0] for r in runs]).T
    clean = clean.astype(bool)
    expected, sigma = p.sum(), math.sqrt(np.sum(p * (1.0 - p)))
    n_clean = int(clean.sum())
    after = np.concatenate([r[0][1:, 1][r[0][:-1, 1] == 1] for r in runs])  # the frames that follow a rejection
    print(f"{int(rejected.sum())} rejections of {len(p)} gated frames, {expected:.1f} ± {sigma:.1f} predicted; "
          f"clean frames {int(rejected[clean].sum())} of {n_clean}; frames after a rejection "
          f"{int(after.sum())} of {len(after)}; restarts {sum(r[1] for r in runs)}")
    assert abs(rejected.sum() - expected) < Z_999 * sigma, (rejected.sum(), expected, sigma)
    assert abs(rejected[clean].sum() - 0.01 * n_clean) < Z_999 * math.sqrt(0.01 * 0.99 * n_clean)


def _imm_own_model_run(imm, seed, n_steps=90):
    """(p, v) NEES and NIS of one run on a motion drawn from the IMM's own switching model: the
    mode follows the chain Π, the state the mode's F and Q, x₀ and the first mode the IMM's prior."""
    rng = np.random.default_rng(seed)
    modes, Pi = imm.models(FRAME_S), imm.transition_matrix(FRAME_S)
    mode = rng.choice(2, p=np.array(imm.sojourn_s) / sum(imm.sojourn_s))
    a0 = np.zeros(3) if mode == 0 else rng.normal(0.0, imm.accel_std_m_s2, 3)
    x = np.r_[3.0, 0.0, 2.0, rng.normal(0.0, imm.velocity_std_m_s, 3), a0]
    out = []
    for k in range(n_steps):
        if k:
            mode = rng.choice(2, p=Pi[mode])
            F, Q = modes[mode]
            x = F @ x + _gaussian(rng, np.zeros(9), Q)
        R = detector_noise(x[:3])
        imm.update(k * FRAME_S, _gaussian(rng, x[:3], R), R)
        mean, cov = imm.predict(k * FRAME_S)
        out.append((nees(x[:6], mean, cov), imm.nis))
    return np.array(out)


def test_imm_is_consistent_on_its_own_switching_model():
    """The IMM's moment-matched estimate is an approximation (the exact posterior is a growing
    mixture); on the motion it models, (p, v) NEES and NIS still pass. F and Q come from the
    filter here; they are checked against their oracles above."""
    make = lambda: IMM(q_accel_m2_s3=0.5, q_jerk_m2_s5=50.0, turn_rate_rad_s=2.0, sojourn_s=(1.0, 0.5),
                       gate_probability=1.0)
    runs = np.array([_imm_own_model_run(make(), seed) for seed in range(N_RUNS)])
    print(_check_consistent(runs[:, :, 0], 6, "NEES (p, v)"), "|", _check_consistent(runs[:, 1:, 1], 3, "NIS"))


def _imm_on_target(seed, duration_s=6.0):
    target = ManoeuvringTarget(seed=seed, duration_s=duration_s + 1.0)
    rng = np.random.default_rng(10_000 + seed)
    imm = IMM(turn_rate_rad_s=target.turn_rate_rad_s)
    times = np.arange(0.0, duration_s, FRAME_S)
    p, v = target.position(times), target.velocity(times)
    out = np.empty((len(times), 3))
    for k, t in enumerate(times):
        R = detector_noise(p[k])
        imm.update(t, _gaussian(rng, p[k], R), R)
        mean, cov = imm.predict(t)  # at t even when the frame was rejected
        out[k] = nees(np.r_[p[k], v[k]], mean, cov), imm.nis, imm.mode_probability[1]
    starts = target.segment_start_s
    since = times - starts[np.searchsorted(starts, times, side="right") - 1]
    return out, target.turning(times), since, imm.n_rejected


def test_imm_on_the_manoeuvring_target():
    """IMM (defaults, turn rate of the target) on 50 seeded targets for 6 s at 30 frames/s.

    Measured (seeds 0–49; the defaults were chosen on seeds 1000–1049): on legs, from 0.3 s after
    a turn, the average NEES of (p, v) is about 3 against a 95 % interval of about [4.4, 7.9]
    (6 degrees of freedom): the filter is *conservative* there, not consistent. The legs are
    exact straight lines, while every filter that can follow a turn carries process noise;
    a single CV filter on a noise-free straight line shows the same (NEES ≈ 3 for any q from 5e-4
    to 0.5 m²/s³). The test therefore asks only that the IMM is never over-confident on legs.
    In turns the average NEES is about 6 but spread (too high at the onset of a turn, too low
    later): not consistent either; not asserted. The turn mode's probability rises in turns and
    falls on legs.
    """
    runs = [_imm_on_target(seed) for seed in range(N_RUNS)]
    values = np.array([r[0] for r in runs])  # (run, step, [NEES, NIS, μ_CT])
    turning = np.array([r[1] for r in runs])
    since = np.array([r[2] for r in runs])
    settled = np.arange(values.shape[1]) * FRAME_S >= 0.5  # after the track's start-up
    leg = ~turning & (since >= 0.3) & settled
    uppers, averages = [], []
    for k in np.nonzero(settled)[0]:
        runs_on_leg = leg[:, k]
        if runs_on_leg.sum() >= 10:
            averages.append(values[runs_on_leg, k, 0].mean())
            uppers.append(chi2_bounds(6, int(runs_on_leg.sum()))[1])
    averages, uppers = np.array(averages), np.array(uppers)
    assert len(averages) > 100
    assert np.mean(averages <= uppers) >= 0.95, np.mean(averages <= uppers)
    turn = turning & (since >= 0.15) & settled
    mu_turn, mu_leg = values[turn][:, 2].mean(), values[leg][:, 2].mean()
    print(f"legs: NEES {averages.mean():.2f}, upper bounds {uppers.min():.2f}–{uppers.max():.2f}; "
          f"turns: NEES {values[turning & settled][:, 0].mean():.2f}; μ_CT turns {mu_turn:.2f} legs {mu_leg:.2f}")
    assert mu_turn > 0.5 and mu_leg < 0.2
    # the turn probability rises through a turn: later in a turn it is higher than at its start
    early = turning & (since < 0.05) & settled
    assert values[turn][:, 2].mean() > values[early][:, 2].mean() + 0.2
    # the track is kept: fewer rejections than the gate's nominal 1 %
    assert sum(r[3] for r in runs) < 0.01 * values.shape[0] * values.shape[1]


# ----------------------------------------------------------------------------------------------
# gating, coasting, determinism, input checks


def _settled(make, n=30):
    """A filter after ``n`` exact measurements of a straight, slow motion."""
    f = make()
    R = detector_noise(np.array([3.0, 0.0, 2.0]))
    for k in range(n):
        f.update(k * FRAME_S, np.array([3.0, 0.2 * k * FRAME_S, 2.0]), R)
    return f, R, n * FRAME_S


FILTERS = {"CV": ConstantVelocity, "CA": ConstantAcceleration, "IMM": IMM}


@pytest.mark.parametrize("name", FILTERS)
def test_gate_rejects_ten_sigma_accepts_one_sigma(name):
    f, R, t = _settled(FILTERS[name])
    mean, cov = f.predict(t)
    L = np.linalg.cholesky(cov[:3, :3] + R)
    e = np.array([0.0, 0.6, 0.8])
    before = f.x, f.P, f.t_s
    assert not f.update(t, mean[:3] + 10.0 * L @ e, R)  # NIS = 100 > χ²₀.₉₉(3) = 11.34
    assert f.nis == pytest.approx(100.0, rel=1e-9) and f.n_rejected == 1
    assert np.array_equal(f.x, before[0]) and np.array_equal(f.P, before[1]) and f.t_s == before[2]
    assert f.update(t, mean[:3] + L @ e, R)  # NIS = 1
    assert f.nis == pytest.approx(1.0, rel=1e-9) and f.n_rejected == 1


@pytest.mark.parametrize("probability", [0.99, 0.9])
def test_gate_threshold_is_the_chi2_quantile(probability):
    threshold = chi2.ppf(probability, 3)
    for nis, accepted in ((threshold * 0.999, True), (threshold * 1.001, False)):
        f, R, t = _settled(lambda: ConstantVelocity(gate_probability=probability))
        mean, cov = f.predict(t)
        L = np.linalg.cholesky(cov[:3, :3] + R)
        assert f.update(t, mean[:3] + math.sqrt(nis) * L @ np.array([1.0, 0.0, 0.0]), R) is accepted


@pytest.mark.parametrize("name", FILTERS)
def test_a_lost_track_restarts_after_ten_rejections_in_a_row(name):
    f, R, t = _settled(FILTERS[name])
    far = np.array([3.0, -0.8, 1.2])  # a second object, metres away from the track
    for k in range(9):
        assert not f.update(t + k * FRAME_S, far, R)
    assert f.n_rejected == 9 and f.n_restarts == 0
    assert f.update(t + 9 * FRAME_S, far, R)  # the tenth starts a new track there
    assert f.n_restarts == 1 and np.array_equal(f.position(f.t_s), far) and math.isnan(f.nis)
    # one outlier between accepted measurements resets the count
    g, R, t = _settled(lambda: FILTERS[name](restart_after=2))
    assert not g.update(t, far, R)
    assert g.update(t, np.array([3.0, 0.2 * t, 2.0]), R)
    assert not g.update(t + FRAME_S, far, R) and g.n_restarts == 0


@pytest.mark.parametrize("name", FILTERS)
def test_coasting_grows_the_position_covariance(name):
    f, R, t_last = _settled(FILTERS[name])
    state = f.x
    traces, dets = [], []
    for k in range(1, 31):  # 30 missed frames
        t = t_last + k * FRAME_S
        assert f.update(t, None) is False
        cov = f.predict(t)[1][:3, :3]
        traces.append(np.trace(cov))
        dets.append(np.linalg.det(cov))
    assert np.all(np.diff(traces) > 0) and np.all(np.diff(dets) > 0)
    assert np.array_equal(f.x, state) and f.n_rejected == 0  # a missed frame changes nothing
    # after 1 s blind the target, 0.2 m further on, is picked up again
    assert f.update(t_last + 1.0, np.array([3.0, 0.2 * (t_last + 1.0), 2.0]), R)


@pytest.mark.parametrize("name", FILTERS)
def test_predict_does_not_change_the_filter(name):
    a, R, t = _settled(FILTERS[name])
    b, _, _ = _settled(FILTERS[name])
    for dt in (0.0, 0.01, 0.5, 3.0):
        a.predict(t + dt), a.position(t + dt), a.velocity(t + dt)
    z = np.array([3.0, 0.2 * t, 2.0])
    a.update(t, z, R), b.update(t, z, R)
    assert np.array_equal(a.x, b.x) and np.array_equal(a.P, b.P)
    mean, cov = a.predict(a.t_s)  # at the last update the prediction is the estimate
    assert np.allclose(mean, a.x[:6], rtol=0, atol=1e-15) and np.allclose(cov, a.P[:6, :6], rtol=0, atol=1e-15)


def test_same_seed_same_numbers():
    make = lambda: ConstantAcceleration(q_jerk_m2_s5=10.0)
    first, second = _run_single(make, 3, 10.0, seed=4), _run_single(make, 3, 10.0, seed=4)
    assert all(np.array_equal(a, b, equal_nan=True) for a, b in zip(first[:2], second[:2]))
    assert np.array_equal(_imm_on_target(2, 2.0)[0], _imm_on_target(2, 2.0)[0], equal_nan=True)


@pytest.mark.parametrize(
    "make, error, field",
    [
        (lambda: ConstantVelocity(q_accel_m2_s3=0.0), ValueError, "q_accel_m2_s3"),
        (lambda: ConstantVelocity(q_accel_m2_s3="1"), TypeError, "q_accel_m2_s3"),
        (lambda: ConstantVelocity(gate_probability=0.0), ValueError, "gate_probability"),
        (lambda: ConstantVelocity(gate_probability=1.2), ValueError, "gate_probability"),
        (lambda: ConstantVelocity(velocity_std_m_s=math.nan), ValueError, "velocity_std_m_s"),
        (lambda: ConstantAcceleration(q_jerk_m2_s5=-1.0), ValueError, "q_jerk_m2_s5"),
        (lambda: ConstantAcceleration(accel_std_m_s2=True), TypeError, "accel_std_m_s2"),
        (lambda: IMM(turn_rate_rad_s=0.0), ValueError, "turn_rate_rad_s"),
        (lambda: IMM(sojourn_s=(1.0,)), ValueError, "sojourn_s"),
        (lambda: IMM(sojourn_s=(1.0, -0.4)), ValueError, "sojourn_s"),
        (lambda: ConstantVelocity(q_accel=1.0), TypeError, "q_accel"),
        (lambda: ConstantVelocity(restart_after=0), ValueError, "restart_after"),
        (lambda: IMM(restart_after=2.5), ValueError, "restart_after"),
    ],
)
def test_bad_parameters_name_the_field(make, error, field):
    with pytest.raises(error, match=field):
        make()


def test_bad_measurements_and_times():
    f = ConstantVelocity()
    with pytest.raises(RuntimeError, match="no measurement"):
        f.predict(0.0)
    assert f.update(0.0, None) is False and not f.initialised  # nothing to coast yet
    R = 1e-4 * np.eye(3)
    with pytest.raises(ValueError, match="z_m"):
        f.update(0.0, [1.0, 2.0], R)
    with pytest.raises(ValueError, match="z_m"):
        f.update(0.0, [1.0, math.nan, 2.0], R)
    with pytest.raises(ValueError, match="R_m2"):
        f.update(0.0, [3.0, 0.0, 2.0])
    with pytest.raises(ValueError, match="R_m2"):
        f.update(0.0, [3.0, 0.0, 2.0], np.eye(2))
    with pytest.raises(ValueError, match="symmetric"):
        f.update(0.0, [3.0, 0.0, 2.0], np.array([[1.0, 0.5, 0], [0, 1, 0], [0, 0, 1]]))
    with pytest.raises(ValueError, match="positive definite"):
        f.update(0.0, [3.0, 0.0, 2.0], np.diag([1.0, 0.0, 1.0]))
    assert f.update(1.0, [3.0, 0.0, 2.0], R) and f.initialised
    with pytest.raises(ValueError, match="t_s must not precede"):
        f.update(0.5, [3.0, 0.0, 2.0], R)
    with pytest.raises(ValueError, match="t_s must not precede"):
        f.predict(0.5)
    with pytest.raises(ValueError, match="t_s"):
        f.predict(math.inf)
    with pytest.raises(ValueError, match="x_true and x_est"):
        nees([1.0, 2.0], [1.0, 2.0, 3.0], np.eye(2))
    with pytest.raises(ValueError, match="P must"):
        nees([1.0, 2.0], [1.0, 2.0], np.eye(3))
    for args, field in (((0, 5), "dof"), ((3, 0), "n_runs"), ((3, 5, 1.0), "p"), ((3.0, 5), "dof")):
        with pytest.raises(ValueError, match=field):
            chi2_bounds(*args)
    f.reset()
    assert not f.initialised and f.n_accepted == 0 and f.x is None
