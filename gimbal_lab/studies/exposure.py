"""The moving drone with exposure as a choice: SP1′, SP2′, BP1′ and BP2′ (docs/design.md,
"Exposure as a choice, and a buying rule": the re-registered claims and their *As built* note).

The moving drone's sphere scene (its circular path, its motions, the global shutter, each
replicate's phases) seen through the buying-rule map's camera: the paper's distorted lens and the
EMVA 1288 sensor model of an IMX273 at f/2.8 at one of two lights, 300 and 10,000 lx. Every
pipeline of the map (two active, six passive) picks its exposure from E on the calibration seeds
(:func:`gimbal_lab.studies.light.choose_exposures`); the test seeds, which never entered a
choice, then run each pipeline at its own exposure. Per condition (motion × light):

* SP1′ "active (paper) < every passive pipeline", SP2′ the same for active (best): the
  intersection–union rule over the passive pipelines (:func:`gimbal_lab.stats.against_every`,
  k = the passive pipelines that chose an exposure, six unless one detected at none);
* BP1′ / BP2′ "active (paper) / (best) < best passive", the best passive pipeline on the
  calibration seeds at its chosen exposure: the three-way rule.

A replicate's pair is the two pipelines' mean errors on the measured frames both detected
(:func:`gimbal_lab.studies.payoff.common_frame_errors`); a replicate without such frames drops
out of that comparison. The 24 verdicts are one family, held to 5 % by Holm.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import pandas as pd

from .. import stats
from ..config import Camera, Estimator, TrackingConfig
from . import light as _light
from ._params import format_p, md_cell, verdict_counts
from .moving_drone import _POINTING, MovingDroneStudy
from .payoff import common_frame_errors

__all__ = ["ExposureStudy", "Study", "MOTIONS", "LIGHTS_LUX", "CLAIMS", "conditions", "config",
           "calibration_index", "grid", "all_configs", "calibration_table", "test_index", "test_configs",
           "pair_table", "check_hypotheses", "analyse", "make_report", "run_study"]

NAME = "exposure"
DESCRIPTION = ("the moving drone with exposure as a choice: SP1'/SP2'/BP1'/BP2', every pipeline at the exposure "
               "it picks for 300 and 10,000 lx (sphere, global shutter)")

#: The motions and lights of the six conditions, numbered motions outer, lights inner.
MOTIONS = ("hover", "vibration", "flight")
LIGHTS_LUX = (300.0, 10_000.0)

#: The claims: id, active pipeline, against ("every passive" or "best passive").
CLAIMS = (("SP1′", "active (paper)", "every passive"), ("SP2′", "active (best)", "every passive"),
          ("BP1′", "active (paper)", "best passive"), ("BP2′", "active (best)", "best passive"))


@dataclass(frozen=True)
class ExposureStudy(_light.ChoiceStudyParams):
    """Parameters of the moving drone with exposure as a choice.

    Parameters
    ----------
    replicates : int
        Test replicates per condition, >= 2 (5 at full size); seeds ``first_seed`` onwards.
    first_seed : int
        Seed of the first test replicate (200: disjoint from every earlier study's and from the
        calibration seeds).
    calibration_seeds : tuple of int
        The seeds on which every pipeline chooses its exposure ((100, 101)); none may be a test seed.
    exposures_ms : tuple of float
        The exposure set E, ms ((0.5, 1, 2, 4, 8, 16.7)); each > 0 and within the frame period.
    revolutions : float
        Periods of the circle per run (2: the first acquisition); down to :data:`MIN_REVOLUTIONS`,
        notebook 17's size under pytest (a run inside its first revolution measures its second half).
    period_s, fps, latency_frames :
        As every study's: the circle's period (2 s), 30 frames/s, one frame of latency.
        ``noise_std`` is not used (the sensor model sets the noise) and is refused when set.
    """

    _TABLE = NAME


#: The study's parameters class (``gimbal-lab run`` looks for ``Study`` in every study module).
Study = ExposureStudy


# ----------------------------------------------------------------------------------------------
# conditions and runs
# ----------------------------------------------------------------------------------------------
def conditions() -> pd.DataFrame:
    """The six conditions: condition (0–5), motion, light_lux; motions outer, lights inner."""
    rows = [(i * len(LIGHTS_LUX) + j, m, lux) for i, m in enumerate(MOTIONS) for j, lux in enumerate(LIGHTS_LUX)]
    return pd.DataFrame(rows, columns=["condition", "motion", "light_lux"])


#: The moving drone's mount for each pointing kind of the map's runs.
_MOUNT_OF = {kind: mount for mount, kind in _POINTING.items()}


def config(condition: int, pipeline: str, exposure_s: float, seed: int, study: ExposureStudy | None = None
           ) -> TrackingConfig:
    """The run that records ``pipeline`` in one condition at one exposure and seed: the moving
    drone's run (sphere, global shutter) with the map's camera and the pipeline's estimator.
    Pipelines that one run records (:data:`gimbal_lab.studies.light.RUNS`) get the same config."""
    study = study or ExposureStudy()
    if pipeline not in _light.PIPELINES:
        raise ValueError(f"pipeline must be one of {_light.PIPELINES}, got {pipeline!r}")
    table = conditions().set_index("condition")
    if condition not in table.index:
        raise ValueError(f"condition must be one of {list(table.index)}, got {condition!r}")
    motion, lux = table.loc[condition, "motion"], float(table.loc[condition, "light_lux"])
    kind, method, lens_strategy, extra_methods = _light._RUN_PARTS[_light._RUN_OF[pipeline][0]]
    drone = MovingDroneStudy(period_s=study.period_s, fps=study.fps, latency_frames=study.latency_frames)
    base = drone.config("sphere", motion, _MOUNT_OF[kind], "global", int(seed))
    camera = Camera(fps=study.fps, latency_frames=study.latency_frames, exposure_s=float(exposure_s),
                    noise="sensor", light_lux=lux, lens="default")
    return base.replace(camera=camera, revolutions=study.revolutions,
                        estimator=Estimator(sphere_method=method, lens_strategy=lens_strategy,
                                            extra_methods=extra_methods))


def calibration_index(study: ExposureStudy | None = None) -> pd.DataFrame:
    """What each calibration run is, in :func:`grid`'s order: condition, exposure_s, seed, run
    (conditions outer, then exposures, seeds and the runs of the map)."""
    study = study or ExposureStudy()
    rows = [(c, e, s, run) for c in conditions()["condition"] for e in study.exposures_s
            for s in study.calibration_seeds for run, *_ in _light.RUNS]
    return pd.DataFrame(rows, columns=["condition", "exposure_s", "seed", "run"])


def grid(study: ExposureStudy | None = None) -> list[TrackingConfig]:
    """The calibration runs, in :func:`calibration_index`'s order."""
    study = study or ExposureStudy()
    return [config(r.condition, _light._run_pipeline(r.run), r.exposure_s, r.seed, study)
            for r in calibration_index(study).itertuples()]


