"""The lab's studies: one module each, with its grid, tables, claims and report.

A study module defines ``NAME``, ``DESCRIPTION``, its parameters dataclass as ``Study`` (with
``from_toml``, ``replicates`` and ``revolutions``), ``grid(params)`` and
``run_study(params, out, store, executor, jobs, progress, clips)``, used by ``gimbal-lab run NAME``;
a study that runs more than its grid (the paper's known-lens pipelines, the moving drone's arms)
also defines ``all_configs(params)``, every run it makes, which the command counts.
A scenario file (``gimbal-lab run FILE.toml``) is run by :mod:`gimbal_lab.studies.scenario`, a
study module whose ``Study`` is the file.
"""

from __future__ import annotations

from importlib import import_module

__all__ = ["STUDIES", "load"]

#: Study name → module (``gimbal-lab run --list`` prints them).
STUDIES = {"paper": "gimbal_lab.studies.paper", "moving-drone": "gimbal_lab.studies.moving_drone",
           "lens-sweep": "gimbal_lab.studies.lens_sweep", "occlusion": "gimbal_lab.studies.occlusion",
           "link": "gimbal_lab.studies.link", "payoff": "gimbal_lab.studies.payoff",
           "light": "gimbal_lab.studies.light", "exposure": "gimbal_lab.studies.exposure"}


def load(name: str):
    """The module of study ``name`` (a ValueError lists the known studies); for a path ending in
    ``.toml``, the scenario module that runs a scenario file (:mod:`gimbal_lab.studies.scenario`)."""
    if name.endswith(".toml"):
        return import_module("gimbal_lab.studies.scenario")
    if name not in STUDIES:
        raise ValueError(f"unknown study {name!r}; known studies: {', '.join(sorted(STUDIES))}")
    return import_module(STUDIES[name])
