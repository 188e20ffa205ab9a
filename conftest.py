"""Settings for the whole test run (unit tests and notebooks)."""

import os
import sys

# GIMBAL_LAB_OTHER_CPU=1 runs the tests as on another x86-64 CPU: the libraries pick their kernels
# per CPU at run time, and an iterative or ill-conditioned computation's last digits follow the
# kernels (issue 26). Set before numpy and OpenCV are loaded, in this process and in the notebook
# kernels and workers it starts: OpenCV's dispatched code at its SSE3 baseline and Intel IPP off,
# numpy's SIMD loops at their baseline, OpenBLAS's generic SSE3 kernels. Each can also be set by
# hand, and so can a BLAS thread count other than 1 (OPENBLAS_NUM_THREADS=2 splits BLAS sums
# differently, but the study workers then run two BLAS threads each beside their renderer).
if os.environ.get("GIMBAL_LAB_OTHER_CPU", "0") not in ("", "0"):
    if "numpy" in sys.modules or "cv2" in sys.modules:
        raise RuntimeError("GIMBAL_LAB_OTHER_CPU must take effect before numpy and cv2 are imported")
    os.environ.setdefault("OPENCV_CPU_DISABLE", "SSE4.1,SSE4.2,AVX,FP16,AVX2,AVX512-SKX")
    os.environ.setdefault("OPENCV_IPP", "disabled")
    os.environ.setdefault("NPY_DISABLE_CPU_FEATURES", "X86_V3 X86_V4 AVX512_ICL AVX512_SPR")
    os.environ.setdefault("OPENBLAS_CORETYPE", "Prescott")
    import cv2

    cv2.setUseOptimized(False)  # this process: IPP, dispatch and OpenCL off at once

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
