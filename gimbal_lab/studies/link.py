"""The link study (issue 30, part 4): the paper's active loop with its gimbal behind a MAVLink link.

Does the paper's advantage of active over passive survive the link, and where does it break
even? docs/design.md, "The link study", fixes the cells, links, metrics and hypotheses before any
run. Cells: the paper's sphere and marker, distorted lens, circular path (its S1 and A4 cells),
``replicates`` replicates paired by seed across every link. Links
(:class:`gimbal_lab.config.GimbalLink`): status rate {50, 10, 5 Hz} × one-way latency {0, 20,
60 ms} × angle quantum {0, 0.1°} × status loss {0, 5 %} × feedback {measured, commanded only},
beside the in-process loop (no link). ``design = "one-at-a-time"`` (the study's default) runs the
in-process loop, the reference link (50 Hz, 0 ms, 0°, 0 %, measured), each other level of each
factor alone and the worst corner; ``"factorial"`` runs every link. The passive camera sends no
command and knows its pose exactly under any link, so one passive run per replicate serves all.

Hypotheses (three-way verdicts, :func:`gimbal_lab.stats.less_than`, Holm across the report's
whole family, :func:`gimbal_lab.stats.holm`):

* **L1** per link and target: active through the link < passive, distance error;
* **L2** per factor step, metric and target: error at the better level < at the next worse
  level, the other factors at the reference link's;
* **L3** per link and target: active through the link < passive, world error (the detection
  mapped to the world through the pose the loop knows).

The propagated arm (``propagated``, docs/design.md "A loop that knows how old its attitude is"):
every link again with ``GimbalLink.attitude = "propagated"`` (the status carried to the instant
it is used by its own rates), with its own family: **L1p** and **L3p** as L1 and L3, and **P1**
per link and target: propagated < as-is, world error.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pandas as pd

from .. import stats
from ..config import GimbalLink, TrackingConfig
from . import _params
from . import report as _report
from ._params import StudyParams
from .paper import PaperStudy

__all__ = ["LinkStudy", "Study", "links", "grid", "replicate_table", "summary_table", "check_hypotheses",
           "check_propagation", "break_even", "hypotheses_markdown", "make_report", "run_study", "FACTORS", "REFERENCE", "WORST",
           "IN_PROCESS", "PASSIVE", "DESIGNS"]

NAME = "link"
DESCRIPTION = "the gimbal behind a MAVLink link: does active still beat passive, and where does it break even"

#: The link's factors and their levels, best first (docs/design.md, "The link study").
FACTORS = {
    "status_rate_hz": (50.0, 10.0, 5.0),
    "latency_s": (0.0, 0.02, 0.06),
    "quantum_rad": (0.0, math.radians(0.1)),
    "loss": (0.0, 0.05),
    "commanded_only": (False, True),
}
#: The reference link: every factor at its best level.
REFERENCE = GimbalLink(status_rate_hz=50.0)
#: The worst corner: every factor at its worst level.
WORST = GimbalLink(status_rate_hz=5.0, latency_s=0.06, quantum_rad=math.radians(0.1), loss=0.05, commanded_only=True)
#: The names of the loop without a link and of the passive camera in the tables.
IN_PROCESS, PASSIVE = "in-process", "passive"
DESIGNS = ("one-at-a-time", "factorial")
TARGETS = ("sphere", "aruco")
#: The paper's cells of the study: its distorted circle (S1 and A4).
DISTORTION, TRAJECTORY = "distorted", "circular"


def link_name(link: GimbalLink | None) -> str:
    """The link's name in the tables: :data:`IN_PROCESS` for None, else its label."""
    return IN_PROCESS if link is None else link.label


def links(design: str = "one-at-a-time") -> dict[str, GimbalLink | None]:
    """The links of a design, by name (the in-process loop first, then the reference link)."""
    if design not in DESIGNS:
        raise ValueError(f"design must be one of {DESIGNS}, got {design!r}")
    out = {IN_PROCESS: None, REFERENCE.label: REFERENCE}
    if design == "one-at-a-time":
        for factor, levels in FACTORS.items():
            for level in levels[1:]:
                link = REFERENCE.replace(**{factor: level})
                out[link.label] = link
        out[WORST.label] = WORST
    else:
        import itertools

        for values in itertools.product(*FACTORS.values()):
            link = GimbalLink(**dict(zip(FACTORS, values)))
            out[link.label] = link
    return out


