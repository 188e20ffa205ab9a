"""Scenario files: your own rig, swept and judged like the built-in studies (docs/design.md,
"Scenario files").

A scenario is a TOML file: one table per part of the run's config (``[camera]``, ``[gimbal]``,
``[platform]``, ``[target]``, ``[pointing]``, ``[estimator]``) giving the rig, a ``[run]`` table
(replicates, first seed, revolutions), a ``[sweep]`` table of factors and their levels, and a
``[compare]`` table of hypotheses between two levels of a factor, judged per condition of the other
factors::

    description = "my webcam on a vibrating quad"

    [run]
    replicates = 10

    [camera]
    calibration = "cam.yml"          # relative to this file; its numbers are kept, not the path
    fps = 30.0

    [platform]
    motion = "vibration"

    [sweep]
    camera = ["calibration:cam.yml", "ideal"]
    pointing = ["stabilised", "paper"]

    [compare.H1]
    a = "paper"
    b = "stabilised"                 # "paper < stabilised" in error, by at least δ, per lens

``gimbal-lab run my-rig.toml`` runs it: the grid of every cell (one level of each factor) times the
replicates, through :func:`gimbal_lab.runner.run` (the store, resume, Dask, progress), then a report
written as the studies write theirs (:mod:`gimbal_lab.studies.report`):
``claims.md`` with every verdict at both levels (as computed, and after Holm's correction across
the scenario's family, :func:`gimbal_lab.stats.holm`), the tables, a figure of the error per cell
with its interval, the forest plot of the verdicts, and a passive | active clip when the scenario
sweeps the two.

The whole file is checked before anything runs: every table, key and level, every hypothesis, and
every cell's :class:`~gimbal_lab.config.TrackingConfig` of every replicate is built first. An error
names the file, the table, the key and what is allowed; unknown keys are errors.

Replicates draw what the studies draw from their seed: the target's start phase
(:func:`gimbal_lab.studies.paper.replicate_phase_s`) and, for a flight, where on its pass the body
starts (the moving-drone study's draw); the body's sway, the gyro and the sensor noise come from the
seed through the config's streams. Every cell shares those draws, so cells compare pair by pair.

The scenario only builds configs: a level is a set of field values of the parts, applied to the
rig's nested dict before the config is built; the closed loop never sees a scenario.
"""

from __future__ import annotations

import copy
import dataclasses
import itertools
import json
import math
import tomllib
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from .. import stats
from ..config import _PARTS, Camera, TrackingConfig, _number, seed_stream
from . import _params
from . import report as _report

__all__ = ["Scenario", "Study", "NAME", "DESCRIPTION", "SCENARIO_DIR", "SHORTHANDS", "METRICS", "KINDS",
           "shipped_scenarios", "grid", "replicate_table", "summary_table", "check_hypotheses",
           "hypotheses_markdown", "make_report", "write_clip", "run_study"]

NAME = "scenario"
DESCRIPTION = "your own rig: a scenario file (gimbal-lab run FILE.toml; docs/design.md, \"Scenario files\")"

#: Where the lab's example scenarios live (a source checkout: ``data/scenarios``).
SCENARIO_DIR = Path(__file__).resolve().parents[2] / "data" / "scenarios"

#: The tables a scenario file may hold, and the one key allowed outside them.
_PART_TABLES = tuple(_PARTS)
_TABLES = ("run", *_PART_TABLES, "sweep", "compare")
_TOP_KEYS = ("description",)

#: ``[run]``: its keys and defaults.
_RUN = {"replicates": 10, "first_seed": 0, "revolutions": 2.0}

#: Fields every replicate draws from its seed: a file may not set them.
_DRAWN = {"target.start_phase_s": "the target's start phase", "platform.motion_phase_s": "where the flight starts"}

#: Fields a calibration file gives (``[camera] calibration = FILE``).
_FROM_CALIBRATION = ("lens", "hfov_rad", "width", "height")

#: What each hypothesis may measure: name → (unit, default δ floor, description).
METRICS = {
    "error": ("m", stats.MIN_EFFECT_M, "mean |d_est − d_true| over the measured frames both runs detected "
                                       "(each run's own detections when the two runs' frame clocks differ)"),
    "missed": ("fraction", 0.02, "fraction of the measured frames without a detection"),
    "offset": ("px", 1.0, "mean distance of the target's true image from the principal point, measured frames"),
}
#: The hypotheses' kinds (:mod:`gimbal_lab.stats`): "a < b" by at least δ, "a at least as good as b"
#: within a margin δ, "a ≈ b" within ±20 % of the two means' average.
KINDS = {"less": "<", "non_inferior": "≤", "equivalent": "≈"}
_HYPOTHESIS_KEYS = ("factor", "a", "b", "kind", "metric", "floor", "statement")

def _paper_camera() -> dict:
    return {"camera.calibration": None, "camera.hfov_rad": math.radians(60.0), "camera.width": 640,
            "camera.height": 480, "camera.lens": "default"}


