"""What every study's parameters share: replicate seeds, a TOML file, the replicate count from the
environment."""

from __future__ import annotations

import math
import os
import tomllib
from dataclasses import asdict, dataclass, fields
from typing import ClassVar
from pathlib import Path

__all__ = ["StudyParams", "replicates_from_env", "REPLICATES_ENV", "report_pyplot", "md_cell", "format_p", "verdict_counts", "verdict_lines", "cpu_seconds_per_frame", "run_frames",
           "COST_REPEATS"]

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


@dataclass(frozen=True)
class StudyParams:
    """What every study's frozen parameters share: the replicates and the paper study's camera and
    loop timing, with ``seeds``, ``from_toml`` and ``to_dict``.

    A study subclasses it as a frozen dataclass, adds its own fields, and sets ``_TABLE``, the name
    of its table in a TOML file (``[paper]``).

    Parameters
    ----------
    replicates : int
        Replicates per cell, >= 2 (an interval needs two); every study's declared size is 10.
    first_seed : int
        Seed of the first replicate, >= 0; replicate i uses seed ``first_seed + i``.
    revolutions : float
        Periods of the target's motion per replicate, >= ``MIN_REVOLUTIONS`` (2: one acquisition
        revolution plus at least one measured; a map whose notebook runs shorter under pytest
        lowers it).
    period_s : float
        Period of the target's motion, s (2).
    fps : float
        Camera frame rate (30).
    latency_frames : int
        Vision latency in frames (1).
    noise_std : float
        Sensor noise, grey levels (2).
    """

    replicates: int = 10
    first_seed: int = 0
    revolutions: float = 2.0
    period_s: float = 2.0
    fps: float = 30.0
    latency_frames: int = 1
    noise_std: float = 2.0

    _TABLE = ""
    #: The fewest revolutions a replicate may run (a class attribute, not a parameter).
    MIN_REVOLUTIONS: ClassVar[float] = 2.0

    def _check_replicates(self) -> None:
        """Validate (and normalise) ``replicates``, ``first_seed`` and ``revolutions``, naming the field;
        first, refuse a NaN or infinite number in any field (``period_s = nan`` in a TOML file)."""
        from ..config import _number

        for f in fields(self):
            _check_finite(f.name, getattr(self, f.name))
        set_ = lambda name, value: object.__setattr__(self, name, value)  # noqa: E731
        set_("replicates", _number("replicates", self.replicates, low=2, high=1000, integer=True))
        set_("first_seed", _number("first_seed", self.first_seed, low=0, high=2**62, integer=True))
        set_("revolutions", _number("revolutions", self.revolutions, low=self.MIN_REVOLUTIONS, high=1000.0))

    def _refuse_unused(self, names: tuple, why: str) -> None:
        """Refuse a value other than the default for fields this study inherits but does not use
        (a parameter that is set and does nothing would mislead), naming the field and why."""
        defaults = {f.name: f.default for f in fields(self)}
        for name in names:
            if getattr(self, name) != defaults[name]:
                raise ValueError(f"{name} is not used by this study ({why}); leave it out, got "
                                 f"{getattr(self, name)!r}")

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
        if cls._TABLE not in data and data and all(isinstance(v, dict) for v in data.values()):
            raise ValueError(f"study config {path} has no [{cls._TABLE}] table (it holds "
                             f"{', '.join(f'[{k}]' for k in data)}): is it another study's?")
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


def _check_finite(name: str, value) -> None:
    """Raise ValueError naming ``name`` (``name[i]``, ``name.key`` inside) if ``value`` is, or holds,
    a NaN or infinite float."""
    if isinstance(value, float) and not math.isfinite(value):
        raise ValueError(f"{name} must be a finite number, got {value!r}")
    if isinstance(value, (list, tuple)):
        for i, item in enumerate(value):
            _check_finite(f"{name}[{i}]", item)
    elif isinstance(value, dict):
        for key, item in value.items():
            _check_finite(f"{name}.{key}", item)


def report_pyplot():
    """matplotlib's pyplot on a file backend (a report is written without a display)."""
    import matplotlib

    if matplotlib.get_backend().lower() not in ("agg", "svg", "pdf"):
        matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


# ----------------------------------------------------------------------------------------------
# verdict tables of the extension studies (claims.md)
# ----------------------------------------------------------------------------------------------
def amount(value: float, unit: str) -> str:
    """A verdict quantity as printed: metres in mm, any other unit as it is, two decimals."""
    return f"{1000 * value:.2f}" if unit == "m" else f"{value:.2f}"