def steps() -> list[tuple[str, str, str]]:
    """L2's factor steps: (factor, better link's name, worse link's name), the other factors at the
    reference link's levels; the status rate's first step is from the in-process loop."""
    out = [("status_rate_hz", IN_PROCESS, REFERENCE.label)]
    for factor, levels in FACTORS.items():
        for better, worse in zip(levels, levels[1:]):
            out.append((factor, REFERENCE.replace(**{factor: better}).label, REFERENCE.replace(**{factor: worse}).label))
    return out


@dataclass(frozen=True)
class LinkStudy(StudyParams):
    """Parameters of the link study (defaults: docs/design.md; ``data/studies/link.toml``).

    Parameters
    ----------
    replicates, first_seed, revolutions, period_s, fps, latency_frames, noise_std :
        As every study's (:class:`~gimbal_lab.studies._params.StudyParams`).
    design : {"one-at-a-time", "factorial"}
        Which links run (:func:`links`).
    only : tuple of str
        Run only these links of the design, by name (:func:`links`' keys); empty: all of them.
        The notebook's test size uses a few.
    targets : tuple of str
        "sphere", "aruco" or both.
    propagated : bool
        Also run every link (not the in-process loop) with the status propagated to the instant it
        is used (the registered arm; True).
    """

    design: str = "one-at-a-time"
    only: tuple = ()
    targets: tuple = TARGETS
    propagated: bool = True

    _TABLE = NAME

    def __post_init__(self):
        self._check_replicates()
        for name in ("only", "targets"):
            value = getattr(self, name)
            if isinstance(value, str) or not isinstance(value, (list, tuple)):
                raise TypeError(f"{name} must be a list of names, got {value!r}")
            object.__setattr__(self, name, tuple(value))
        if not self.targets or set(self.targets) - set(TARGETS):
            raise ValueError(f"targets must be some of {TARGETS}, got {list(self.targets)}")
        available = links(self.design)
        unknown = [n for n in self.only if n not in available]
        if unknown:
            raise ValueError(f"only: no link named {unknown} in the {self.design!r} design; links: {list(available)}")
        if not isinstance(self.propagated, (bool, np.bool_)):
            raise TypeError(f"propagated must be true or false, got {self.propagated!r}")
        object.__setattr__(self, "propagated", bool(self.propagated))

    @property
    def links(self) -> dict[str, GimbalLink | None]:
        """The links this study runs, by name."""
        every = links(self.design)
        return {n: link for n, link in every.items() if not self.only or n in self.only}

    @property
    def paper(self) -> PaperStudy:
        """The paper study whose cells these are (same replicates and timing)."""
        return PaperStudy(replicates=self.replicates, first_seed=self.first_seed, revolutions=self.revolutions,
                          period_s=self.period_s, fps=self.fps, latency_frames=self.latency_frames,
                          noise_std=self.noise_std)

    def config(self, target: str, link: str, seed: int, attitude: str = "as-is") -> TrackingConfig:
        """The run of a target, a link's name (or :data:`PASSIVE`) and a replicate; ``attitude``
        "propagated" for the propagated arm (a link's, not the in-process loop's)."""
        if link == PASSIVE:
            return self.paper.config(target, DISTORTION, TRAJECTORY, "passive", seed)
        config = self.paper.config(target, DISTORTION, TRAJECTORY, "active", seed)
        chosen = links(self.design)[link]
        if attitude != "as-is":
            if chosen is None:
                raise ValueError(f"the {link} loop has no link to propagate")
            chosen = chosen.replace(attitude=attitude)
        return config.with_(pointing__link=chosen)

    @property
    def propagated_links(self) -> list[str]:
        """The links (by their as-is name) the propagated arm runs: every link, none when off."""
        return [n for n, link in self.links.items() if link is not None] if self.propagated else []

    def to_dict(self) -> dict:
        out = super().to_dict()
        out.update(only=list(self.only), targets=list(self.targets))
        return out