#: Named levels of a part-named factor: name → the fields it sets (None: the field's default).
#: ``camera`` also takes "calibration:FILE", ``pointing`` "filter:cv", "filter:ca", "filter:imm".
SHORTHANDS = {
    "camera": {"ideal": {"camera.lens": "none"}, "paper": _paper_camera()},
    "pointing": {**{kind: {"pointing.kind": kind, "pointing.filter": None}
                    for kind in ("fixed", "stabilised", "paper", "predictive", "filter")},
                 **{f"filter:{f}": {"pointing.kind": "filter", "pointing.filter": f} for f in ("cv", "ca", "imm")}},
    "platform": {motion: {"platform.motion": motion} for motion in ("static", "hover", "vibration", "flight")},
    "target": {kind: {"target.kind": kind} for kind in ("sphere", "aruco")},
}
_CALIBRATION_PREFIX = "calibration:"


# ----------------------------------------------------------------------------------------------
# reading a file
# ----------------------------------------------------------------------------------------------
class _Errors:
    """Errors of one file: ``where: [table] key: problem; allowed: ...``."""

    def __init__(self, where: str):
        self.where = where

    def __call__(self, table: str, key: str | None, problem: str, allowed: str) -> ValueError:
        at = f"[{table}]" + (f" {key}" if key else "")
        return ValueError(f"{self.where}: {at}: {problem}; allowed: {allowed}")


def _level_name(value) -> str:
    """How a level is named in the report and in ``[compare]``: strings as written, numbers in
    their shortest exact form, tables and lists as JSON."""
    if isinstance(value, str):
        return value
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        short = format(value, "g")
        return short if float(short) == value else repr(value)
    if isinstance(value, int):
        return str(value)
    return json.dumps(value, sort_keys=True)


def _field_path(key: str, fail) -> tuple[str, ...]:
    """The part field a ``[sweep]`` key ``part.field[.field]`` names, checked against the parts."""
    path = tuple(key.split("."))
    part = path[0]
    if part not in _PARTS:
        raise fail("sweep", key, f"{part!r} is not a part", f"a part ({', '.join(_PARTS)}) or part.field")
    obj = _PARTS[part]()
    for depth, name in enumerate(path[1:], start=1):
        if not (dataclasses.is_dataclass(obj) and not isinstance(obj, type)):
            raise fail("sweep", key, f"{'.'.join(path[:depth])} has no fields", "a field of a part, or of its "
                       "parameter tables (platform.sway.yaw_rms_rad)")
        names = [f.name for f in dataclasses.fields(obj) if f.init]
        if name not in names:
            raise fail("sweep", key, f"{'.'.join(path[:depth])} has no field {name!r}", ", ".join(names))
        obj = getattr(obj, name)
    if key in _DRAWN:
        raise fail("sweep", key, f"{_DRAWN[key]} is drawn per replicate from its seed", "any other field")
    if len(path) < 2:
        raise fail("sweep", key, "names a part, not a field", "part.field")
    return path


def _flatten_sweep(table: dict, prefix: str = "") -> dict:
    """``[sweep]`` keys as written (``camera.fps = [...]`` is TOML's nested table) → dotted names."""
    out = {}
    for key, value in table.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(_flatten_sweep(value, f"{name}."))
        else:
            out[name] = value
    return out


def _calibration_changes(text: str, folder: Path, fail, table: str, key: str) -> dict:
    """The camera fields a calibration file gives (its numbers), the path relative to ``folder``."""
    path = (folder / text).resolve() if not Path(text).is_absolute() else Path(text)
    try:
        camera = Camera.from_calibration(path)
    except (FileNotFoundError, ValueError, TypeError) as exc:
        raise fail(table, key, f"calibration {text!r}: {exc}", "an OpenCV FileStorage or ROS camera_info file, "
                   "its path relative to the scenario file") from None
    table_ = camera.to_dict()
    return {"camera.calibration": table_["calibration"], "camera.lens": table_["lens"], "camera.hfov_rad": None,
            "camera.width": None, "camera.height": None}


def _levels(key: str, values, folder: Path, fail) -> dict:
    """``{level name: {dotted field: value}}`` of one ``[sweep]`` factor."""
    if not isinstance(values, list) or len(values) < 2:
        raise fail("sweep", key, f"{values!r} is not a list of levels", "a list of at least two levels (a factor "
                   "with one level belongs in its part's table)")
    levels = {}
    if key in SHORTHANDS or "." not in key:
        if key not in SHORTHANDS:
            named = [k for k in _PARTS if k in SHORTHANDS]
            raise fail("sweep", key, f"{key!r} has no named levels" if key in _PARTS else f"{key!r} is not a part",
                       f"named levels for {', '.join(named)}, or part.field = [values] for any field")
        allowed = list(SHORTHANDS[key]) + ([f"{_CALIBRATION_PREFIX}FILE"] if key == "camera" else [])
        for value in values:
            if key == "camera" and isinstance(value, str) and value.startswith(_CALIBRATION_PREFIX):
                changes = _calibration_changes(value[len(_CALIBRATION_PREFIX):], folder, fail, "sweep", key)
            elif isinstance(value, str) and value in SHORTHANDS[key]:
                changes = dict(SHORTHANDS[key][value])
            else:
                raise fail("sweep", key, f"level {value!r} is not a named {key} level", ", ".join(allowed))
            if value in levels:
                raise fail("sweep", key, f"level {value!r} is given twice", "distinct levels")
            levels[value] = changes
        return levels
    path = _field_path(key, fail)
    for value in values:
        name = _level_name(value)
        if name in levels:
            raise fail("sweep", key, f"level {name} is given twice", "distinct levels")
        levels[name] = {".".join(path): value}
    return levels


