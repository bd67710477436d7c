"""Run the survey's table presets, at one size or in rounds of growing counts (``--size decide``).

Each preset runs as its own ``python -m gtsweep`` process; its wall time, peak memory (resident memory of its
whole process tree, sampled), keypoint cache hit rate and number of MLflow runs are recorded. In rounds
(:data:`ROUNDS`), round k runs only the cells that ``needed`` (the caller's judgement of which findings are
still undecided and which cells they read, see :mod:`gtsweep.reproduction.sequential`) names, at round k's counts per
texture: a preset's grid is cut to them with ``pairings``, ``++selector_for`` and ``transform`` overrides
(:func:`restriction`). Each round's run of a preset starts from a copy of its previous run's cells (:func:`carry`):
the cells it does not run stay at the count they last reached, and the cells it runs keep the rows of the images
and pairs they already evaluated (a data set's first n views are the same for any larger count,
``tests/test_survey.py``; :mod:`gtsweep.orchestration.view_reuse`), so a round evaluates only its new images and
pairs, and only for the cells still needed. The keypoint cache is shared by every round.
"""
from __future__ import annotations

import json
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

from gtsweep.core.atomic import write_atomically
from gtsweep.core.config import METHOD_GROUPS
from gtsweep.core.memory import PeakMemory
from gtsweep.core.paths import SWEEPS_DIR
from gtsweep.core.rundirs import PARENT_RECORD, RUN_RECORD
from gtsweep.reproduction import task_costs
from gtsweep.reproduction.run_record import RunRecord, copy_absent

PRESETS = ("table2_selectors", "table3_detectors", "table4_incremental", "table5_absolute", "table6_pairings",
           "table7_reference_features")
#: Fixed data set sizes (per texture). The table presets select dataset=survey (1288x964 views, capture physics);
#: "hour" reduces its counts (1 synthetic image, 6 + 6 pairs per texture) to about an hour on 2 cores, "presets"
#: keeps the presets' stated counts (10 synthetic images, 20 + 20 pairs; several hours), "full" is the survey's
#: protocol (100 + 100 + 100; days on 2 cores, hours on a cluster). "tiny" is for tests.
SIZES = {
    "tiny": ["dataset.textures=[gravel,wood]", "dataset.view_size=[320,240]", "dataset.n_synthetic=1",
             "dataset.n_incremental=2", "dataset.n_absolute=2"],
    "hour": ["dataset=survey", "dataset.n_synthetic=1", "dataset.n_incremental=6", "dataset.n_absolute=6"],
    "presets": ["dataset=survey"],
    "full": ["dataset=survey", "dataset.n_synthetic=100", "dataset.n_incremental=100", "dataset.n_absolute=100"],
}
#: ``--size decide``: counts per texture of each round, (synthetic images, incremental pairs, absolute pairs),
#: ending at the survey's full protocol (section 5: 100 of each per texture).
ROUNDS = ((1, 6, 6), (2, 12, 12), (4, 25, 25), (8, 50, 50), (16, 100, 100), (100, 100, 100))
FULL = (100, 100, 100)
#: Table 2 evaluates without selection (hundreds of thousands of keypoints): one image per texture, as the survey
#: ("for this experiment we evaluate a single test image per type of ground texture", 4.1).
PRESET_OVERRIDES = {"table2_selectors": ["dataset.n_synthetic=1"]}
#: Which count of a round each preset's findings rest on (its clusters): index into a ROUNDS entry.
KIND = {"table2_selectors": 0, "table3_detectors": 0, "table4_incremental": 1, "table5_absolute": 2,
        "table6_pairings": 0, "table7_reference_features": 1}


def counts(preset: str, counts_per_texture) -> int:
    """The count per texture a preset's findings rest on in a round (Table 2: always 1, the survey's)."""
    return 1 if preset == "table2_selectors" else int(counts_per_texture[KIND[preset]])


def fraction(preset: str, counts_per_texture) -> float:
    """Information fraction of a preset in a round: its count over the survey's full count."""
    full = 1 if preset == "table2_selectors" else FULL[KIND[preset]]
    return min(counts(preset, counts_per_texture) / full, 1.0)