Study = LinkStudy


def grid(study: LinkStudy | None = None) -> list[TrackingConfig]:
    """Every run: per target, the passive runs, then each link's active runs (replicates inner)."""
    study = study or LinkStudy()
    return [study.config(target, name, seed) for target in study.targets for name in (PASSIVE, *study.links)
            for seed in study.seeds] + \
        [study.config(target, name, seed, "propagated") for target in study.targets for name in study.propagated_links
         for seed in study.seeds]


# ----------------------------------------------------------------------------------------------
# tables
# ----------------------------------------------------------------------------------------------
def _row(result) -> dict:
    c = result.config
    f = result.frames
    measured = f[f["revolution"] >= 1]
    det = measured[measured["detected"]]
    link = c.pointing.link
    world = np.linalg.norm(det[["est_x_m", "est_y_m", "est_z_m"]].to_numpy()
                           - det[["true_x_m", "true_y_m", "true_z_m"]].to_numpy(), axis=1)
    known = np.abs(measured[["known_q_yaw_rad", "known_q_roll_rad", "known_q_pitch_rad"]].to_numpy()
                   - measured[["q_yaw_rad", "q_roll_rad", "q_pitch_rad"]].to_numpy()).max(axis=1)
    mean = lambda x: float(np.mean(x)) if len(x) else math.nan  # noqa: E731
    return {"target": c.target.kind, "link": PASSIVE if not c.pointing.active else link_name(link),
            "mode": c.pointing.mode, "seed": c.seed, "attitude": link.attitude if link else "as-is",
            "status_rate_hz": link.status_rate_hz if link else math.nan,
            "latency_ms": 1000 * link.latency_s if link else math.nan,
            "quantum_deg": math.degrees(link.quantum_rad) if link else math.nan,
            "loss": link.loss if link else math.nan,
            "commanded_only": bool(link.commanded_only) if link else False,
            "frames": len(measured), "detection_rate": float(measured["detected"].mean()) if len(measured) else math.nan,
            "mean_abs_error_m": mean(det["abs_error_m"]), "mean_world_error_m": mean(world),
            "mean_offset_px": mean(det["offset_px"]), "mean_known_joint_error_rad": mean(known),
            "mean_known_age_s": float(np.nanmean(measured["known_age_s"])) if len(measured) else math.nan}


def replicate_table(results) -> pd.DataFrame:
    """One row per run: target, link (its name, or "passive"), mode, seed, the link's factors, and
    the replicate's means over its measured revolution(s): detection_rate, mean_abs_error_m (the
    paper's |d_est − d_true|), mean_world_error_m (|p_est − p_true|, the detection through the pose
    the loop knows), mean_offset_px, mean_known_joint_error_rad (largest joint of |known − true|)
    and mean_known_age_s."""
    return pd.DataFrame([_row(r) for r in results])


METRICS = {"distance": "mean_abs_error_m", "world": "mean_world_error_m"}


def summary_table(replicates: pd.DataFrame) -> pd.DataFrame:
    """Per target and link: replicate count, each metric's mean and 95 % t-interval, and the means
    of detection rate, offset and known pose."""
    rows = []
    for (target, link), g in replicates.groupby(["target", "link"], sort=False):
        row = {"target": target, "link": link, "replicates": len(g)}
        for metric, column in METRICS.items():
            m, lo, hi = stats.mean_interval(g[column])
            row.update({column: m, f"{metric}_ci_low_m": lo, f"{metric}_ci_high_m": hi})
        for column in ("detection_rate", "mean_offset_px", "mean_known_joint_error_rad", "mean_known_age_s"):
            row[column] = float(g[column].mean())
        rows.append(row)
    return pd.DataFrame(rows)