def _part_table(name: str, table, folder: Path, fail) -> dict:
    """A part's table as the nested dict of its part (a calibration file read and kept as numbers)."""
    if not isinstance(table, dict):
        raise fail(name, None, f"is {type(table).__name__} {table!r}, not a table", f"a table of {name} fields")
    table = dict(table)
    for drawn, what in _DRAWN.items():
        part, key = drawn.split(".")
        if part == name and key in table:
            raise fail(name, key, f"{what} is drawn per replicate from its seed", "the part's other fields")
    try:
        if name == "camera" and "calibration" in table:
            text = table.pop("calibration")
            if not isinstance(text, str):
                raise fail(name, "calibration", f"{text!r} is not a path", "a calibration file's path, relative to "
                           "the scenario file")
            given = [k for k in _FROM_CALIBRATION if k in table]
            if given:
                raise fail(name, given[0], "the calibration file gives it", "the camera's other fields beside "
                           "calibration (fps, latency_frames, exposure_s, readout_s, blur, n_subframes, noise_std, "
                           "noise, light_lux, sensor, f_number)")
            changes = _calibration_changes(text, folder, fail, name, "calibration")
            table.update({k.split(".", 1)[1]: v for k, v in changes.items() if v is not None})
        return _PARTS[name].from_dict(table).to_dict()
    except (ValueError, TypeError) as exc:
        if str(exc).startswith(fail.where):
            raise
        raise ValueError(f"{fail.where}: [{name}] {exc}") from None  # the part's message names key and rule


def _hypothesis(hid: str, table, factors: dict, fail) -> dict:
    where = f"compare.{hid}"
    if not isinstance(table, dict):
        raise fail(where, None, f"is {table!r}, not a table", "a table with a, b and optionally factor, kind, metric, "
                   "floor, statement")
    unknown = sorted(set(table) - set(_HYPOTHESIS_KEYS))
    if unknown:
        raise fail(where, unknown[0], "unknown key", ", ".join(_HYPOTHESIS_KEYS))
    for key in ("a", "b"):
        if key not in table:
            raise fail(where, key, "missing", "a level of a [sweep] factor (a < b is judged per condition of the "
                       "other factors)")
        if not isinstance(table[key], (str, int, float)) or isinstance(table[key], bool):
            raise fail(where, key, f"{table[key]!r} is not a level name", "a level as written in [sweep]")
    a, b = _level_name(table["a"]), _level_name(table["b"])
    if a == b:
        raise fail(where, "b", f"the same level as a ({a!r})", "another level of the factor")
    if "factor" in table:
        factor = table["factor"]
        if factor not in factors:
            raise fail(where, "factor", f"{factor!r} is not a [sweep] factor", ", ".join(factors) or "none: [sweep] is empty")
    else:
        if not factors:
            raise fail(where, "factor", f"no [sweep] table, so {a!r} and {b!r} are levels of no factor",
                       "a [sweep] table with a factor that has both levels")
        holding = [f for f, levels in factors.items() if a in levels and b in levels]
        if len(holding) != 1:
            problem = "no factor has both levels" if not holding else f"factors {', '.join(holding)} all have both"
            raise fail(where, "factor", f"{problem} ({a!r}, {b!r})", "factor = one of " + ", ".join(factors))
        factor = holding[0]
    for key, level in (("a", a), ("b", b)):
        if level not in factors[factor]:
            raise fail(where, key, f"{level!r} is not a level of {factor}", ", ".join(factors[factor]))
    kind = table.get("kind", "less")
    if kind not in KINDS:
        raise fail(where, "kind", f"{kind!r}", ", ".join(KINDS))
    metric = table.get("metric", "error")
    if metric not in METRICS:
        raise fail(where, "metric", f"{metric!r}", ", ".join(f"{m} ({METRICS[m][0]})" for m in METRICS))
    floor = table.get("floor")
    if floor is not None:
        if kind == "equivalent":
            raise fail(where, "floor", "an equivalence has its ±20 % margin, no floor", "floor with kind less or "
                       "non_inferior")
        try:
            floor = _number("floor", floor, low=0.0, low_open=True)
        except (ValueError, TypeError) as exc:
            raise fail(where, "floor", str(exc), f"a number > 0 in the metric's unit ({METRICS[metric][0]})") from None
    statement = table.get("statement", f"{a} {KINDS[kind]} {b} ({metric})")
    if not isinstance(statement, str):
        raise fail(where, "statement", f"{statement!r} is not text", "a string")
    return {"factor": factor, "a": a, "b": b, "kind": kind, "metric": metric, "floor": floor, "statement": statement}


def _check_hypothesis(hid: str, h, factors: dict, fail) -> None:
    """A resolved hypothesis (``Scenario.hypotheses``) refers to the scenario's factors and levels."""
    where = f"compare.{hid}"
    if not isinstance(h, dict) or set(h) != set(_HYPOTHESIS_KEYS):
        raise fail(where, None, f"{h!r} is not a resolved hypothesis", f"a dict of {', '.join(_HYPOTHESIS_KEYS)}")
    if h["factor"] not in factors:
        raise fail(where, "factor", f"{h['factor']!r} is not a [sweep] factor", ", ".join(factors) or "none")
    for key in ("a", "b"):
        if h[key] not in factors[h["factor"]]:
            raise fail(where, key, f"{h[key]!r} is not a level of {h['factor']}", ", ".join(factors[h["factor"]]))
    if h["kind"] not in KINDS or h["metric"] not in METRICS:
        raise fail(where, "kind" if h["kind"] not in KINDS else "metric", f"{h['kind']!r}, {h['metric']!r}",
                   f"kind {', '.join(KINDS)}; metric {', '.join(METRICS)}")