def all_configs(study: ExposureStudy | None = None) -> list[TrackingConfig]:
    """The runs known before any is made: the calibration runs (the test runs follow the choices)."""
    return grid(study)


def calibration_table(results, study: ExposureStudy | None = None) -> pd.DataFrame:
    """One row per calibration run and pipeline it records (:func:`gimbal_lab.studies.light.choice_table`),
    the condition in the column ``point``, as the map's choice code reads it. ``results`` are
    :func:`grid`'s runs in its order."""
    return _light.choice_table(calibration_index(study or ExposureStudy()), results, unit="condition")


def test_index(choices: pd.DataFrame, study: ExposureStudy | None = None) -> pd.DataFrame:
    """The test runs: per condition and test seed, each run kind at each exposure one of its
    pipelines chose (pipelines of one run kind that chose the same exposure share the run).
    Columns condition, seed, run, exposure_s."""
    study = study or ExposureStudy()
    chosen = choices.dropna(subset=["exposure_s"])
    kinds = sorted({(int(r.point), _light._RUN_OF[r.pipeline][0], float(r.exposure_s)) for r in chosen.itertuples()},
                   key=lambda k: (k[0], [r for r, *_ in _light.RUNS].index(k[1]), k[2]))
    rows = [(c, seed, run, e) for c, run, e in kinds for seed in study.seeds]
    return pd.DataFrame(rows, columns=["condition", "seed", "run", "exposure_s"])


def test_configs(index: pd.DataFrame, study: ExposureStudy | None = None) -> list[TrackingConfig]:
    """The configs of :func:`test_index`'s rows, in its order."""
    study = study or ExposureStudy()
    return [config(r.condition, _light._run_pipeline(r.run), r.exposure_s, r.seed, study) for r in index.itertuples()]


