"""The reproduction's looks, taken on its committed state (:mod:`gtsweep.reproduction.state`).

A look is a function of the rows it reads, so the rounds 1-5 of ``--size decide`` are replayed on the prefixes of
the rows their cells had then (:func:`replay`: round k reads every cell up to round k's count, a cell left at an
earlier count has no rows beyond it). The amendment's looks follow (:func:`amended_looks`): findings 3, 4 and 9 at
the survey's count with the remaining alpha, the restated findings and Table 2's extension at their own alpha 0.05;
each only once every row it reads exists, else *pending*.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gtsweep.report.pools import Data
from gtsweep.report.tables import frame
from gtsweep.reproduction import amended
from gtsweep.reproduction.findings import Finding, check, judge, survey_variant
from gtsweep.reproduction.rounds import PRESETS, ROUNDS, counts
from gtsweep.reproduction.sequential import Sequential, Status
from gtsweep.reproduction.state import State, item_numbers

PENDING = "pending"
#: The survey's count per texture: the amended final looks are at t = 1.
FULL = 100


def round_count(preset: str, k: int) -> int:
    """The count per texture a preset's cells reached in round ``k`` (0-based); Table 2 stays at 1."""
    return counts(preset, ROUNDS[k])


def preset_run(state: State, preset: str, k: int, limit: int | None) -> dict:
    """What round ``k`` of a preset read, as :meth:`Sequential.update` takes it."""
    return {"preset": preset, "round": k + 1, "counts": list(ROUNDS[k]), "summaries": state.summaries(preset, limit),
            "views": state.views(preset, limit)}


def replay(state: State, alpha: float, rounds: int = 5) -> Sequential:
    """Rounds 1 to ``rounds`` of ``--size decide`` judged again on the state's rows, as :func:`run_rounds` ran
    them: round 1 every preset, each later round the presets that the open findings asked for."""
    sequential, latest = Sequential(alpha), {}
    wanted = {p: None for p in PRESETS if p in state.presets}
    for k in range(rounds):
        if not wanted:
            break
        wanted = {p: c for p, c in wanted.items() if round_count(p, k) <= state.reached(p)}  # rebuilt so far
        for preset in [p for p in PRESETS if p in wanted]:
            latest[preset] = preset_run(state, preset, k, round_count(preset, k))
        asked = sequential.update(k, latest)
        wanted = {p: c for p, c in asked.items() if p in state.presets and c != []}
    return sequential


@dataclass
class Look:
    """A look of the amendment: its finding (or *pending* with what it still lacks) and its level."""

    finding: Finding
    level: float
    n_per_texture: int
    missing: str = ""


#: Which part of the new data (:data:`~gtsweep.reproduction.design.NEW_WINDOWS`) each amended look reads.
PART = {"best_repeatability_final": "round6", "sift_ambiguous_final": "round6",
        "sift_best_on_synthetic_final": "round6-pairings", "selectors_restated": "extension",
        "best_repeatability_restated": "round6", "low_ambiguity_restated": "round6",
        "censure_or_msd_best_restated": "restated", "nms_beats_other_selectors": "extension",
        "selection_hurts_dense_detectors": "extension"}


def preset_data(state: State, preset: str, alpha: float, numbers: range | None = None) -> Data:
    summaries = state.summaries(preset)
    views = state.views(preset)
    if numbers is not None:  # only these images or pairs (the extension's original tests, which pick nothing)
        views = {k: v[np.isin(item_numbers(v["image"]), list(numbers))] for k, v in views.items()}
    frames, _ = survey_variant({preset: frame(summaries)})
    return Data(frames[preset], views, alpha)


def amended_looks(state: State, sequential: Sequential, alpha: float, done: set[str]) -> dict[str, list[Look]]:
    """The amendment's looks: ``final`` (findings 3, 4, 9), ``restated`` (3', 5', 6') and ``extension`` (1, 2
    and 1' on the fresh images); ``done``: the parts of the new data whose every chunk the state holds (a look
    of another part is *pending*)."""
    final = []
    for hypothesis in amended.FINAL:
        status = next(s for s in sequential.status if s.hypothesis.text == hypothesis.text)
        final.append(_look(state, hypothesis, alpha - status.spent, FULL, done, status))
    restated = [_look(state, h, alpha, FULL, done) for h in amended.RESTATED[1:]]
    fresh = range(*amended.EXTENSION_IMAGES)
    extension = [_look(state, h, alpha, len(fresh), done, numbers=fresh)
                 for h in [*amended.EXTENSION, amended.RESTATED[0]]]
    return {"final": final, "restated": restated, "extension": extension}


def _look(state: State, hypothesis, level: float, per_texture: int, done: set[str], status: Status | None = None,
          numbers: range | None = None) -> Look:
    part = PART[hypothesis.build.__name__]
    if status is not None and status.decided:
        return Look(status.finding, status.nominal, status.per_texture)
    if part not in done:
        return Look(Finding(hypothesis.text, PENDING, hypothesis.test, margin=hypothesis.margin), level,
                    per_texture, f"its new data ({part}) is not collected yet")
    data = preset_data(state, hypothesis.preset, level, numbers)
    finding = judge(hypothesis, data)
    if status is not None:  # the sequential record: the final look at t = 1 spends the rest of alpha
        status.finding, status.round, status.per_texture, status.fraction = finding, 6, FULL, 1.0
        status.spent, status.nominal = status.spent + level, level  # the whole alpha: t = 1
        status.looks.append((6, FULL, level, finding.verdict))
    return Look(finding, level, per_texture)


__all__ = ["replay", "amended_looks", "Look", "PENDING", "check"]
