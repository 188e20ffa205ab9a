"""Settings for the whole test run (unit tests and notebooks)."""

import os

# One BLAS thread in this process and in the notebook kernels it starts (before numpy is
# imported): the matrices are small and a second thread beside the renderer only spins
# (gimbal_lab.runner.CHILD_THREAD_LIMITS; the study workers get the same limits anyway).
for _name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_name, "1")

# Notebooks draw their interactive explorers once, statically (gimbal_lab.plotting.interactive):
# the kernels nbmake starts inherit this environment.
os.environ.setdefault("GIMBAL_LAB_WIDGETS", "0")

# The extension studies' notebooks (09 onwards) run 3 replicates per cell under the test suite
# instead of the studies' declared 10: the moving-drone grid alone is 36 cells of blurred frames,
# about 33 minutes at full size on 2 cores. Same code, fewer replicates; their checks hold at any
# count. Set GIMBAL_LAB_REPLICATES=10 before `pytest` to test the full size.
os.environ.setdefault("GIMBAL_LAB_REPLICATES", "3")
