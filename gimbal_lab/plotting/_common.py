"""Helpers shared by the plotting submodules."""

from __future__ import annotations

import os
from pathlib import Path


def results_dir(sub: str = "") -> Path:
    """Return (and create) the results folder, ``$GIMBAL_LAB_RESULTS`` or ``./results``."""
    root = Path(os.environ.get("GIMBAL_LAB_RESULTS", "results"))
    path = root / sub if sub else root
    path.mkdir(parents=True, exist_ok=True)
    return path


def save_figure(fig, name: str, out_dir: str | os.PathLike | None = None, dpi: int = 120) -> Path:
    """Save ``fig`` as ``<out_dir>/<name>.png`` (default ``results/figures``) and return the path."""
    folder = Path(out_dir) if out_dir is not None else results_dir("figures")
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{name}.png"
    fig.savefig(path, dpi=dpi, bbox_inches="tight")
    return path
