"""A study's clips, rendered once per set of runs: a clip of an earlier report is reused (copied)
when the runs it shows are unchanged.

Rendering a clip replays its runs frame by frame (the paper study's two clips take tens of
seconds on 2 cores); the runs themselves come from the store in a moment. So beside each clip
``NAME.mp4`` lies ``NAME.json``: the clip's key, the runs it shows (label, seed, store key) and
the SHA-256 of the clip's bytes. The key is a SHA-256 of the runs' store keys
(:meth:`gimbal_lab.runner.ResultsStore.key`: each run's config and the package's source hash) and
the clip's frame rate, so any change of code or of a run renders the clip again, as a changed
run is computed again. A clip is reused only when its sidecar carries the same key and its bytes
still match the digest.
"""

from __future__ import annotations

import hashlib
import json
import shutil
from pathlib import Path

__all__ = ["clip_key", "write_or_reuse_clip", "CLIP_FORMAT"]

#: Version of the sidecar (and of what a key covers); another version is never reused.
CLIP_FORMAT = 1


def clip_key(runs, fps: float) -> str:
    """Key (hex, 24 characters) of a clip of ``runs`` (TrackingResults, in the order shown) at ``fps``."""
    from ..runner import ResultsStore

    text = json.dumps({"format": CLIP_FORMAT, "runs": [ResultsStore.key(r.config) for r in runs], "fps": float(fps)},
                      sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:24]


def _sidecar(clip: Path) -> Path:
    return clip.with_suffix(".json")


def _reusable(previous: Path, key: str) -> bool:
    """Is ``previous`` a whole clip whose sidecar names ``key``?"""
    try:
        meta = json.loads(_sidecar(previous).read_bytes())
        data = previous.read_bytes()
    except (OSError, ValueError):
        return False
    return (isinstance(meta, dict) and meta.get("format") == CLIP_FORMAT and meta.get("key") == key
            and meta.get("sha256") == hashlib.sha256(data).hexdigest())


def write_or_reuse_clip(path, runs, fps: float, frames, previous=None, progress: bool = False) -> list[Path]:
    """Write the clip of ``runs`` to ``path`` and its sidecar beside it; return both paths.

    Parameters
    ----------
    path : path
        The clip to write (``.mp4`` or ``.gif``, :func:`gimbal_lab.show.write_clip`).
    runs : sequence of TrackingResult
        The runs the clip shows, in order (the key covers their order).
    fps : float
        The clip's frame rate, Hz.
    frames : callable
        ``frames()`` returns the clip's RGB frames; called only when the clip is rendered.
    previous : path, optional
        The same clip in an earlier report: copied instead of rendered when its sidecar names the
        same key and its bytes match the sidecar's digest.
    progress : bool
        Say on stderr whether the clip is copied or rendered.
    """
    from ..runner import ResultsStore, source_hash
    from ..show import write_clip

    path = Path(path)
    key = clip_key(runs, fps)
    from .report import say

    if previous is not None and _reusable(Path(previous), key):
        say(f"clip {path.name}: its runs are unchanged, copied from the earlier report", progress)
        path.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(previous, path)
    else:
        say(f"clip {path.name}: rendering ...", progress)
        write_clip(path, frames(), fps=fps)
    meta = {"format": CLIP_FORMAT, "key": key, "fps": float(fps), "source_hash": source_hash(),
            "runs": [{"label": r.config.label, "seed": r.config.seed, "store_key": ResultsStore.key(r.config)}
                     for r in runs],
            "sha256": hashlib.sha256(path.read_bytes()).hexdigest()}
    _sidecar(path).write_text(json.dumps(meta, indent=1) + "\n")
    return [path, _sidecar(path)]