def round_overrides(counts_per_texture) -> list[str]:
    synthetic, incremental, absolute = counts_per_texture
    return ["dataset=survey", f"dataset.n_synthetic={synthetic}", f"dataset.n_incremental={incremental}",
            f"dataset.n_absolute={absolute}"]


def run_preset(preset: str, overrides: list[str], work: Path, uri: str, cache: Path | None = None) -> dict:
    """Run one preset in its own process (output ``work/<preset>``); returns its measurements. The process runs in
    ``work``, so every path it is given is absolute."""
    work, cache = Path(work).resolve(), (Path(cache).resolve() if cache else None)
    out = work / preset
    work.mkdir(parents=True, exist_ok=True)
    args = [sys.executable, "-m", "gtsweep", f"sweeps={preset}", *overrides, f"hydra.run.dir={out}",
            f"mlflow.tracking_uri={uri}", "runner.progress=false", f"cache.dir={cache or work / 'cache'}"]
    start = time.perf_counter()
    with open(work / f"{preset}.log", "a") as log:  # a resumed run's attempts one after another
        process = subprocess.Popen(args, stdout=log, stderr=subprocess.STDOUT, cwd=work)
        try:
            with PeakMemory(pid=process.pid) as memory:  # the whole tree, every 0.5 s
                process.wait()
        except BaseException:  # interrupted: the sweep stops as on its own Ctrl-C, keeping its finished cells
            stop(process)
            raise
    seconds = time.perf_counter() - start
    if process.returncode != 0:
        raise SystemExit(f"gtsweep.reproduce: preset {preset} failed (exit {process.returncode}); "
                         f"see {work / f'{preset}.log'}")
    record = json.loads((out / RUN_RECORD).read_text())
    parent = json.loads((out / PARENT_RECORD).read_text())["parent_run_id"]
    lookups = record["cache_hits"] + record["cache_misses"]
    return {"preset": preset, "output": out, "wall_s": seconds, "peak_mb": memory.total / 2**20,
            "cache_hit_rate": record["cache_hits"] / lookups if lookups else float("nan"),
            "mlflow_runs": 1 + _child_runs(uri, parent), "cells": record["cells"],
            "items_evaluated": record.get("items_evaluated"), "items_reused": record.get("items_reused")}


def stop(process: subprocess.Popen, grace: float = 120.0) -> None:
    """Stop a preset's sweep as Ctrl-C does (SIGINT: it marks its MLflow runs and keeps its finished cells; a
    terminal's Ctrl-C has reached it already), and wait for it; killed when it has not stopped after ``grace``."""
    if process.poll() is None:
        process.send_signal(signal.SIGINT)
    try:
        process.wait(grace)
    except subprocess.TimeoutExpired:
        process.kill()
        process.wait()


def _child_runs(uri: str, parent: str) -> int:
    from mlflow.tracking import MlflowClient

    client = MlflowClient(uri)
    experiment = client.get_run(parent).info.experiment_id
    return len(client.search_runs([experiment], f"tags.mlflow.parentRunId = '{parent}'", max_results=50000))


def run_fixed(presets, overrides: list[str], work: Path, log=print, record: RunRecord | None = None) -> list[dict]:
    """Every preset once at one size (``overrides``); with a ``record``, the presets it holds as finished are
    not run again, and each finished run is added to it."""
    uri = f"sqlite:///{work / 'mlflow.db'}"
    results = []
    for preset in presets:
        done = record.get(preset) if record is not None else None
        if done is None:
            log(f"gtsweep.reproduce: {preset} ...")
            done = _recorded(record, preset, work / preset,
                             lambda: run_preset(preset, [*overrides, *PRESET_OVERRIDES.get(preset, [])], work, uri))
        results.append(done)
        _report(results[-1], log)
    return results


def _recorded(record: RunRecord | None, key: str, output: Path, start: Callable[[], dict]) -> dict:
    return start() if record is None else record.run(key, output, start)


