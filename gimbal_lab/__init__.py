"""gimbal-lab: active (gimbal) versus passive visual tracking from drones.

Reproduces and extends Hansen & de Figueiredo, "Active Object Detection and Tracking Using
Gimbal Mechanisms for Autonomous Drone Applications", Drones 2024, 8(2), 55,
doi:10.3390/drones8020055.

Modules
-------
camera        intrinsics, projection, Brown-Conrady distortion
kinematics    DH transforms and the 3-DoF yaw-roll-pitch gimbal
scene         headless pyrender scene synthesis
detection     sphere (circle and exact ellipse) and ArUco localisation
control       axis plant, PID, Ziegler-Nichols, inner and outer loops
trajectories  the study's target motions
simulation    the closed tracking loop
experiments   the paper's grid, parallel runs, summaries and claim checks
plotting      every figure
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("gimbal-lab")
except PackageNotFoundError:  # running from a source tree that was not installed
    __version__ = "0.0.0"
