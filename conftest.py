"""Settings for the whole test run (unit tests and notebooks)."""

import os

# Notebooks draw their interactive explorers once, statically (gimbal_lab.plotting.interactive):
# the kernels nbmake starts inherit this environment.
os.environ.setdefault("GIMBAL_LAB_WIDGETS", "0")