def run_rounds(presets, needed: Callable[[int, dict[str, dict]], dict[str, list[dict] | None]], work: Path,
               rounds=ROUNDS, extra: list[str] = (), log=print, record: RunRecord | None = None) -> list[dict]:
    """Rounds of growing counts: round 0 runs every cell of every preset; after round k, ``needed(k, latest)``
    (``latest``: each preset's newest measurements) names the cells round k + 1 runs, per preset the methods of
    each cell (None: all of them; a set of preset names: all of theirs); stops when it names none or after the
    last round. Returns every run's measurements with its round, counts, cells asked for and extra cells run.
    With a ``record`` (:class:`~gtsweep.reproduction.run_record.RunRecord`), the runs it holds as finished are
    taken from it (``needed`` judges them again, as it did), and each finished run is added to it."""
    uri, cache = f"sqlite:///{work / 'mlflow.db'}", work / "cache"
    runs, latest, wanted = [], {}, dict.fromkeys(presets)
    for k, counts_per_texture in enumerate(rounds):
        if not wanted:
            break
        log(f"gtsweep.reproduce: round {k + 1} ({counts_per_texture} per texture): {', '.join(sorted(wanted))}")
        for preset in [p for p in presets if p in wanted]:
            key = f"round{k + 1}/{preset}"
            result = record.get(key) if record is not None else None
            if result is None:
                out, cut, extra_cells = work / f"round{k + 1}" / preset, [], 0
                if preset in latest:
                    carry(latest[preset]["output"], out)
                    if wanted[preset] is not None:
                        cut, extra_cells = restriction(cells_of(latest[preset]["output"]), wanted[preset],
                                                          preset_options(preset))
                overrides = [*round_overrides(counts_per_texture), *extra, *PRESET_OVERRIDES.get(preset, []), *cut]

                def start(preset=preset, overrides=overrides, extra_cells=extra_cells):
                    result = run_preset(preset, overrides, work / f"round{k + 1}", uri, cache)
                    return {**result, "round": k + 1, "counts": list(counts_per_texture), "extra_cells": extra_cells,
                            "cells_needed": result["cells"] - extra_cells}

                result = _recorded(record, key, out, start)
            runs.append(result)
            latest[preset] = result
            _report(result, log)
        asked = needed(k, latest)
        asked = asked if isinstance(asked, dict) else dict.fromkeys(asked)
        wanted = {p: cells for p, cells in asked.items() if p in presets and cells != []}
    return runs


def carry(previous: Path, out: Path) -> None:
    """Start ``out`` from a copy of a previous run's cells (rows, summaries and what each cell's rows cover); a
    file ``out`` already has (an interrupted attempt's newer cell) is kept."""
    for part in ("cells", "reuse"):
        if (Path(previous) / part).is_dir():
            shutil.copytree(Path(previous) / part, out / part, dirs_exist_ok=True, copy_function=copy_absent)


def cells_of(output: Path) -> list[dict]:
    """The methods of every cell of a sweep's output directory."""
    return [json.loads(p.read_text())["methods"] for p in sorted(Path(output).glob("cells/*.json"))]


def _identity(methods: dict) -> tuple:
    return tuple(methods.get(k) for k in METHOD_GROUPS)


def restriction(available: list[dict], needed: list[dict],
                options: dict[str, str] | None = None) -> tuple[list[str], int]:
    """Overrides that cut a preset's grid (its cells ``available``) to the cells ``needed``, and how many cells
    beyond those the cut grid still runs: ``transform=[...]`` for the transforms, ``pairings=[...]`` for the
    (detector, descriptor) pairs, ``++selector_for={...}`` for a detector that needs one of several selectors, and
    in a detection grid ``detector=[...]`` for the detectors needed, named as the preset names them (``options``:
    :func:`preset_options`; without them, a detector needed for no cell stays). A detector needing several but not
    all of its selectors keeps them all: the extra cells."""
    if {_identity(c) for c in available} <= {_identity(c) for c in needed}:
        return [], 0
    transforms = list(dict.fromkeys(c["transform"] for c in needed))
    pose = any(c.get("descriptor") for c in available)
    pairs = list(dict.fromkeys((c["detector"], c["descriptor"]) for c in needed if c.get("descriptor")))
    ran, wanted = {}, {}
    for group, cells in ((ran, available), (wanted, needed)):
        for c in cells:
            group.setdefault(c["detector"], set()).add(c["selector"])
    pins = {d: next(iter(s)) for d, s in wanted.items() if len(s) == 1 and ran[d] != s}
    cut = not pose and options and set(wanted) < set(ran) and set(wanted) <= set(options)
    detectors = [d for d in options if d in wanted] if cut else list(ran)
    overrides = []
    if len(detectors) < len(ran):
        overrides.append(f"detector=[{','.join(options[d] for d in detectors)}]")
    if set(transforms) != {c["transform"] for c in available}:
        overrides.append(f"transform=[{','.join(transforms)}]")
    if pose and set(pairs) != {(c["detector"], c["descriptor"]) for c in available if c.get("descriptor")}:
        overrides.append(f"pairings=[{','.join(f'[{d},{s}]' for d, s in pairs)}]")
    if pins:
        overrides.append(f"++selector_for={{{','.join(f'{d}:{s}' for d, s in sorted(pins.items()))}}}")
    kept_pairs = set(pairs)
    runs = [c for c in available if c["transform"] in transforms and c["detector"] in detectors
            and c["selector"] == pins.get(c["detector"], c["selector"])
            and (not pose or (c["detector"], c.get("descriptor")) in kept_pairs)]
    return overrides, len({_identity(c) for c in runs} - {_identity(c) for c in needed})


