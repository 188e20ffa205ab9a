"""gimbal-lab: active (gimbal) versus passive visual tracking from drones.

Reproduces and extends Hansen & de Figueiredo, "Active Object Detection and Tracking Using
Gimbal Mechanisms for Autonomous Drone Applications", Drones 2024, 8(2), 55,
doi:10.3390/drones8020055.

Modules
-------
camera        intrinsics, projection, Brown-Conrady distortion
kinematics    DH transforms and the 3-DoF yaw-roll-pitch gimbal
scene         headless pyrender scene synthesis, sensor noise
detection     sphere (circle and exact ellipse) and ArUco localisation
evaluation    static accuracy sweeps of the detectors
control       axis plant, PID, Ziegler-Nichols, inner and outer loops
tracking      line-of-sight filter and the predictive outer loop
trajectories  the study's target motions
config        the run's config: camera, gimbal, platform, target, pointing, estimator parts
simulation    the closed tracking loop
runner        executors (local spawn pool, Dask), the results store, progress
outputs       output files whole or absent; report folders with a manifest of their own files
video         H.264 MP4 clips that browsers play (PyAV)
stats         replicate statistics and three-way verdicts
studies       one module per study (paper: the 16-cell grid and its claims)
mavlink       MAVLink Gimbal Protocol v2: a driver and the lab's gimbal as a simulated device
plotting      every figure
"""



def __getattr__(name):
    # ``__version__`` is read on first use: importlib.metadata costs a tenth of a second, which
    # ``gimbal-lab --help`` should not pay.
    if name == "__version__":
        from importlib.metadata import PackageNotFoundError, version

        try:
            value = version("gimbal-lab")
        except PackageNotFoundError:  # running from a source tree that was not installed
            value = "0.0.0"
        globals()["__version__"] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