# ----------------------------------------------------------------------------------------------
# the scenario
# ----------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Scenario:
    """A scenario read from a file, every path resolved and every file read: plain data (its
    :meth:`to_dict` is JSON, and ``Scenario(**scenario.to_dict())`` is the same scenario).

    Parameters
    ----------
    name : str
        The report's folder name (the file's name without ``.toml``).
    base : dict
        The rig: :meth:`TrackingConfig.to_dict` tables of the six parts.
    factors : dict
        ``{factor: {level name: {dotted field: value, ...}}}`` in the file's order; a value None
        gives the field its default.
    hypotheses : dict
        ``{id: {factor, a, b, kind, metric, floor, statement}}``.
    description : str
    replicates : int
        Per cell, >= 2; seeds ``first_seed`` … ``first_seed + replicates − 1``.
    first_seed : int
    revolutions : float
        Of the target's motion per replicate, >= 2: the first is acquisition.
    source : str
        The file it was read from (errors name it).
    text : str
        The file's text as it was read (the report keeps a copy).

    Raises
    ------
    ValueError, TypeError
        Naming the file, the table and the key; every cell of every replicate is built on
        construction, so a scenario that exists runs.
    """

    name: str
    base: dict
    factors: dict = field(default_factory=dict)
    hypotheses: dict = field(default_factory=dict)
    description: str = ""
    replicates: int = _RUN["replicates"]
    first_seed: int = _RUN["first_seed"]
    revolutions: float = _RUN["revolutions"]
    source: str = ""
    text: str = ""

    def __post_init__(self):
        fail = _Errors(self.source or f"scenario {self.name!r}")
        for key, limits in (("replicates", dict(low=2, high=1000, integer=True)),
                            ("first_seed", dict(low=0, high=2**62, integer=True)),
                            ("revolutions", dict(low=2.0, high=1000.0))):
            try:
                object.__setattr__(self, key, _number(key, getattr(self, key), **limits))
            except (ValueError, TypeError) as exc:
                raise fail("run", key, str(exc), {"replicates": "an integer from 2 to 1000",
                                                  "first_seed": "an integer >= 0",
                                                  "revolutions": "a number >= 2 (the first is acquisition)"}[key]) \
                    from None
        for hid, h in self.hypotheses.items():
            _check_hypothesis(hid, h, self.factors, fail)
        for cell in self.cells:
            for seed in self.seeds:
                self.config(cell, seed)

    # reading ---------------------------------------------------------------------------------
    @classmethod
    def from_toml(cls, path, **changes) -> "Scenario":
        """The scenario of a TOML file (grammar: module docstring and docs/design.md, "Scenario
        files"); ``changes`` replace fields after reading (``replicates=3``).

        Raises
        ------
        FileNotFoundError
            No such file.
        ValueError
            Naming the file, the table, the key and what is allowed.
        """
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"no such scenario file: {str(path)!r}")
        fail = _Errors(str(path))
        text = path.read_text()
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as exc:
            raise ValueError(f"{path}: not valid TOML: {exc}") from None
        unknown = [k for k in data if k not in _TABLES + _TOP_KEYS]
        if unknown:
            raise fail(unknown[0], None, "unknown table" if isinstance(data[unknown[0]], dict) else "unknown key",
                       f"the tables {', '.join(f'[{t}]' for t in _TABLES)} and the key description")
        for key in _TABLES:
            if key in data and not isinstance(data[key], dict):
                raise fail(key, None, f"is {data[key]!r}, not a table", f"[{key}] as a table")
        description = data.get("description", "")
        if not isinstance(description, str):
            raise fail("description", None, f"{description!r} is not text", "a string")
        run = data.get("run", {})
        for key in run:
            if key not in _RUN:
                raise fail("run", key, "unknown key", ", ".join(_RUN))
        folder = path.resolve().parent
        base = {name: _part_table(name, data.get(name, {}), folder, fail) for name in _PART_TABLES}
        sweep = _flatten_sweep(data.get("sweep", {}))
        factors = {key: _levels(key, values, folder, fail) for key, values in sweep.items()}
        touched = {}
        for factor, levels in factors.items():
            for dotted in {d for changes in levels.values() for d in changes}:
                if dotted in touched:
                    raise fail("sweep", factor, f"sets {dotted}, as {touched[dotted]} does", "factors that set "
                               "different fields (one factor per field)")
                touched[dotted] = factor
        hypotheses = {str(hid): _hypothesis(str(hid), table, factors, fail)
                      for hid, table in data.get("compare", {}).items()}
        fields_ = dict(name=path.name.removesuffix(".toml"), base=base, factors=factors, hypotheses=hypotheses,
                       description=description, source=str(path), text=text, **{k: run[k] for k in run})
        return cls(**{**fields_, **changes})

    def to_dict(self) -> dict:
        """The scenario as plain JSON data (numbers, not paths): ``Scenario(**d)`` rebuilds it."""
        return asdict(self)

    # the grid --------------------------------------------------------------------------------
    @property
    def seeds(self) -> list[int]:
        """Replicate i runs with seed ``first_seed + i``."""
        return list(range(self.first_seed, self.first_seed + self.replicates))

    @property
    def cells(self) -> list[tuple[tuple[str, str], ...]]:
        """Every cell: one ``(factor, level)`` per factor, the factors' levels in the file's order
        (the last factor varies fastest); one empty cell without a sweep."""
        return [tuple(zip(self.factors, levels)) for levels in itertools.product(*self.factors.values())]

    def config(self, cell, seed: int) -> TrackingConfig:
        """The run of ``cell`` and replicate ``seed``: the rig with the cell's levels, the replicate's
        draws (start phase; a flight's start) and the scenario's length."""
        fail = _Errors(self.source or f"scenario {self.name!r}")
        tables = copy.deepcopy(self.base)
        for factor, level in cell:
            for dotted, value in self.factors[factor][level].items():
                *parents, leaf = dotted.split(".")
                node = tables
                for name in parents:
                    node = node.setdefault(name, {})
                if value is None:
                    node.pop(leaf, None)
                else:
                    node[leaf] = copy.deepcopy(value)
        try:
            config = TrackingConfig.from_dict({**tables, "revolutions": self.revolutions, "seed": seed})
            return config.with_(**_replicate_draws(config, seed))
        except (ValueError, TypeError) as exc:  # a rule tying two parts: its message names both
            if not cell:
                raise ValueError(f"{fail.where}: the rig's part tables: {exc}") from None
            raise ValueError(f"{fail.where}: [sweep] cell {_cell_label(cell)}: {exc}") from None

    def runs(self) -> list[tuple[tuple, int, TrackingConfig]]:
        """``(cell, seed, config)`` of every run, cells outer and replicates inner."""
        return [(cell, seed, self.config(cell, seed)) for cell in self.cells for seed in self.seeds]


