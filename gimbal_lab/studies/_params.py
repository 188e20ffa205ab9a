"""What every study's parameters share: replicate seeds, a TOML file, the replicate count from the
environment."""

from __future__ import annotations

import os
import tomllib
from dataclasses import asdict, fields
from pathlib import Path

__all__ = ["StudyParams", "replicates_from_env", "REPLICATES_ENV"]

#: Environment variable that sets the extension studies' replicate count in their notebooks.
REPLICATES_ENV = "GIMBAL_LAB_REPLICATES"


def replicates_from_env(default: int = 10) -> int:
    """The replicate count from :data:`REPLICATES_ENV` (``default``, the study's size, when unset).

    Raises ValueError naming the variable for anything but an integer >= 2.
    """
    text = os.environ.get(REPLICATES_ENV, "").strip()
    if not text:
        return int(default)
    try:
        value = int(text)
    except ValueError:
        raise ValueError(f"{REPLICATES_ENV} must be an integer >= 2, got {text!r}") from None
    if value < 2:
        raise ValueError(f"{REPLICATES_ENV} must be an integer >= 2 (an interval needs two replicates), got {value}")
    return value


class StudyParams:
    """Mixin for a study's frozen parameters dataclass: ``seeds``, ``from_toml`` and ``to_dict``.

    The subclass sets ``_TABLE``, the name of its table in a TOML file (``[paper]``), and has the
    fields ``replicates`` and ``first_seed``.
    """

    _TABLE = ""

    @property
    def seeds(self) -> list[int]:
        """Replicate i runs with seed ``first_seed + i``."""
        return list(range(self.first_seed, self.first_seed + self.replicates))

    @classmethod
    def from_toml(cls, path):
        """Parameters from a TOML file with the study's table (unknown keys name themselves)."""
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"study config {path} does not exist")
        try:
            data = tomllib.loads(path.read_text())
        except tomllib.TOMLDecodeError as exc:
            raise ValueError(f"study config {path} is not valid TOML: {exc}") from None
        table = data.get(cls._TABLE, data)
        if not isinstance(table, dict):
            raise ValueError(f"study config {path}: [{cls._TABLE}] must be a table")
        allowed = {f.name for f in fields(cls)}
        unknown = sorted(set(table) - allowed)
        if unknown:
            raise ValueError(f"study config {path}: unknown key(s) {', '.join(unknown)}; "
                             f"allowed: {', '.join(sorted(allowed))}")
        return cls(**table)

    def to_dict(self) -> dict:
        return asdict(self)
