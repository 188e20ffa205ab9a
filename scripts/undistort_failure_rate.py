"""How often ``gimbal_lab.camera.undistort`` fails on random strong-pincushion lenses.

Each lens draws k1 ~ U(0, 1) (pincushion, up to strong), k2, k3 ~ U(−1, 1) and p1, p2 ~
U(−0.01, 0.01); each lens gets 20 points spread uniformly over the disc where its radial map
r·(1 + k1 r² + k2 r⁴ + k3 r⁶) rises (radius capped at 2, points up to 0.999 of it), kept where
the map keeps its orientation all the way from the centre (det J > 0 at 64 steps along the
segment from the origin: beyond a fold made by the tangential terms a point shares its image
with one before it). A lens fails when undistort refuses any of its points or brings one back
farther than 4·‖J⁻¹‖·tol from where it was (tol = 1e-12, undistort's default stopping
residual). The disc is computed here with ``np.roots`` (accurate for coefficients of order
one), independently of the code under test, so the script measures any version of it::

    python scripts/undistort_failure_rate.py [N_LENSES] [SEED]
"""

from __future__ import annotations

import sys

import numpy as np

from gimbal_lab.camera import BrownConrady, UndistortionError, distort, undistort

TOL = 1e-12


def disc_radius(k1, k2, k3) -> float:
    roots = np.roots([7 * k3, 5 * k2, 3 * k1, 1.0])
    s = roots[np.isreal(roots)].real
    s = s[s > 0]
    return float(np.sqrt(s.min())) if s.size else np.inf


def jacobian(x, lens):
    """Forward differences are too coarse near the fold: the analytic Jacobian, written out."""
    k1, k2, p1, p2, k3 = lens.coefficients
    u, v = x[:, 0], x[:, 1]
    r2 = u * u + v * v
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    dradial = k1 + r2 * (2 * k2 + 3 * k3 * r2)
    J = np.empty((len(x), 2, 2))
    J[:, 0, 0] = radial + 2 * u * u * dradial + 2 * p1 * v + 6 * p2 * u
    J[:, 0, 1] = J[:, 1, 0] = 2 * u * v * dradial + 2 * p1 * u + 2 * p2 * v
    J[:, 1, 1] = radial + 2 * v * v * dradial + 6 * p1 * v + 2 * p2 * u
    return J


def main(n_lenses: int = 5000, seed: int = 1) -> None:
    rng = np.random.default_rng(seed)
    refused = wrong = points = bad_points = 0
    for _ in range(n_lenses):
        k1 = rng.uniform(0.0, 1.0)
        k2, k3 = rng.uniform(-1.0, 1.0, 2)
        p1, p2 = rng.uniform(-0.01, 0.01, 2)
        lens = BrownConrady(k1=k1, k2=k2, p1=p1, p2=p2, k3=k3)
        r = 0.999 * min(disc_radius(k1, k2, k3), 2.0) * np.sqrt(rng.uniform(0.0, 1.0, 20))
        angle = rng.uniform(0.0, 2 * np.pi, 20)
        x = np.column_stack((r * np.cos(angle), r * np.sin(angle)))
        along = (x[:, None, :] * np.linspace(0.0, 1.0, 65)[None, 1:, None]).reshape(-1, 2)
        unfolded = np.all(np.linalg.det(jacobian(along, lens)).reshape(len(x), 64) > 0, axis=1)
        x = x[unfolded]
        J = jacobian(x, lens)
        points += len(x)
        try:
            back = undistort(distort(x, lens), lens, tol=TOL)
        except UndistortionError:
            refused += 1
            bad_points += len(x)
            continue
        bound = 4 * TOL / np.linalg.svd(J, compute_uv=False)[:, -1]
        far = np.hypot(*(back - x).T) > bound
        wrong += bool(far.any())
        bad_points += int(far.sum())
    print(f"{n_lenses} lenses, {points} points: refused {refused / n_lenses:.2%} of lenses, "
          f"wrong answer {wrong / n_lenses:.2%} of lenses; failed points {bad_points / points:.2%} "
          "(a refused lens counts all its points)")


if __name__ == "__main__":
    main(*(int(a) for a in sys.argv[1:3]))
