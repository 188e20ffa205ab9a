"""The lab's studies: one module each, with its grid, tables, claims and report.

A study module defines ``NAME``, ``DESCRIPTION``, its parameters dataclass as ``Study`` (with
``from_toml``, ``replicates`` and ``revolutions``), ``grid(params)`` and
``run_study(params, out, store, executor, jobs, progress, clips)``, used by ``gimbal-lab run NAME``.
"""

from __future__ import annotations

from importlib import import_module

__all__ = ["STUDIES", "load"]

#: Study name → module (``gimbal-lab run --list`` prints them).
STUDIES = {"paper": "gimbal_lab.studies.paper", "moving-drone": "gimbal_lab.studies.moving_drone",
           "lens-sweep": "gimbal_lab.studies.lens_sweep", "occlusion": "gimbal_lab.studies.occlusion"}


def load(name: str):
    """The module of study ``name`` (a ValueError lists the known studies)."""
    if name not in STUDIES:
        raise ValueError(f"unknown study {name!r}; known studies: {', '.join(sorted(STUDIES))}")
    return import_module(STUDIES[name])