def unit_name(unit: str) -> str:
    """The printed unit of a verdict row's ``unit`` ("m" is printed in mm)."""
    return "mm" if unit == "m" else unit


def verdict_reason(row, no_pairs: str) -> str:
    """One sentence of measured reason for a verdict (empty for one that holds); ``no_pairs`` says
    why a row without an interval had nothing to compare (it follows "only N replicate(s) ")."""
    from .. import stats

    u, f = unit_name(row.unit), lambda x: amount(x, row.unit)  # noqa: E731
    if row.verdict == stats.HOLDS:
        return ""
    if not math.isfinite(row.low):
        return f"only {row.n} replicate(s) {no_pairs}: nothing to compare"
    if row.verdict == stats.DOES_NOT_HOLD and row.low > 0:
        return (f"the opposite is measured: {row.a} exceeds {row.b} by {f(row.difference)} {u} "
                f"(95 % interval [{f(row.low)}, {f(row.high)}] {u})")
    if row.verdict == stats.DOES_NOT_HOLD:
        return f"no effect worth the name: the interval [{f(row.low)}, {f(row.high)}] {u} lies within ±δ = {f(row.delta)} {u}"
    if row.high < 0:
        return f"the difference {f(row.difference)} {u} is real but smaller than δ = {f(row.delta)} {u}"
    return f"the interval [{f(row.low)}, {f(row.high)}] {u} straddles 0 and reaches beyond ±δ = {f(row.delta)} {u}"


def verdict_rule(delta: str, more: str = "") -> str:
    """The report's sentence stating the verdict rule (docs/design.md, Verdicts) for a study whose
    δ is ``delta``, followed by the study's own ``more``."""
    rule = ("Verdicts: for “a < b”, the 95 % t-interval of the paired difference a − b; **holds** when it lies "
            f"below 0 and the mean difference is at least δ = {delta}; **does not hold** when it lies above 0 or "
            "within ±δ; otherwise **inconclusive**.")
    return f"{rule} {more}" if more else rule


def md_cell(value) -> str:
    """``value`` as the text of one Markdown table cell: a ``|`` inside it escaped (``\\|``), so
    that it does not end the cell (``|gap|`` would otherwise add two cells to its row)."""
    return str(value).replace("|", "\\|")


def format_p(p) -> str:
    """A p-value as printed: three significant digits, "–" for a verdict without a test."""
    return f"{float(p):.3g}" if p is not None and math.isfinite(float(p)) else "–"


def verdict_counts(verdicts) -> str:
    """The sentence counting the verdicts at both levels: as computed (95 %) and, when the table
    has ``verdict_holm``, held to the family's 5 % error rate (Holm)."""
    from .. import stats

    n = len(verdicts)

    def count(column):
        c = verdicts[column].value_counts()
        return ", ".join(f"{c.get(v, 0)} {v}" for v in stats.VERDICTS)

    text = f"Of {n} conditions, at 95 % each: {count('verdict')}."
    if "verdict_holm" in verdicts:
        text += (f" At the family level (Holm's step-down over these {n} verdicts, 5 % family-wise error): "
                 f"{count('verdict_holm')}.")
    return text