# ----------------------------------------------------------------------------------------------
# hypotheses
# ----------------------------------------------------------------------------------------------
def _values(replicates, target, link, column) -> pd.Series:
    sel = replicates[(replicates["target"] == target) & (replicates["link"] == link)]
    if sel["seed"].duplicated().any():
        raise ValueError(f"{target}, {link}: a seed appears twice (a mix of runs)")
    return sel.set_index("seed")[column].sort_index()


def check_hypotheses(replicates: pd.DataFrame) -> pd.DataFrame:
    """L1, L2 and L3 for every link, step and target present, with three-way verdicts, then
    :func:`gimbal_lab.stats.holm` across the whole table (columns p_holm, verdict_holm).

    Unit "m". A pair with a missing value (a replicate without a detection) drops out; fewer
    than two pairs is "inconclusive".
    """
    rows = []
    if "attitude" in replicates:
        replicates = replicates[replicates["attitude"] == "as-is"]
    present = set(zip(replicates["target"], replicates["link"]))

    def add(cid, statement, condition, a_label, b_label, a, b, factor="", metric="distance"):
        a, b = a.align(b, join="outer")
        rows.append(dict(id=cid, statement=statement, condition=condition, a=a_label, b=b_label, unit="m",
                         factor=factor, metric=metric,
                         result=stats.less_than(a.to_numpy(), b.to_numpy(), drop_missing=True)))

    order = [n for n in dict.fromkeys(replicates["link"]) if n != PASSIVE]
    for cid, metric, what in (("L1", "distance", "distance error"), ("L3", "world", "world error")):
        column = METRICS[metric]
        for target in TARGETS:
            if (target, PASSIVE) not in present:
                continue
            for name in order:
                if (target, name) in present:
                    add(cid, f"active through the link < passive ({what})", f"{target}, {name}", "active", "passive",
                        _values(replicates, target, name, column), _values(replicates, target, PASSIVE, column),
                        metric=metric)
    for metric, column in METRICS.items():
        for target in TARGETS:
            for factor, better, worse in steps():
                if (target, better) in present and (target, worse) in present:
                    add("L2", f"the {metric} error grows from the better to the worse level", f"{target}, {factor}",
                        better, worse, _values(replicates, target, better, column),
                        _values(replicates, target, worse, column), factor=factor, metric=metric)
    if not rows:
        raise ValueError("the replicate table holds none of the cells the hypotheses compare")
    return stats.holm(stats.verdict_table(rows))


def _as_is_name(name: str) -> str:
    """A propagated link's name without its ", propagated" (the as-is link it pairs with)."""
    suffix = ", propagated"
    return name[:-len(suffix)] if name.endswith(suffix) else name


def check_propagation(replicates: pd.DataFrame) -> pd.DataFrame:
    """The propagated arm's family (docs/design.md, "A loop that knows how old its attitude is"):
    L1p and L3p per link and target (the propagated loop < passive, distance and world error) and
    P1 (propagated < as-is, world error), conditions named by the as-is link, then
    :func:`gimbal_lab.stats.holm` across these verdicts alone. Empty without propagated runs."""
    arm = replicates[replicates["attitude"] == "propagated"]
    if arm.empty:
        return pd.DataFrame()
    present = set(zip(replicates["target"], replicates["link"]))
    rows = []

    def add(cid, statement, condition, a_label, b_label, a, b, metric):
        a, b = a.align(b, join="outer")
        rows.append(dict(id=cid, statement=statement, condition=condition, a=a_label, b=b_label, unit="m",
                         factor="", metric=metric, result=stats.less_than(a.to_numpy(), b.to_numpy(), drop_missing=True)))

    names = list(dict.fromkeys(arm["link"]))
    for cid, metric, what in (("L1p", "distance", "distance error"), ("L3p", "world", "world error")):
        for target in TARGETS:
            if (target, PASSIVE) not in present:
                continue
            for name in names:
                if (target, name) in present:
                    add(cid, f"propagated active through the link < passive ({what})", f"{target}, {_as_is_name(name)}",
                        "propagated", "passive", _values(replicates, target, name, METRICS[metric]),
                        _values(replicates, target, PASSIVE, METRICS[metric]), metric)
    for target in TARGETS:
        for name in names:
            plain = _as_is_name(name)
            if (target, name) in present and (target, plain) in present:
                add("P1", "propagating the status lowers the world error", f"{target}, {plain}", "propagated",
                    "as-is", _values(replicates, target, name, METRICS["world"]),
                    _values(replicates, target, plain, METRICS["world"]), "world")
    return stats.holm(stats.verdict_table(rows)) if rows else pd.DataFrame()