# ----------------------------------------------------------------------------------------------
# pairs and verdicts
# ----------------------------------------------------------------------------------------------
def pair_table(choices: pd.DataFrame, index: pd.DataFrame, results) -> pd.DataFrame:
    """One row per condition, test seed, active pipeline and passive pipeline (each at its chosen
    exposure): active_m and passive_m, the two mean errors on the measured frames both detected
    (NaN when there are none), and common_rate, those frames' share of the measured frames."""
    results = list(results)
    if len(results) != len(index):
        raise ValueError(f"expected {len(index)} test runs, got {len(results)}")
    frames = {(int(r.condition), int(r.seed), r.run, float(r.exposure_s)): results[i].frames
              for i, r in zip(index.index, index.itertuples())}
    chosen = {(int(r.point), r.pipeline): float(r.exposure_s) for r in choices.dropna(subset=["exposure_s"]).itertuples()}
    rows = []
    for (c, seed) in sorted({(k[0], k[1]) for k in frames}):
        of = {}  # each pipeline's frames at its chosen exposure, None for a pipeline without a choice
        for pipe in _light.PIPELINES:
            e = chosen.get((c, pipe))
            of[pipe] = None if e is None else _light._pipeline_frames(frames[(c, seed, _light._RUN_OF[pipe][0], e)],
                                                                      pipe)
        for active in _light.ACTIVE:
            fa = of[active]
            if fa is None:
                continue
            for passive in _light.PASSIVE:
                fp = of[passive]
                if fp is None:
                    continue
                errors = common_frame_errors({"active": fa, "passive": fp})
                rows.append({"condition": c, "seed": seed, "active": active, "passive": passive,
                             "active_m": errors["active"][0], "passive_m": errors["passive"][0],
                             "common_rate": errors["active"][1]})
    return pd.DataFrame(rows, columns=["condition", "seed", "active", "passive", "active_m", "passive_m",
                                       "common_rate"])


def check_hypotheses(pairs: pd.DataFrame, best: pd.DataFrame) -> pd.DataFrame:
    """The 24 verdicts (:data:`CLAIMS` × conditions, ``condition`` named "motion, light lx"), held
    to the family's 5 % by Holm.

    SP′ is the intersection–union verdict over the passive pipelines with a choice (``b`` names
    the one that decides it, ``k`` how many); BP′ the three-way rule against the condition's best
    passive pipeline. A condition where the claim's active pipeline detected at no exposure, or
    no passive pipeline did, gets an untested "inconclusive" (NaN p, counted in the family).
    """
    table = conditions().set_index("condition")
    best = best.set_index("point")
    rows = []
    for cid, active, against in CLAIMS:
        for c in table.index:
            motion, lux = table.loc[c, "motion"], float(table.loc[c, "light_lux"])
            where = {"id": cid, "condition": f"{motion}, {lux:g} lx", "motion": motion, "light_lux": lux, "a": active}
            p = pairs[(pairs["condition"] == c) & (pairs["active"] == active)]
            if against == "every passive":
                names = [n for n in _light.PASSIVE if (p["passive"] == n).any()]
            else:
                b = best.loc[c, "best_passive"] if c in best.index else None
                names = [b] if b is not None and not pd.isna(b) and (p["passive"] == b).any() else []
            if not names:
                rows.append({**where, "b": against, "k": 0, "result": _untested()})
                continue
            verdicts = []
            for n in names:
                q = p[p["passive"] == n].sort_values("seed")
                verdicts.append(stats.less_than(q["active_m"].to_numpy(float), q["passive_m"].to_numpy(float),
                                                drop_missing=True))
            j, v = stats.against_every(verdicts) if against == "every passive" else (0, verdicts[0])
            rows.append({**where, "b": names[j], "k": len(names), "result": v})
    out = stats.holm(stats.verdict_table(rows))
    out["unit"] = "m"
    return out


def _untested() -> stats.Verdict:
    return stats.less_than([math.nan, math.nan], [math.nan, math.nan], drop_missing=True)


def analyse(calibration_results, test_index_table, test_results, study: ExposureStudy) -> dict:
    """Every table of the report: calibration, choices, best, pairs, verdicts."""
    calibration = calibration_table(calibration_results, study)
    choices = _light.choose_exposures(calibration)
    best = _light.best_pipelines(choices)
    pairs = pair_table(choices, test_index_table, test_results)
    verdicts = check_hypotheses(pairs, best)
    return {"conditions": conditions(), "calibration": calibration, "choices": choices, "best": best,
            "pairs": pairs, "verdicts": verdicts}