def preset_options(preset: str, group: str = "detector") -> dict[str, str]:
    """The options of ``group`` a preset selects (its defaults list's ``override /<group>: [...]``), by method
    name: ``{"sift": "tuned/sift", ...}``; empty when it selects none or is not one of the package's presets."""
    import yaml

    path = SWEEPS_DIR / f"{preset}.yaml"
    defaults = (yaml.safe_load(path.read_text()) or {}).get("defaults") or [] if path.exists() else []
    chosen = next((e[f"override /{group}"] for e in defaults if isinstance(e, dict) and f"override /{group}" in e),
                  [])
    return {option.rsplit("/", 1)[-1]: option for option in ([chosen] if isinstance(chosen, str) else chosen)}


def _report(r: dict, log) -> None:
    items = f", {r['items_evaluated']} (cell, image or pair) evaluated, {r['items_reused']} kept" \
        if r.get("items_evaluated") is not None else ""
    log(f"  {r['preset']}: {r['cells']} cells{items}, {r['wall_s']:.0f} s, peak {r['peak_mb']:.0f} MB, "
        f"cache hit rate {r['cache_hit_rate']:.2f}, {r['mlflow_runs']} MLflow runs")


def full_protocol_estimate(runs: list[dict], preset: str | None = None) -> float:
    """Seconds the fixed full protocol would take (of one ``preset``, or of all), from measured per-task costs:
    each preset's first run (every cell and image evaluated) with its task work (:mod:`task_costs`: detection,
    description, matching, pose, from its cells' per-view timings) scaled to the survey's counts per texture and
    its other costs (start-up, summaries, report) as measured. A preset's detections that an earlier preset at
    the same scale already made are taken from the keypoint cache, as in a run of the whole protocol."""
    first = {}
    for r in runs:
        if r["preset"] not in first or r.get("round", 0) < first[r["preset"]].get("round", 0):
            first[r["preset"]] = r
    total, made = 0.0, {}
    for name in sorted(first, key=lambda p: PRESETS.index(p) if p in PRESETS else len(PRESETS)):
        r = first[name]
        scale = 1 if name == "table2_selectors" else FULL[KIND[name]] / counts(name, r.get("counts", FULL))
        rows = task_costs.view_rows(r["output"])
        work = sum(task_costs.work_seconds(rows, made.get(scale)).values())
        found = task_costs.detections(rows)
        made.setdefault(scale, set()).update(zip(found["detector"], found["view"]))
        if preset is None or name == preset:
            total += task_costs.scaled_seconds(r["wall_s"], work, task_costs.cpus_of(r["output"]), scale)
    return total


def spent(runs: list[dict], preset: str, until: int) -> float:
    """Seconds ``preset``'s runs took up to and including round ``until``."""
    return sum(r["wall_s"] for r in runs if r["preset"] == preset and r.get("round", 0) <= until)


def save(record: Path, content: dict) -> None:
    write_atomically(record, json.dumps(content, default=str, indent=1))