def break_even(verdicts: pd.DataFrame, cid: str = "L1", column: str = "verdict_holm") -> pd.DataFrame:
    """Per target and factor (columns target, factor, fails_at, links_checked), the first level (walking from the reference link towards the worse
    levels, the other factors at the reference's) at which ``cid`` no longer holds, by ``column``;
    "none" when it holds at every level run. The status rate starts from the in-process loop."""
    rows = []
    v = verdicts[verdicts["id"] == cid]
    for target in TARGETS:
        for factor, levels in FACTORS.items():
            path = ([IN_PROCESS] if factor == "status_rate_hz" else []) + \
                   [REFERENCE.replace(**{factor: level}).label for level in levels]
            found, walked = "none", []
            for name in path:
                sel = v[v["condition"] == f"{target}, {name}"]
                if sel.empty:
                    continue
                walked.append(name)
                if sel.iloc[0][column] != stats.HOLDS:
                    found = name
                    break
            if walked:
                rows.append({"target": target, "factor": factor, "fails_at": found, "links_checked": len(walked)})
    return pd.DataFrame(rows)


def verdict_reason(row) -> str:
    return _params.verdict_reason(row, "with a detection in both runs")


def hypotheses_markdown(verdicts: pd.DataFrame, summary: pd.DataFrame | None = None,
                        study: LinkStudy | None = None) -> str:
    """claims.md: the setting, every verdict with its interval and δ and its Holm verdict, the
    count per hypothesis, a reason for each that does not hold, and the break-even per factor."""
    study = study or LinkStudy()
    n = int(verdicts["n"].max()) if len(verdicts) else 0
    lines = [
        "# The link: the paper's active loop with its gimbal behind MAVLink",
        "",
        f"Cells: the paper's {', '.join(study.targets)} on the distorted circle (its S1 and A4), {n} replicates of "
        f"{study.revolutions:g} revolutions (the first is acquisition), paired by seed across every link. Active: the "
        "paper's PI image loop, its gimbal run by the simulated MAVLink device in lock-step over loopback UDP; it "
        "knows the joints of the latest attitude status received, and maps its detection to the world through "
        f"them. Design: {study.design} ({len(study.links)} links"
        f"{', a subset' if study.only else ''}); passive: the stabilised gimbal at home (no link).",
        "",
        _params.verdict_rule("max(1 mm, 10 % of the smaller mean)", "Holm: L1–L3 are one family at 5 % family-wise "
                             "(verdict_holm), and the propagated arm's L1p, L3p and P1 another."),
        "",
        "| id | condition | a | b | metric | n | mean a mm | mean b mm | a − b [95 % CI] mm | δ mm | verdict | "
        "p Holm | Holm verdict |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    mm = lambda x: f"{1000 * x:.2f}"  # noqa: E731
    for row in verdicts.itertuples():
        p = "–" if not math.isfinite(row.p_holm) else f"{row.p_holm:.2g}"
        lines.append(f"| {row.id} | {row.condition} | {row.a} | {row.b} | {row.metric} | {row.n} | {mm(row.mean_a)} | "
                     f"{mm(row.mean_b)} | {mm(row.difference)} [{mm(row.low)}, {mm(row.high)}] | {mm(row.delta)} | "
                     f"**{row.verdict}** | {p} | **{row.verdict_holm}** |")
    lines += ["", "| hypothesis | " + " | ".join(stats.VERDICTS) + " | Holm: " + " | Holm: ".join(stats.VERDICTS)
              + " |", "|---|---|---|---|---|---|---|"]
    for cid, g in verdicts.groupby("id", sort=False):
        a, b = g["verdict"].value_counts(), g["verdict_holm"].value_counts()
        lines.append(f"| {cid} | " + " | ".join(str(a.get(v, 0)) for v in stats.VERDICTS) + " | "
                     + " | ".join(str(b.get(v, 0)) for v in stats.VERDICTS) + " |")
    for cid, what in (("L1", "distance error"), ("L3", "world error"), ("L1p", "distance error, propagated"),
                      ("L3p", "world error, propagated")):
        table = break_even(verdicts, cid)
        if len(table):
            lines += ["", f"## Break-even of {cid} ({what}): the first level of each factor where active no longer "
                      "beats passive (Holm verdict)", "", "| target | factor | first link where it fails | links checked |",
                      "|---|---|---|---|"]
            lines += [f"| {r.target} | {r.factor} | {r.fails_at} | {r.links_checked} |" for r in table.itertuples()]
    failing = verdicts[verdicts["verdict"] != stats.HOLDS]
    lines += ["", "## Conditions that do not hold or are inconclusive (per-comparison verdict)", ""]
    if failing.empty:
        lines.append("Every condition holds.")
    for row in failing.itertuples():
        lines.append(f"- **{row.id}** ({row.condition}, {row.metric}: {row.a} vs {row.b}), {row.verdict}: "
                     f"{verdict_reason(row)}.")
    if summary is not None and len(summary):
        lines += ["", "## Per target and link (measured revolutions, means over replicates)", "",
                  "| target | link | n | distance error mm [95 % CI] | world error mm [95 % CI] | detected % | "
                  "offset px | known joint error mrad | known age ms |", "|---|---|---|---|---|---|---|---|---|"]
        for r in summary.itertuples():
            lines.append(f"| {r.target} | {r.link} | {r.replicates} | {mm(r.mean_abs_error_m)} "
                         f"[{mm(r.distance_ci_low_m)}, {mm(r.distance_ci_high_m)}] | {mm(r.mean_world_error_m)} "
                         f"[{mm(r.world_ci_low_m)}, {mm(r.world_ci_high_m)}] | {100 * r.detection_rate:.1f} | "
                         f"{r.mean_offset_px:.1f} | {1000 * r.mean_known_joint_error_rad:.2f} | "
                         f"{1000 * r.mean_known_age_s:.1f} |")
    return "\n".join(lines) + "\n"


# ----------------------------------------------------------------------------------------------
# figures and the report
# ----------------------------------------------------------------------------------------------
def plot_advantage(summary: pd.DataFrame, metric: str = "distance"):
    """Per target, each link's active error (mean and 95 % interval) beside the passive one's band:
    the advantage survives a link whose interval lies below the band. Returns the figure."""
    from ._params import report_pyplot

    plt = report_pyplot()
    column = METRICS[metric]
    targets = [t for t in TARGETS if (summary["target"] == t).any()]
    fig, axes = plt.subplots(len(targets), 1, figsize=(9, 1.2 + 0.32 * summary["link"].nunique() * len(targets)),
                             squeeze=False)
    for ax, target in zip(axes[:, 0], targets):
        s = summary[summary["target"] == target]
        passive = s[s["link"] == PASSIVE]
        active = s[s["link"] != PASSIVE].reset_index(drop=True)
        y = np.arange(len(active))[::-1]
        mean = 1000 * active[column].to_numpy()
        low = 1000 * active[f"{metric}_ci_low_m"].to_numpy()
        high = 1000 * active[f"{metric}_ci_high_m"].to_numpy()
        ax.errorbar(mean, y, xerr=[mean - low, high - mean], fmt="o", color="C0", capsize=3, label="active via link")
        if len(passive):
            p = passive.iloc[0]
            ax.axvspan(1000 * p[f"{metric}_ci_low_m"], 1000 * p[f"{metric}_ci_high_m"], color="C3", alpha=0.2)
            ax.axvline(1000 * p[column], color="C3", label="passive (95 % interval shaded)")
        ax.set_yticks(y, active["link"])
        ax.set_xlabel(f"{metric} error, mm (mean over replicates, 95 % t-interval)")
        ax.set_title(f"{target}: active through each link vs passive")
        ax.legend(loc="best", fontsize="small")
    fig.tight_layout()
    return fig


def plot_factors(summary: pd.DataFrame, metric: str = "distance"):
    """The active error against each factor's levels (the others at the reference link's), a line
    per target, the passive level dashed. Returns the figure."""
    from ._params import report_pyplot

    plt = report_pyplot()
    column = METRICS[metric]
    fig, axes = plt.subplots(1, len(FACTORS), figsize=(3.0 * len(FACTORS), 3.2), sharey=True)
    labels = {"status_rate_hz": ("status rate", lambda v: "in-proc." if v is None else f"{v:g} Hz"),
              "latency_s": ("latency", lambda v: f"{1000 * v:g} ms"),
              "quantum_rad": ("quantum", lambda v: f"{math.degrees(v):g}°"),
              "loss": ("status loss", lambda v: f"{100 * v:g} %"),
              "commanded_only": ("feedback", lambda v: "commanded" if v else "measured")}
    for ax, (factor, levels) in zip(axes, FACTORS.items()):
        title, fmt = labels[factor]
        path = ([(None, IN_PROCESS)] if factor == "status_rate_hz" else []) + \
               [(level, REFERENCE.replace(**{factor: level}).label) for level in levels]
        for i, target in enumerate(t for t in TARGETS if (summary["target"] == t).any()):
            s = summary[summary["target"] == target].set_index("link")
            xs = [k for k, (_, name) in enumerate(path) if name in s.index]
            if not xs:
                continue
            rows = s.loc[[path[k][1] for k in xs]]
            m = 1000 * rows[column].to_numpy()
            err = [m - 1000 * rows[f"{metric}_ci_low_m"].to_numpy(), 1000 * rows[f"{metric}_ci_high_m"].to_numpy() - m]
            ax.errorbar(xs, m, yerr=err, fmt="o-", color=f"C{i}", capsize=3, label=f"{target} active")
            if PASSIVE in s.index:
                ax.axhline(1000 * s.loc[PASSIVE, column], color=f"C{i}", ls="--", lw=1, label=f"{target} passive")
        ax.set_xticks(range(len(path)), [fmt(level) for level, _ in path])
        ax.set_title(title)
    axes[0].set_ylabel(f"{metric} error, mm")
    handles, names = axes[0].get_legend_handles_labels()
    if handles:
        axes[0].legend(handles, names, fontsize="small")
    fig.tight_layout()
    return fig


def make_report(results, study: LinkStudy) -> _report.Report:
    """The study's report (:class:`gimbal_lab.studies.report.Report`): ``summary.csv``,
    ``replicates.parquet`` and ``.csv``, ``verdicts.csv``, ``claims.md``, ``study.json`` and in
    ``figures/`` the advantage and the factors per metric and the forest plot, PNG and SVG."""
    replicates = replicate_table(results)
    summary = summary_table(replicates)
    verdicts = pd.concat([check_hypotheses(replicates), check_propagation(replicates)], ignore_index=True)
    figures = []
    for metric in METRICS:
        figures += [(f"advantage_{metric}", lambda metric=metric: plot_advantage(summary, metric)),
                    (f"factors_{metric}", lambda metric=metric: plot_factors(summary, metric))]
    return _report.Report(NAME, study, len(results), [
        ("summary.csv", summary), ("replicates.parquet", replicates), ("replicates.csv", replicates),
        ("verdicts.csv", verdicts), ("claims.md", hypotheses_markdown(verdicts, summary, study)),
    ], figures, verdicts)


def run_study(study: LinkStudy, out, *, store=None, executor=None, jobs=None, progress=True,
              clips: bool = True) -> dict:
    """Run the grid (reusing ``store``) and write the report to ``out/link``
    (:func:`gimbal_lab.studies.report.run_and_report`).

    ``clips`` is accepted for the command line's sake; this study writes figures, not clips.
    """
    return _report.run_and_report(NAME, "link study", grid(study), make_report, study, out, store=store,
                                  executor=executor, jobs=jobs, progress=progress)
