"""Notebooks as git holds them carry no outputs and open with the paper's reference (README,
"The notebooks": outputs are stripped before a notebook is committed).

What is checked is each notebook's blob in git's index, the version the next commit records (the
last commit's, unless a change is staged), never the working copy: a notebook opened in
JupyterLab gets outputs and execution counts the moment it is run or autosaved, and exploring it
must not fail the suite. With nbstripout's git filter installed (``nbstripout --install``, once
per clone), ``git add`` stages the stripped notebook whatever the working copy holds.

Outside a git checkout (a release archive, ``git archive``, a copy without ``.git``) the
committed notebooks cannot be read and these tests are skipped, saying why. A notebook not yet
added to git is skipped too: it is checked once it is staged.
"""

import json
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.ipynb"))


def _git(*args: str, data: bytes | None = None) -> bytes:
    return subprocess.run(["git", "-C", str(ROOT), *args], input=data, capture_output=True, check=True).stdout


def _staged_notebooks() -> tuple[dict[str, str], str | None]:
    """Each notebook's path (relative to the root) -> its staged blob id, and None; or ({}, why
    the committed notebooks cannot be read)."""
    if shutil.which("git") is None:
        return {}, "git is not installed: the committed notebooks cannot be read"
    try:
        top = _git("rev-parse", "--show-toplevel").decode().strip()
    except (subprocess.CalledProcessError, OSError) as exc:
        said = (getattr(exc, "stderr", None) or b"").decode(errors="replace").strip().splitlines()
        return {}, (f"{ROOT} is not a git checkout (a release archive or a copy?): the committed notebooks cannot be "
                    f"read{f' (git: {said[0]})' if said else ''}")
    if Path(top).resolve() != ROOT:  # e.g. an unpacked archive inside some other repository
        return {}, f"{ROOT} is not the top of a git checkout (git finds {top}): the committed notebooks cannot be read"
    blobs = {}
    for line in _git("ls-files", "--stage", "-z", "--", "notebooks/*.ipynb").decode().split("\0"):
        if line:
            meta, path = line.split("\t", 1)
            _mode, blob, stage = meta.split()
            if stage != "0":
                return {}, f"{path} is unmerged in git's index: finish the merge first"
            blobs[path] = blob
    return blobs, None


STAGED, NOT_A_CHECKOUT = _staged_notebooks()


def committed_cells(path: Path) -> list[dict]:
    """The cells of ``path`` as git's index holds it (skips when that cannot be read)."""
    if NOT_A_CHECKOUT:
        pytest.skip(NOT_A_CHECKOUT)
    name = path.relative_to(ROOT).as_posix()
    if name not in STAGED:
        pytest.skip(f"{name} is not in git yet: it is checked once it is added")
    return json.loads(_git("cat-file", "blob", STAGED[name]))["cells"]


def test_there_are_notebooks():
    assert NOTEBOOKS, "no notebooks found under notebooks/"


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.name for p in NOTEBOOKS])
def test_notebook_is_stripped(path):
    cells = committed_cells(path)
    dirty = [i for i, c in enumerate(cells) if c["cell_type"] == "code" and (c.get("outputs") or c.get("execution_count"))]
    assert not dirty, (f"{path.name}: cells {dirty} of the staged notebook carry outputs; run `nbstripout {path}` "
                       "and `git add` it again (or install the filter once: `nbstripout --install`)")


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.name for p in NOTEBOOKS])
def test_notebook_names_the_paper(path):
    first = committed_cells(path)[0]
    text = "".join(first["source"])
    assert first["cell_type"] == "markdown" and "10.3390/drones8020055" in text, (
        f"{path.name}: the first cell must be markdown naming the paper and its DOI"
    )
