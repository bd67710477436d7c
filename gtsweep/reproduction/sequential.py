"""The sequential design of ``--size decide``: each finding is judged after every round that added its data, at a
level that keeps its error rate, and frozen once decided.

Design: group-sequential alpha spending (Lan & DeMets 1983) with the Pocock-type spending function
alpha · ln(1 + (e - 1) t) (:func:`~gtsweep.evaluation.statistics.spent_alpha`), t = the information fraction,
the count per texture over the survey's full count (100; Table 2's single image per texture is its full count,
t = 1 at once). At look k a finding's tests run at the increment alpha(t_k) - alpha(t_k-1): by the union bound the
probability of any wrong verdict of each kind (holds, fails, equivalent) over all looks stays below alpha,
whatever the correlation between looks (conservative against exact boundaries). Pocock-type rather than
O'Brien-Fleming: the rounds exist to stop early when the verdict is clear; O'Brien-Fleming spends almost nothing
before half the data (about 1e-15 at t = 0.06), so no round before the 50th image could decide anything. A
finding still undecided at its full count stays undecided, with the images that would decide it at the observed
effect.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import pandas as pd

from gtsweep.core.config import METHOD_GROUPS
from gtsweep.evaluation.statistics import spent_alpha
from gtsweep.evaluation.verdicts import DECIDED
from gtsweep.report.samples import load_views
from gtsweep.report.tables import frame, load_summaries
from gtsweep.reproduction.findings import FINDINGS, Finding, Hypothesis, check, survey_variant
from gtsweep.reproduction.rounds import counts, fraction


@dataclass
class Status:
    hypothesis: Hypothesis
    finding: Finding | None = None
    round: int = 0  # the round of its last look
    per_texture: int = 0  # count per texture at its last look
    fraction: float = 0.0  # information fraction at its last look
    spent: float = 0.0  # alpha spent so far
    nominal: float = math.nan  # the level of its last look
    looks: list = field(default_factory=list)  # (round, per texture, nominal level, verdict)

    @property
    def decided(self) -> bool:
        return self.finding is not None and self.finding.verdict in DECIDED

    @property
    def final(self) -> bool:
        return self.decided or self.fraction >= 1.0  # not testable early (e.g. an empty half): more data may help

    @property
    def asks_for_data(self) -> bool:
        """Open, and more images could decide it: a finding no number of images decides (an interval over the
        methods compared: ``to_decide`` infinite) asks for none, and is judged again only when its preset runs for
        another finding."""
        return not self.final and not (self.finding is not None and self.finding.to_decide == math.inf)


class Sequential:
    """The state of every finding across rounds; :meth:`update` is the ``needed`` callback of
    :func:`gtsweep.reproduction.rounds.run_rounds`."""

    def __init__(self, alpha: float, findings: list[Hypothesis] = FINDINGS, information=fraction):
        self.alpha, self.information = alpha, information  # information(preset, counts): fraction t in (0, 1]
        self.status = [Status(h) for h in findings]

    def update(self, k: int, latest: dict[str, dict]) -> dict[str, list[dict]]:
        """Judge every open finding whose preset ran in round ``k`` (0-based); the cells the next round needs:
        per preset, the union of the cells its open findings read (:attr:`Hypothesis.needs`), as method dicts."""
        data = {}
        for s in self.status:
            run = latest.get(s.hypothesis.preset)
            if s.final or run is None or run.get("round") != k + 1:
                continue
            preset = s.hypothesis.preset
            if preset not in data:
                summaries, views = run_data(run)
                frames, _ = survey_variant({preset: frame(summaries)})
                data[preset] = (frames, {preset: views})
            t = self.information(preset, run["counts"])
            nominal = spent_alpha(self.alpha, t) - s.spent
            s.finding = check(s.hypothesis, *data[preset], nominal)
            s.round, s.per_texture, s.fraction, s.spent, s.nominal = k + 1, counts(preset, run["counts"]), t, \
                spent_alpha(self.alpha, t), nominal
            s.looks.append((k + 1, s.per_texture, nominal, s.finding.verdict))
        return needed_cells([s.hypothesis for s in self.status if s.asks_for_data], latest)

    def decided_at(self) -> dict[str, tuple[int, int]]:
        """Per finding (its text): the round and the count per texture of its last look."""
        return {s.hypothesis.text: (s.round, s.per_texture) for s in self.status if s.round}

    def findings(self) -> list[Finding]:
        return [s.finding or Finding(s.hypothesis.text, "not measured") for s in self.status]



def run_data(run: dict, views: bool = True) -> tuple[list[dict], dict | None]:
    """A preset run's cell summaries and per-view rows: given with the run (read from the reproduction's state),
    else read from its output directory."""
    if "summaries" in run:
        return run["summaries"], run.get("views")
    return load_summaries(run["output"]), load_views(run["output"]) if views else None


def needed_cells(open_findings: list[Hypothesis], latest: dict[str, dict]) -> dict[str, list[dict]]:
    """Per preset of ``open_findings``, the methods of the cells they read among the cells of its newest run."""
    needed = {}
    for preset in dict.fromkeys(h.preset for h in open_findings):
        if preset not in latest:
            continue
        cells = frame(run_data(latest[preset], views=False)[0])
        keep = pd.Series(False, index=cells.index)
        for hypothesis in (h for h in open_findings if h.preset == preset):
            keep |= hypothesis.needs(cells).to_numpy()
        methods = [c for c in METHOD_GROUPS if c in cells]
        needed[preset] = [{m: (None if pd.isna(v) else v) for m, v in row.items()}
                          for row in cells.loc[keep.to_numpy(), methods].to_dict("records")]
    return needed
