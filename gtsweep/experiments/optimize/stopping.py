"""When a study has found its best: "the best value has stopped moving".

A study stops before ``n_trials`` (then a maximum) when ``experiment.patience`` is set and none of the last
``patience`` complete trials raised the best score of the trials before them by more than
``experiment.min_improvement`` (absolute score units). The defaults of ``make tune``: patience 20 trials (twice
TPE's 10 random start-up trials, so the model-guided search has had as many trials as the random start) and
min_improvement 0.005, half a unit of the survey's two printed decimals: a smaller gain could not change any
number the survey's tables print.
"""
from __future__ import annotations

import numpy as np


def settled(values, patience: int | None, min_improvement: float) -> bool:
    """True when the scores ``values`` (complete trials in order, higher is better) have a best that the last
    ``patience`` trials did not raise by more than ``min_improvement``; False without ``patience`` or with fewer
    than ``patience`` + 1 trials."""
    values = np.asarray(list(values), dtype=np.float64)
    if not patience or len(values) <= patience:
        return False
    before = np.nanmax(values[:-patience])
    return not np.nanmax(values[-patience:]) > before + float(min_improvement)