#: ``gimbal-lab run`` looks for ``Study`` in a study module.
Study = Scenario


def _replicate_draws(config: TrackingConfig, seed: int) -> dict:
    """What replicate ``seed`` draws (:func:`~gimbal_lab.studies.paper.replicate_phase_s`: the start
    phase; a flight's start on its round trip, as the moving-drone study draws it)."""
    from .paper import replicate_phase_s

    draws = {"target__start_phase_s": replicate_phase_s(seed, config.target.period_s)}
    if config.platform.motion == "flight":
        period = config.platform.flight.period_s
        # the replicate's named "flight_phase" stream, as the moving-drone study's (docs/design.md, "Repairs")
        draws["platform__motion_phase_s"] = float(np.random.default_rng(seed_stream(seed, "flight_phase"))
                                                  .uniform(0, period))
    return draws


def _cell_label(cell) -> str:
    return ", ".join(f"{factor}={level}" for factor, level in cell) or "the rig"


def grid(scenario: Scenario) -> list[TrackingConfig]:
    """Every (cell, replicate) config of the scenario, cells outer and replicates inner."""
    return [config for _, _, config in scenario.runs()]


def shipped_scenarios(folder=None) -> list[tuple[Path, str]]:
    """The example scenarios (``data/scenarios/*.toml``) with their descriptions, by file name."""
    folder = Path(folder) if folder is not None else SCENARIO_DIR
    out = []
    for path in sorted(folder.glob("*.toml")):
        try:
            description = tomllib.loads(path.read_text()).get("description", "")
        except (OSError, tomllib.TOMLDecodeError) as exc:
            description = f"(unreadable: {exc})"
        out.append((path, str(description)))
    return out


# ----------------------------------------------------------------------------------------------
# tables
# ----------------------------------------------------------------------------------------------
def _measured(result) -> pd.DataFrame:
    """The frames after the acquisition revolution (by frame index: runs of one clock share them)."""
    f = result.frames
    return f[f["frame"] >= round(result.config.frames_per_revolution)]


def _mean(values) -> float:
    values = np.asarray(values, float)
    values = values[np.isfinite(values)]
    return float(values.mean()) if values.size else math.nan


def replicate_table(scenario: Scenario, results) -> pd.DataFrame:
    """One row per run: its factors' levels, seed and means over its measured revolutions.

    Columns: one per factor (the level), seed, label (the cell), mode, frames, detection_rate,
    mean_abs_error_m (on its own detections), mean_offset_px (the target's true image from the
    principal point), mean_streak_px (the target's blur streak) and time_to_centre_s (active runs:
    first instant within 5 % of the image width of the centre, acquisition revolution).
    """
    from .paper import CENTRED_FRACTION, _time_to_centre

    runs = scenario.runs()
    if len(runs) != len(results):
        raise ValueError(f"{len(results)} results for the scenario's {len(runs)} runs")
    rows = []
    for (cell, seed, config), r in zip(runs, results):
        if r.config != config:
            raise ValueError(f"result {r.config.label} (seed {r.config.seed}) is not the run of "
                             f"{_cell_label(cell)}, seed {seed}")
        f = _measured(r)
        detected = f["detected"].to_numpy()
        acquiring = r.frames[r.frames["frame"] < round(config.frames_per_revolution)]
        rows.append({**dict(cell), "seed": seed, "label": _cell_label(cell), "mode": config.pointing.mode,
                     "frames": len(f), "detection_rate": _mean(detected),
                     "mean_abs_error_m": _mean(f["abs_error_m"].to_numpy()[detected]),
                     "mean_offset_px": _mean(f["true_offset_px"]), "mean_streak_px": _mean(f["streak_px"]),
                     "time_to_centre_s": (_time_to_centre(acquiring, CENTRED_FRACTION * config.camera.width)
                                          if config.pointing.active else math.nan)})
    return pd.DataFrame(rows)