def _ms(x) -> str:
    return f"{1000 * x:.3g}" if x is not None and math.isfinite(x) else "–"


def _mm(x) -> str:
    return f"{1000 * x:.2f}" if x is not None and math.isfinite(x) else "–"


def claims_markdown(tables: dict, study: ExposureStudy) -> str:
    """claims.md: the conditions, every pipeline's chosen exposure and calibration error, then the
    24 verdicts at both levels."""
    v, choices = tables["verdicts"], tables["choices"]
    cond = tables["conditions"].set_index("condition")
    lines = [f"# The moving drone with exposure as a choice (exposures chosen on seeds "
             f"{', '.join(map(str, study.calibration_seeds))}, tested on seeds {study.seeds[0]}–{study.seeds[-1]})", "",
             "The moving drone's sphere on its circle, global shutter, the paper's distorted lens, the IMX273 sensor "
             f"model at f/2.8; {study.revolutions:g} revolutions per run. E = {{"
             + ", ".join(f"{e:g}" for e in study.exposures_ms) + "} ms. docs/design.md, “Exposure as a choice, and a "
             "buying rule”.", "",
             "## The exposure each pipeline chose (ms) and its mean error there on the calibration seeds (mm)", "",
             "| motion | light (lx) | " + " | ".join(_light.PIPELINES) + " |", "|" + "---|" * (len(_light.PIPELINES) + 2)]
    for c, g in choices.groupby("point", sort=True):
        g = g.set_index("pipeline")
        cells = [f"{_ms(g.loc[p, 'exposure_s'])} ({_mm(g.loc[p, 'error_m'])})" if p in g.index else "–"
                 for p in _light.PIPELINES]
        lines.append(f"| {cond.loc[c, 'motion']} | {cond.loc[c, 'light_lux']:g} | " + " | ".join(cells) + " |")
    lines += ["", "## Verdicts", "", "SP′: against every passive pipeline at its own exposure (intersection–union, "
              "Bonferroni over the k compared for “does not hold”; the one named decides). BP′: against the best "
              "passive pipeline on the calibration seeds. Three-way rule, δ = max(1 mm, 10 % of the smaller mean); "
              f"the {len(v)} verdicts are one family (Holm, 5 %).", "", f"- {verdict_counts(v)}", "",
              "| claim | motion | light (lx) | against | A − B [95 % CI] mm | pairs | verdict | Holm |",
              "|---|---|---|---|---|---|---|---|"]
    for r in v.itertuples():
        lines.append(f"| {r.id} {md_cell(r.a)} | {r.motion} | {r.light_lux:g} | {md_cell(r.b)} (k = {r.k}) "
                     f"| {_mm(r.difference)} [{_mm(r.low)}, {_mm(r.high)}] | {r.n} | {r.verdict} | **{r.verdict_holm}** |")
    lines += ["", f"Smallest Holm-adjusted p in the family: {format_p(v['p_holm'].min())}."]
    return "\n".join(lines) + "\n"


def make_report(calibration_results, test_index_table, test_results, study: ExposureStudy):
    """The report: conditions.csv, calibration.csv, choices.csv, best.csv, pairs.csv,
    verdicts.csv, claims.md, study.json and the forest plot of the verdicts."""
    from . import report as _report

    tables = analyse(calibration_results, test_index_table, test_results, study)
    runs = len(calibration_results) + len(test_results)
    return _report.Report(NAME, study, runs, [
        ("conditions.csv", tables["conditions"]), ("calibration.csv", tables["calibration"]),
        ("choices.csv", tables["choices"]), ("best.csv", tables["best"]), ("pairs.csv", tables["pairs"]),
        ("verdicts.csv", tables["verdicts"]), ("claims.md", claims_markdown(tables, study)),
    ], [], tables["verdicts"], forest="forest", formats=("png",))


def run_study(study: ExposureStudy, out, *, store=None, executor=None, jobs=None, progress=True, clips=True) -> dict:
    """``gimbal-lab run exposure``: the calibration runs, the choices, the test runs (reusing
    ``store``) and the report in ``out/exposure``. ``clips`` is accepted for the command's
    uniformity; the study writes none."""
    from . import report as _report

    def plan(calibration):
        index = test_index(_light.choose_exposures(calibration_table(calibration, study)), study)
        return index, test_configs(index, study)

    return _report.run_with_choices(NAME, "exposure", grid(study), plan, make_report, study, out, store=store,
                                    executor=executor, jobs=jobs, progress=progress)
