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


class SavedPath(type(Path())):
    """A path :func:`save_figure` wrote; a notebook shows it as the plain path, not ``PosixPath('...')``."""

    def __repr__(self) -> str:  # IPython's display uses it too
        return str(self)


class SavedPaths(list):
    """The paths :func:`save_figure` wrote; a notebook shows them one per line, not as a list of
    ``PosixPath('...')``."""

    def __repr__(self) -> str:  # IPython's display uses it too
        return "\n".join(str(p) for p in self)


def save_figure(fig, name: str, out_dir: str | os.PathLike | None = None, dpi: int = 120, formats=None):
    """Save ``fig`` as ``<out_dir>/<name>.png`` (default folder ``results/figures``).

    With ``formats`` (e.g. ``("png", "svg")``: SVG or PDF for papers) every format is written
    and the list of paths is returned; without it, the PNG's path. A notebook cell ending in this
    call shows the paths as plain text, one per line.
    """
    folder = Path(out_dir) if out_dir is not None else results_dir("figures")
    folder.mkdir(parents=True, exist_ok=True)
    paths = SavedPaths()
    for fmt in formats or ("png",):
        path = SavedPath(folder / f"{name}.{fmt}")
        fig.savefig(path, dpi=dpi, bbox_inches="tight")
        paths.append(path)
    return paths if formats else paths[0]


def interactive(fn, **controls):
    """``ipywidgets.interactive(fn, **controls)``, or one static call of ``fn`` when widgets are off.

    With ``GIMBAL_LAB_WIDGETS=0`` (the test suite sets it, see ``conftest.py``) ``fn`` is called
    once with every control's initial value and None is returned: the notebook draws the same
    figure without live widgets. Under nbmake, notebooks whose cells displayed live widgets were
    seen to stall now and then (the kernel idle, its reply never received) until the cell timeout;
    in a live JupyterLab the widgets are unchanged (``scripts/browser_check.py`` drives them).
    """
    if os.environ.get("GIMBAL_LAB_WIDGETS", "1") == "0":
        fn(**{name: getattr(control, "value", control) for name, control in controls.items()})
        return None
    import ipywidgets

    return ipywidgets.interactive(fn, **controls)
