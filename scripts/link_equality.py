"""How close a run through the MAVLink link with every effect off comes to the in-process run.

For each seed of the link study's cells (the paper's sphere and marker, distorted lens, circular
path, active), the run in-process and the same run through the simulated gimbal device with a
status every inner step, no latency, no quantisation, no loss (``GimbalLink(status_rate_hz=1000)``)
are compared frame by frame: the first frame whose detection (detected, u, v) differs, whether the
joints stay within :func:`gimbal_lab.mavlink.loop.equality_bound` (the messages' float32 fields)
up to it, the largest joint-angle and world-estimate differences over the run, and the difference
of the replicate's mean distance error (m). tests/test_mavlink_loop.py checks three of these runs;
this script shows how every seed's compare::

    python scripts/link_equality.py [N_SEEDS] [REVOLUTIONS]
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

import sys

import numpy as np

from gimbal_lab.config import GimbalLink
from gimbal_lab.mavlink.loop import equality_bound
from gimbal_lab.simulation import make_renderer, simulate
from gimbal_lab.studies.paper import PaperStudy

JOINTS = ["q_yaw_rad", "q_roll_rad", "q_pitch_rad"]
ESTIMATE = ["est_x_m", "est_y_m", "est_z_m"]
TARGETS = ("sphere", "aruco")


def compare(in_process, linked) -> dict:
    a, b = in_process.frames, linked.frames
    fa, fb = a[["detected", "u_px", "v_px"]].to_numpy(float), b[["detected", "u_px", "v_px"]].to_numpy(float)
    differs = ~np.all((fa == fb) | (np.isnan(fa) & np.isnan(fb)), axis=1)
    first = int(np.argmax(differs)) if differs.any() else len(a)
    dq = np.abs(a[JOINTS].to_numpy() - b[JOINTS].to_numpy())
    bound = equality_bound(a[JOINTS].to_numpy(), a["t_mid_s"].to_numpy())
    measured = a["revolution"] >= 1
    mean = lambda f: float(f.loc[measured & f["detected"], "abs_error_m"].mean())  # noqa: E731
    return {"first_difference": first, "within_bound": bool(np.all(dq[:first + 1] <= bound[:first + 1])),
            "max_dq_before_rad": float(dq[:first + 1].max()), "max_dq_rad": float(dq.max()),
            "max_dest_m": float(np.nanmax(np.abs(a[ESTIMATE].to_numpy() - b[ESTIMATE].to_numpy()))),
            "d_mean_error_m": mean(b) - mean(a)}


def main() -> None:
    n_seeds = int(sys.argv[1]) if len(sys.argv) > 1 else 10
    revolutions = float(sys.argv[2]) if len(sys.argv) > 2 else 2.0
    study = PaperStudy(replicates=max(n_seeds, 2))
    ideal = GimbalLink(status_rate_hz=1000.0)
    same = bounded = 0
    worst = 0.0
    for target in TARGETS:
        base = study.config(target, "distorted", "circular", "active", 0).replace(revolutions=revolutions)
        renderer = make_renderer(base)
        try:
            for seed in study.seeds[:n_seeds]:
                config = study.config(target, "distorted", "circular", "active", seed).replace(revolutions=revolutions)
                out = compare(simulate(config, renderer), simulate(config.with_(pointing__link=ideal), renderer))
                n = config.n_frames
                same += out["first_difference"] == n
                bounded += out["within_bound"]
                worst = max(worst, abs(out["d_mean_error_m"]))
                first = "none" if out["first_difference"] == n else f"frame {out['first_difference']}"
                print(f"{target:6s} seed {seed}: first detection that differs: {first}; joints within the bound "
                      f"up to it: {out['within_bound']} (max |Δq| {out['max_dq_before_rad']:.2e} rad); over the run "
                      f"max |Δq| {out['max_dq_rad']:.2e} rad, max |Δestimate| {out['max_dest_m']:.2e} m, "
                      f"Δ mean distance error {out['d_mean_error_m']:.2e} m", flush=True)
        finally:
            renderer.close()
    runs = n_seeds * len(TARGETS)
    print(f"{same} of {runs} runs detect identically on every frame; {bounded} of {runs} keep the joints within "
          f"the bound up to their first differing detection; largest |Δ mean distance error| {worst:.2e} m")


if __name__ == "__main__":
    main()
