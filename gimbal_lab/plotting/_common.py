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


def save_figure(fig, name: str, out_dir: str | os.PathLike | None = None, dpi: int = 120, formats=None):
    """Save ``fig`` as ``<out_dir>/<name>.png`` (default folder ``results/figures``).

    With ``formats`` (e.g. ``("png", "svg")``: SVG or PDF for papers) every format is written
    and the list of paths is returned; without it, the PNG's path.
    """
    folder = Path(out_dir) if out_dir is not None else results_dir("figures")
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for fmt in formats or ("png",):
        path = folder / f"{name}.{fmt}"
        fig.savefig(path, dpi=dpi, bbox_inches="tight")
        paths.append(path)
    return paths if formats else paths[0]