def summary_table(replicates: pd.DataFrame, scenario: Scenario) -> pd.DataFrame:
    """Per cell, in the scenario's order: replicates, the error's mean with its 95 % t-interval
    (``mean_abs_error_m``, ``ci_low_m``, ``ci_high_m``), the detection rate's (``detection_rate``,
    ``rate_ci_low``, ``rate_ci_high``) and the means of the other replicate columns."""
    rows = []
    for cell in scenario.cells:
        g = replicates[replicates["label"] == _cell_label(cell)]
        row = {**dict(cell), "label": _cell_label(cell), "mode": g["mode"].iloc[0] if len(g) else "",
               "replicates": len(g)}
        mean, low, high = stats.mean_interval(g["mean_abs_error_m"])
        row.update(mean_abs_error_m=mean, ci_low_m=low, ci_high_m=high)
        mean, low, high = stats.mean_interval(g["detection_rate"])
        row.update(detection_rate=mean, rate_ci_low=low, rate_ci_high=high)
        for col in ("mean_offset_px", "mean_streak_px", "time_to_centre_s"):
            row[col] = _mean(g[col])
        row["replicates_with_detections"] = int(g["mean_abs_error_m"].notna().sum())
        rows.append(row)
    return pd.DataFrame(rows)


# ----------------------------------------------------------------------------------------------
# hypotheses
# ----------------------------------------------------------------------------------------------
def _pair_values(metric: str, run_a, run_b) -> tuple[float, float]:
    """The two runs' values of ``metric`` on one replicate (module's :data:`METRICS`)."""
    fa, fb = _measured(run_a), _measured(run_b)
    if metric == "missed":
        return 1.0 - _mean(fa["detected"]), 1.0 - _mean(fb["detected"])
    if metric == "offset":
        return _mean(fa["true_offset_px"]), _mean(fb["true_offset_px"])
    da, db = fa["detected"].to_numpy(), fb["detected"].to_numpy()
    ca, cb = run_a.config, run_b.config
    if (ca.camera.fps, ca.target.period_s, len(fa)) == (cb.camera.fps, cb.target.period_s, len(fb)):
        da = db = da & db  # the frames both detected
    return _mean(fa["abs_error_m"].to_numpy()[da]), _mean(fb["abs_error_m"].to_numpy()[db])


def _verdict(kind: str, a: np.ndarray, b: np.ndarray, floor: float) -> stats.Verdict:
    if kind == "less":
        return stats.less_than(a, b, floor=floor, drop_missing=True)
    if kind == "non_inferior":
        return stats.non_inferior(a, b, floor=floor, drop_missing=True)
    keep = np.isfinite(a) & np.isfinite(b)
    if keep.sum() >= 2:
        return stats.equivalent(a[keep], b[keep])
    mean_a, mean_b = (float(x[keep].mean()) if keep.any() else math.nan for x in (a, b))
    margin = stats.EQUIVALENCE_MARGIN * 0.5 * (abs(mean_a) + abs(mean_b))
    return stats.Verdict(stats.INCONCLUSIVE, "equivalent", mean_a, mean_b, mean_a - mean_b, math.nan, math.nan,
                         margin, int(keep.sum()), 0.90, math.nan)


def check_hypotheses(scenario: Scenario, results) -> pd.DataFrame:
    """Every hypothesis of ``[compare]`` per condition of the other factors, with its verdict at
    both levels.

    A condition fixes every other factor's level; replicate s pairs the runs of levels a and b
    with seed s. Values per :data:`METRICS`; a replicate without a value (no detection) drops out
    of its pair. Verdicts: :func:`gimbal_lab.stats.less_than`, :func:`~gimbal_lab.stats.non_inferior`
    (margin δ with the hypothesis' floor) or :func:`~gimbal_lab.stats.equivalent`; then
    :func:`gimbal_lab.stats.holm` across the scenario's whole family.

    Returns
    -------
    DataFrame
        One row per hypothesis and condition: id, statement, condition, factor, a, b, metric, unit,
        the :class:`gimbal_lab.stats.Verdict` fields, p_holm and verdict_holm.
    """
    by_run = {(cell, seed): r for (cell, seed, _), r in zip(scenario.runs(), results)}
    rows = []
    for hid, h in scenario.hypotheses.items():
        unit, default_floor, _ = METRICS[h["metric"]]
        others = [f for f in scenario.factors if f != h["factor"]]
        for condition in itertools.product(*(scenario.factors[f] for f in others)):
            fixed = dict(zip(others, condition))

            def cell(level):
                return tuple((f, level if f == h["factor"] else fixed[f]) for f in scenario.factors)

            pairs = [_pair_values(h["metric"], by_run[(cell(h["a"]), s)], by_run[(cell(h["b"]), s)])
                     for s in scenario.seeds]
            a, b = (np.array(v, float) for v in zip(*pairs))
            floor = h["floor"] if h["floor"] is not None else default_floor
            rows.append(dict(id=hid, statement=h["statement"], condition=_cell_label(tuple(fixed.items())) if fixed
                             else "all", factor=h["factor"], a=h["a"], b=h["b"], metric=h["metric"], unit=unit,
                             result=_verdict(h["kind"], a, b, floor)))
    table = stats.verdict_table(rows)
    return stats.holm(table) if len(table) else table