def verdict_lines(verdicts, reason, unit_in_list: bool = False) -> list[str]:
    """claims.md's verdict table, the count per hypothesis and the list of conditions that do not
    hold or are inconclusive, each with ``reason(row)`` (the unit beside the condition when
    ``unit_in_list``).

    The table gives each verdict's ``p_value`` when the table has one, and beside it the
    Holm-adjusted ``p_holm`` and the family-level ``verdict_holm`` when present
    (:func:`gimbal_lab.stats.holm`); the counts are given at both levels. Every text cell is
    escaped with :func:`md_cell`.
    """
    from .. import stats

    has_p, has_holm = "p_value" in verdicts, {"p_holm", "verdict_holm"} <= set(verdicts.columns)
    head = ["id", "claim", "condition", "a", "b", "n", "mean a", "mean b", "a − b [95 % CI]", "δ", "unit"]
    head += ["p"] * has_p + ["verdict"] + ["p (Holm)", "verdict (Holm)"] * has_holm
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row in verdicts.itertuples():
        f = lambda x: amount(x, row.unit)  # noqa: E731
        cells = [row.id, row.statement, row.condition, row.a, row.b, row.n, f(row.mean_a), f(row.mean_b),
                 f"{f(row.difference)} [{f(row.low)}, {f(row.high)}]", f(row.delta), unit_name(row.unit)]
        cells += [format_p(row.p_value)] * has_p + [f"**{row.verdict}**"]
        if has_holm:
            cells += [format_p(row.p_holm), f"**{row.verdict_holm}**"]
        lines.append("| " + " | ".join(md_cell(c) for c in cells) + " |")
    levels = [("verdict", "")] + [("verdict_holm", " (Holm)")] * has_holm
    head = ["hypothesis"] + [f"{v}{suffix}" for _, suffix in levels for v in stats.VERDICTS]
    lines += ["", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for cid, g in verdicts.groupby("id", sort=False):
        counts = [g[column].value_counts() for column, _ in levels]
        lines.append(f"| {md_cell(cid)} | " + " | ".join(str(c.get(v, 0)) for c in counts for v in stats.VERDICTS)
                     + " |")
    lines += ["", verdict_counts(verdicts)]
    failing = verdicts[verdicts["verdict"] != stats.HOLDS]
    lines += ["", "## Conditions that do not hold or are inconclusive", ""]
    if failing.empty:
        lines.append("Every condition holds.")
    for row in failing.itertuples():
        unit = f", {unit_name(row.unit)}" if unit_in_list else ""
        lines.append(f"- **{row.id}** ({row.condition}: {row.a} vs {row.b}{unit}), {row.verdict}: {reason(row)}.")
    if has_holm:
        lines += holm_change_lines(verdicts)
    return lines


def holm_change_lines(verdicts) -> list[str]:
    """The section listing every verdict that Holm's correction turns from decisive to inconclusive."""
    changed = verdicts[verdicts["verdict"] != verdicts["verdict_holm"]]
    lines = ["", "## Verdicts that do not survive the family's correction", ""]
    if changed.empty:
        return lines + ["Every decisive verdict stays decisive after Holm's correction."]
    for row in changed.itertuples():
        lines.append(f"- **{row.id}** ({row.condition}: {row.a} vs {row.b}): {row.verdict} at 95 % (p = "
                     f"{format_p(row.p_value)}), {row.verdict_holm} in the family (Holm p = {format_p(row.p_holm)}).")
    return lines


# ----------------------------------------------------------------------------------------------
# the cost of a pipeline (docs/design.md, "When does a gimbal pay off?": pipelines compared)
# ----------------------------------------------------------------------------------------------
#: Passes over the frames whose least CPU time is a pipeline's cost.
COST_REPEATS = 5


def run_frames(result, start: int = 0, stop: int | None = None, renderer=None, every: int = 1) -> list:
    """The noisy frames ``start:stop:every`` of a finished run, rendered again exactly as the run saw
    them (:func:`gimbal_lab.show.replay`): the stored frames every pipeline's cost is measured on."""
    from ..show import replay

    return [image for _, image in replay(result, renderer=renderer, every=every, start=start, stop=stop)]


def cpu_seconds_per_frame(estimate, images, repeats: int = COST_REPEATS) -> float:
    """CPU time per frame of ``estimate(image)`` over ``images``, s: the least of ``repeats`` passes.

    Each pass times the whole list with :func:`time.process_time` (CPU time of this process, not
    the wall clock, so other processes sharing the machine do not count); the minimum over passes
    is the cost least disturbed by what the process itself does besides (caches, the allocator).
    OpenCV's thread pool is held to one thread while it runs, so a pipeline's cost is that of one
    core, as in the runs' workers. Measured apart from the runs, never their wall time.

    Parameters
    ----------
    estimate : callable
        image → anything (an estimator of :meth:`gimbal_lab.config.Estimator.build`).
    images : sequence of ndarray
        The frames, the same for every pipeline compared.
    repeats : int
        Passes, >= 1 (5 by docs/design.md).
    """
    import time

    import cv2

    images = list(images)
    if not images:
        raise ValueError("images must hold at least one frame to time")
    if isinstance(repeats, bool) or not isinstance(repeats, int) or repeats < 1:
        raise ValueError(f"repeats must be an integer >= 1, got {repeats!r}")
    threads = cv2.getNumThreads()
    cv2.setNumThreads(1)
    try:
        best = math.inf
        for _ in range(repeats):
            t0 = time.process_time()
            for image in images:
                estimate(image)
            best = min(best, time.process_time() - t0)
    finally:
        cv2.setNumThreads(threads)
    return best / len(images)