def _p(value: float) -> str:
    return "–" if not math.isfinite(value) else f"{value:.2g}" if value >= 0.001 else f"{value:.1e}"


def verdict_reason(row) -> str:
    """One sentence of measured reason for a verdict that does not hold or is inconclusive."""
    if row.kind == "equivalent" and row.verdict != stats.HOLDS and math.isfinite(row.low):
        u, f = _params.unit_name(row.unit), (lambda x: _params.amount(x, row.unit))  # noqa: E731
        return (f"the 90 % interval [{f(row.low)}, {f(row.high)}] {u} is "
                f"{'entirely outside' if row.verdict == stats.DOES_NOT_HOLD else 'not inside'} the ±{f(row.delta)} "
                f"{u} margin")
    if row.kind == "non-inferior" and row.verdict != stats.HOLDS and math.isfinite(row.low):
        u, f = _params.unit_name(row.unit), (lambda x: _params.amount(x, row.unit))  # noqa: E731
        return (f"the 90 % interval [{f(row.low)}, {f(row.high)}] {u} "
                f"{'lies above' if row.verdict == stats.DOES_NOT_HOLD else 'reaches beyond'} the margin "
                f"+{f(row.delta)} {u}")
    return _params.verdict_reason(row, "with a value in both runs (detections)")


def hypotheses_markdown(verdicts: pd.DataFrame, summary: pd.DataFrame, scenario: Scenario) -> str:
    """claims.md of a scenario: the rig, the sweep, every verdict at both levels, the cells."""
    n_cells = len(scenario.cells)
    sweep = "; ".join(f"{factor} ∈ {{" + ", ".join(levels) + "}" for factor, levels in scenario.factors.items())
    title = "hypotheses, measured" if len(verdicts) else "the cells, measured (no hypotheses)"
    lines = [f"# Scenario {scenario.name}: {title}", ""]
    if scenario.description:
        lines += [scenario.description, ""]
    base = TrackingConfig.from_dict(scenario.base)
    K = base.camera.intrinsics
    lines += [
        f"Read from `{scenario.source or scenario.name}`. The rig: a {K.width} × {K.height} px camera "
        f"(fx {K.fx:.1f} px, fy {K.fy:.1f} px, principal point ({K.cx:.1f}, {K.cy:.1f}) px, "
        f"{math.degrees(base.camera.horizontal_field_rad):.1f}° across; lens {base.camera.lens_label}) at "
        f"{base.camera.fps:g} frames/s, {base.camera.exposure_label(bool(base.target.occluders))}; "
        f"platform {base.platform.motion}; {base.target.kind} on the "
        f"{base.target.trajectory} path (period {base.target.period_s:g} s); pointing {base.pointing.kind}; "
        f"estimator {base.estimator.sphere_method}, lens {base.estimator.lens_strategy}.",
        "",
        f"Sweep: {sweep or 'none'} "
        f"({n_cells} cell{'s' if n_cells != 1 else ''}), {scenario.replicates} replicates per cell (seeds "
        f"{scenario.first_seed}–{scenario.first_seed + scenario.replicates - 1}) of {scenario.revolutions:g} "
        "revolutions, the first of which is acquisition; cells are paired by replicate.",
        "",
        _params.verdict_rule("max(floor, 10 % of the smaller mean); the floor is the hypothesis' own, by default "
                             "1 mm for error, 0.02 for missed frames, 1 px for offset",
                             "“a ≤ b” (non-inferiority): holds when the upper end of the 90 % interval lies below "
                             "+δ. “a ≈ b”: the 90 % interval inside ±20 % of the two means' average. Each verdict "
                             "is shown as computed and after Holm's correction across the scenario's "
                             "hypotheses (family-wise 5 %)."),
        "",
        "Metrics: " + "; ".join(f"**{m}** ({_params.unit_name(u)}): {text}" for m, (u, _, text) in METRICS.items())
        + ".",
        "",
    ]
    if len(verdicts):
        lines += ["| id | claim | condition | a | b | n | mean a | mean b | a − b [interval] | δ | unit | p | verdict "
                  "| p (Holm) | verdict (family) |", "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for row in verdicts.itertuples():
            f = lambda x: _params.amount(x, row.unit)  # noqa: E731
            level = "95 %" if row.kind == "less" else "90 %"
            lines.append(f"| {row.id} | {row.statement} | {row.condition} | {row.a} | {row.b} | {row.n} | "
                         f"{f(row.mean_a)} | {f(row.mean_b)} | {f(row.difference)} [{f(row.low)}, {f(row.high)}] "
                         f"({level}) | {f(row.delta)} | {_params.unit_name(row.unit)} | {_p(row.p_value)} | "
                         f"**{row.verdict}** | {_p(row.p_holm)} | **{row.verdict_holm}** |")
        lines += ["", "| hypothesis | " + " | ".join(stats.VERDICTS) + " | family: " + " | family: ".join(stats.VERDICTS)
                  + " |", "|---" * 7 + "|"]
        for hid, g in verdicts.groupby("id", sort=False):
            counts, family = g["verdict"].value_counts(), g["verdict_holm"].value_counts()
            lines.append(f"| {hid} | " + " | ".join(str(counts.get(v, 0)) for v in stats.VERDICTS) + " | "
                         + " | ".join(str(family.get(v, 0)) for v in stats.VERDICTS) + " |")
        failing = verdicts[verdicts["verdict"] != stats.HOLDS]
        lines += ["", "## Conditions that do not hold or are inconclusive", ""]
        if failing.empty:
            lines.append("Every condition holds.")
        for row in failing.itertuples():
            lines.append(f"- **{row.id}** ({row.condition}: {row.a} vs {row.b}, {row.metric}), {row.verdict}: "
                         f"{verdict_reason(row)}.")
    else:
        lines.append("The scenario states no hypotheses ([compare] is empty): the cells below are its result.")
    lines += ["", "## Cells (measured revolutions)", "",
              "| cell | mode | n | error mm [95 % CI] | detection rate [95 % CI] | offset px | streak px | "
              "time to centre s |", "|---|---|---|---|---|---|---|---|"]
    for row in summary.itertuples():
        mm = lambda x: f"{1000 * x:.2f}" if math.isfinite(x) else "–"  # noqa: E731
        num = lambda x, d=2: f"{x:.{d}f}" if math.isfinite(x) else "–"  # noqa: E731
        lines.append(f"| {row.label} | {row.mode} | {row.replicates} | {mm(row.mean_abs_error_m)} "
                     f"[{mm(row.ci_low_m)}, {mm(row.ci_high_m)}] | {num(row.detection_rate)} "
                     f"[{num(row.rate_ci_low)}, {num(row.rate_ci_high)}] | {num(row.mean_offset_px, 1)} | "
                     f"{num(row.mean_streak_px, 1)} | {num(row.time_to_centre_s)} |")
    return "\n".join(lines) + "\n"


# ----------------------------------------------------------------------------------------------
# report
# ----------------------------------------------------------------------------------------------
def _clip_pair(scenario: Scenario, results):
    """The passive and active runs of the first replicate that differ in one factor's level only,
    preferring a stabilised passive camera; None when the scenario has no such pair."""
    first = scenario.first_seed
    runs = [(cell, r) for (cell, seed, _), r in zip(scenario.runs(), results) if seed == first]
    pairs = []
    for (cell_p, p), (cell_a, a) in itertools.permutations(runs, 2):
        differ = [i for i, (x, y) in enumerate(zip(cell_p, cell_a)) if x != y]
        if len(differ) == 1 and p.config.pointing.mode == "passive" and a.config.pointing.mode == "active":
            pairs.append((p.config.pointing.kind != "stabilised", p, a))
    return min(pairs, key=lambda t: t[0])[1:] if pairs else None


def write_clip(folder, scenario: Scenario, results, progress: bool = False) -> list[Path]:
    """``folder/clips/passive-active.mp4``: one passive | active pair (:func:`_clip_pair`) side by
    side as :func:`gimbal_lab.show.side_by_side` draws it; nothing when there is no pair."""
    pair = _clip_pair(scenario, results)
    if pair is None:
        return []
    from ..show import side_by_side
    from ..show import write_clip as write

    passive, active = pair
    frames = side_by_side(passive, active)
    _report.say(f"{scenario.name}: rendering the passive | active clip ({passive.config.n_frames} frames) ...", progress)
    if progress:
        from tqdm.auto import tqdm

        frames = tqdm(frames, total=passive.config.n_frames, desc="clip", unit="frame")
    return [write(Path(folder) / "clips" / "passive-active.mp4", frames, fps=passive.config.camera.fps)]


def make_report(results, scenario: Scenario) -> _report.Report:
    """The scenario's report (:class:`gimbal_lab.studies.report.Report`): its tables, claims and figures.

    Files: ``summary.csv``, ``replicates.parquet`` and ``.csv``, ``verdicts.csv``, ``claims.md``,
    ``scenario.toml`` (the file as read), ``study.json`` and ``figures/`` (``cells``: the error
    and detection rate per cell with their intervals; ``hypotheses_forest`` when it has
    hypotheses), PNG and SVG.
    """
    from .. import plotting

    replicates = replicate_table(scenario, results)
    summary = summary_table(replicates, scenario)
    verdicts = check_hypotheses(scenario, results)
    files = [("summary.csv", summary), ("replicates.parquet", replicates), ("replicates.csv", replicates),
             ("verdicts.csv", verdicts), ("claims.md", hypotheses_markdown(verdicts, summary, scenario))]
    if scenario.text:
        files.append(("scenario.toml", scenario.text))
    return _report.Report(scenario.name, scenario, len(results), files,
                          [("cells", lambda: plotting.scenario.plot_cells(summary))], verdicts)


def run_study(scenario: Scenario, out, *, store=None, executor=None, jobs=None, progress=True,
              clips: bool = True) -> dict:
    """Run the scenario's grid (reusing ``store``) and write its report to ``out/NAME`` (NAME: the
    scenario's name; :func:`gimbal_lab.studies.report.run_and_report`: only the report's own files
    are replaced), with the passive | active clip when ``clips``.

    Returns a dict with the results, the verdicts, the folder, the paths written and the paths kept.
    """
    def add_clip(folder, results, scenario):
        write_clip(folder, scenario, results, progress=progress)

    return _report.run_and_report(scenario.name, f"scenario {scenario.name}", grid(scenario), make_report, scenario,
                                  out, store=store, executor=executor, jobs=jobs, progress=progress,
                                  extra=add_clip if clips else None)
