"""``experiment=optimize``: tune method parameters on the optimisation split, as the survey did (section 5).

One Optuna study per selected detector (objective ``repeatability``) or per ``[detector, descriptor]`` pairing
(objective ``pose_success``). The driver asks ``parallel_trials`` trials at a time, evaluates them as Ray tasks
(or in-process with ``runner.backend=serial``), tells each result as it arrives, and asks the next batch when the
batch is done. Before each batch the TPE sampler is re-seeded from ``sampler_seed`` and the number of complete
trials, so the same config and seed give the same trials and numbers, on Ray or in-process alike.

The study lives in an RDB storage (sqlite by default): rerunning the same command continues it. Complete trials
count toward ``n_trials``; trials left RUNNING by a kill are marked FAIL and their parameters asked again. Every
trial is an MLflow child run of the study's run (:mod:`gtsweep.tracking.study`). The best parameters are
written as ``conf/<group>/tuned/<name>.yaml``, a config file Hydra selects with ``detector=[tuned/<name>]``.
"""
from __future__ import annotations

import json
import time
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

from gtsweep.core.atomic import write_atomically
from gtsweep.core.config import config_hash, plain
from gtsweep.core.errors import BadInput, GtsweepError
from gtsweep.core.paths import CONF_DIR, DEFAULT_CACHE_DIR
from gtsweep.core.seeds import stable_seed
from gtsweep.evaluation.views import make_shard
from gtsweep.optimize.objective import OBJECTIVES, evaluate
from gtsweep.optimize.search_space import defaults_in_space, parse_space

POSE_DATA = ("optimisation", "incremental")


@dataclass
class Target:
    """What one study tunes: a detector (``group`` "detector") or a descriptor on a detector's keypoints."""

    group: str
    name: str
    detector: str
    descriptor: str | None
    node: dict  # the tuned method's config: params, search_space, ...
    defaults: dict  # the parameters the search starts from
    space: dict  # the declared search space
    distributions: dict
    detector_params: dict

    @property
    def label(self) -> str:
        return self.name if self.group == "detector" else f"{self.detector}+{self.descriptor}"


# ------------------------------------------------------------------------------------------------ settings
def _int(settings: Mapping, key: str, low: int) -> int:
    value = settings.get(key)
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise BadInput(f"experiment.{key} must be an integer >= {low}, got {value!r}")
    return value


def read_settings(cfg: Mapping) -> dict:
    """``cfg.experiment`` checked, with the storage made absolute; a mistake raises a one-line BadInput."""
    from gtsweep.evaluation.transforms import TRANSFORMS
    from gtsweep.stages.select import SELECTORS

    s = plain(cfg["experiment"])
    if s.get("objective") not in OBJECTIVES:
        raise BadInput(f"experiment.objective must be one of {', '.join(OBJECTIVES)}, got {s.get('objective')!r}")
    for key, low in (("n_trials", 1), ("parallel_trials", 1), ("min_keypoints", 1), ("sampler_seed", 0),
                     ("n_startup_trials", 0)):
        _int(s, key, low)
    iou = s.get("iou_threshold")
    if isinstance(iou, bool) or not isinstance(iou, (int, float)) or not 0 < iou < 1:
        raise BadInput(f"experiment.iou_threshold must be a number in (0, 1), got {iou!r}")
    selector = s.get("selector") or {}
    if selector.get("name") not in SELECTORS:
        raise BadInput(f"experiment.selector.name must be one of {', '.join(SELECTORS)}, got {selector.get('name')!r}")
    transforms = s.get("transforms")
    if not isinstance(transforms, dict) or not transforms:
        raise BadInput("experiment.transforms must map synthetic transforms to {strengths: [...]}")
    for name, t in transforms.items():
        strengths = (t or {}).get("strengths")
        if name not in TRANSFORMS:
            raise BadInput(f"experiment.transforms.{name}: unknown transform; choices: {', '.join(TRANSFORMS)}")
        if not isinstance(strengths, list) or not strengths or \
                not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in strengths):
            raise BadInput(f"experiment.transforms.{name}.strengths must be a non-empty list of numbers")
    if s.get("pose_data") not in POSE_DATA:
        raise BadInput(f"experiment.pose_data must be one of {', '.join(POSE_DATA)}, got {s.get('pose_data')!r}")
    s["storage"] = s.get("storage") or f"sqlite:///{(Path.cwd() / DEFAULT_CACHE_DIR / 'optuna.db').resolve()}"
    return s


def job_transforms(settings: Mapping) -> dict:
    """The transforms a trial evaluates, in the form :func:`gtsweep.evaluation.views.views` takes."""
    if settings["objective"] == "pose_success" and settings["pose_data"] == "incremental":
        return {"incremental": {"kind": "pairs"}}
    return {name: {"kind": "synthetic", "strengths": list(t["strengths"]), "params": dict(t.get("params") or {})}
            for name, t in settings["transforms"].items()}


# ------------------------------------------------------------------------------------------------- targets
def build_targets(cfg: Mapping, settings: Mapping) -> list[Target]:
    """One target per selected detector, or per pairing for the pose objective; search spaces checked."""
    from gtsweep.stages.describe import descriptor_params
    from gtsweep.stages.detect import get_detector
    from gtsweep.stages.pairing import applicability

    detectors = plain(cfg.get("detector")) or {}
    if not detectors:
        raise BadInput("experiment=optimize needs at least one detector, e.g. detector=[sift]")
    for name in detectors:
        get_detector(name)
    if settings["objective"] == "repeatability":
        return [_target("detector", name, name, None, detectors[name], detectors[name].get("search_space"),
                        (get_detector(name).count_param or "",)) for name in detectors]
    descriptors = plain(cfg.get("descriptor")) or {}
    pairings = plain(cfg.get("pairings"))
    if not descriptors:
        raise BadInput("objective pose_success needs a descriptor, e.g. descriptor=[sift]")
    if pairings is None:
        pairings = [[next(iter(detectors)), next(iter(descriptors))]]
    targets = []
    for pairing in pairings:
        if not isinstance(pairing, list) or len(pairing) != 2 or pairing[0] not in detectors \
                or pairing[1] not in descriptors:
            raise BadInput(f"pairing {pairing!r} must be [detector, descriptor] from detector={list(detectors)} "
                           f"and descriptor={list(descriptors)}")
        detector, descriptor = pairing
        reason = applicability(detector, descriptor)
        if reason:
            raise BadInput(f"pairing [{detector}, {descriptor}] cannot be evaluated: {reason}")
        node = descriptors[descriptor]
        space = node.get("search_space") or (settings.get("descriptor_search_spaces") or {}).get(descriptor)
        target = _target("descriptor", descriptor, detector, descriptor, node, space, (),
                         defaults=descriptor_params(node, detector))
        target.detector_params = dict(detectors[detector].get("params") or {})
        targets.append(target)
    return targets


def _target(group, name, detector, descriptor, node, space, excluded, defaults=None) -> Target:
    defaults = dict(node.get("params") or {}) if defaults is None else defaults
    distributions = parse_space(f"{group}.{name}.search_space", space, defaults, excluded)
    return Target(group, name, detector, descriptor, node, defaults, dict(space), distributions,
                  dict(node.get("params") or {}) if group == "detector" else {})


def study_name(target: Target, settings: Mapping, fingerprint: str, seed: int, several: bool = False) -> str:
    """``experiment.study_name`` (``-<label>`` appended when several studies run), else
    ``<label>-<objective>-<hash>`` with a hash of everything that determines the scores."""
    if settings.get("study_name"):
        return f"{settings['study_name']}-{target.label}" if several else str(settings["study_name"])
    keys = ("objective", "selector", "min_keypoints", "iou_threshold", "sampler_seed")
    what = {**{k: settings.get(k) for k in keys}, "transforms": job_transforms(settings), "dataset": fingerprint,
            "seed": seed, "space": target.space, "defaults": target.defaults, "detector": target.detector,
            "detector_params": target.detector_params, "descriptor": target.descriptor}
    if settings["objective"] == "pose_success":
        what.update(ratio=settings.get("ratio"), pose=settings.get("pose"))
        if settings.get("mutual"):  # only when on, so that earlier studies keep their names
            what["mutual"] = True
    return f"{target.label}-{settings['objective']}-{config_hash(what)[:10]}"


def job(target: Target, settings: Mapping, values: Mapping, seed: int, cache_dir: str | None) -> dict:
    """The work of one trial for :func:`gtsweep.optimize.objective.evaluate`."""
    tuned = {**target.defaults, **values}
    detector_params = tuned if target.group == "detector" else target.detector_params
    return {"objective": settings["objective"], "detector": target.detector, "detector_params": detector_params,
            "descriptor": target.descriptor, "descriptor_params": tuned if target.group == "descriptor" else {},
            "selector": settings["selector"]["name"], "selector_params": dict(settings["selector"].get("params") or {}),
            "transforms": job_transforms(settings), "seed": seed, "cache_dir": cache_dir,
            "settings": {k: settings.get(k) for k in ("min_keypoints", "iou_threshold", "ratio", "mutual", "pose")}}


# --------------------------------------------------------------------------------------------------- study
def open_study(storage: str, name: str):
    """Create or load the study; trials left RUNNING by a kill become FAIL and their parameters are asked again."""
    import optuna
    from optuna.trial import TrialState

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    warnings.filterwarnings("ignore", category=optuna.exceptions.ExperimentalWarning)
    if storage.startswith("sqlite:///"):
        Path(storage[len("sqlite:///"):]).parent.mkdir(parents=True, exist_ok=True)
    try:
        rdb = optuna.storages.RDBStorage(storage, engine_kwargs={"connect_args": {"timeout": 60}}
                                         if storage.startswith("sqlite") else None)
        study = optuna.create_study(study_name=name, storage=rdb, direction="maximize", load_if_exists=True)
    except Exception as e:  # bad URL, unreachable database
        raise BadInput(f"cannot open the Optuna storage '{storage}': {str(e).strip().splitlines()[0]}") from None
    for trial in study.get_trials(deepcopy=False, states=(TrialState.RUNNING,)):
        study.tell(trial.number, state=TrialState.FAIL)
        if "retry_of" not in trial.user_attrs:  # a trial that was itself retried may have crashed the process
            study.enqueue_trial(trial.params, user_attrs={"retry_of": trial.number})
    return study


def _complete(study) -> list:
    from optuna.trial import TrialState

    return study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))


def _batches(trials: list, shards, jobs: list[dict], runner_cfg: Mapping):
    """``(trial, result)`` as each trial's evaluation finishes: in-process, or as Ray tasks in parallel."""
    if runner_cfg.get("backend", "ray") == "serial":
        for trial, work in zip(trials, jobs):
            yield trial, evaluate(shards, work)
        return
    import ray

    remote = ray.remote(num_cpus=1, max_retries=0)(evaluate)
    pending = {remote.remote(shards, work): trial for trial, work in zip(trials, jobs)}
    while pending:
        done, _ = ray.wait(list(pending), num_returns=1)
        trial = pending.pop(done[0])
        try:
            result = ray.get(done[0])
        except Exception as e:  # a crashed worker: the trial fails, the study goes on
            result = {"error": f"Ray task failed: {str(e).strip().splitlines()[0]}"}
        yield trial, result


def optimise(study, target: Target, settings: Mapping, shards, runner_cfg: Mapping, seed: int,
             cache_dir: str | None, on_trial=None) -> dict:
    """Run trials until ``n_trials`` are complete; returns counts for the summary."""
    import optuna

    n_trials, parallel = settings["n_trials"], settings["parallel_trials"]
    if settings.get("enqueue_defaults", True) and not study.trials:
        start = defaults_in_space(target.distributions, target.defaults)
        if start is not None:  # the defaults are trial 0: the tuned result is never worse on these images
            study.enqueue_trial(start, user_attrs={"defaults": True})
    new = failed = 0
    last_error = ""
    while (done := len(_complete(study))) < n_trials:
        study.sampler = optuna.samplers.TPESampler(seed=stable_seed(settings["sampler_seed"], done),
                                                   n_startup_trials=settings["n_startup_trials"])
        trials = [study.ask(target.distributions) for _ in range(min(parallel, n_trials - done))]
        jobs = [job(target, settings, t.params, seed, cache_dir) for t in trials]
        for trial, result in _batches(trials, shards, jobs, runner_cfg):
            if "metrics" in result:
                trial.set_user_attr("metrics", result["metrics"])
                frozen = study.tell(trial, result["metrics"]["score"])
                new += 1
            else:
                trial.set_user_attr("error", result["error"])
                frozen = study.tell(trial, state=optuna.trial.TrialState.FAIL)
                failed, last_error = failed + 1, result["error"]
            if on_trial is not None:
                on_trial(frozen)
        if failed > max(n_trials, parallel):
            raise GtsweepError(f"{target.label}: {failed} trials failed; the last: {last_error}")
    return {"new": new, "failed": failed}


# -------------------------------------------------------------------------------------------------- output
def tuned_node(target: Target, values: Mapping) -> dict:
    """The tuned method's config: its config with the best values merged into ``params``."""
    node = json.loads(json.dumps(target.node))
    node["params"] = {**(node.get("params") or {}), **values}
    per_detector = (node.get("per_detector") or {}).get(target.detector)
    if per_detector:  # the tuned values must not be overridden for the detector they were tuned on
        node["per_detector"][target.detector] = {k: v for k, v in per_detector.items() if k not in values}
    return node


def write_tuned(path: Path, target: Target, values: Mapping, header: list[str]) -> Path:
    """``<name>: {params: ...}`` with a Hydra package header, loadable as ``<group>=[tuned/<name>]``."""
    import yaml

    node = tuned_node(target, values)
    space = node.pop("search_space", None)
    body = yaml.safe_dump({target.name: node}, sort_keys=False, default_flow_style=False)
    if space:  # kept, so that the tuned config can be tuned further; one flow-style line per parameter
        body += "  search_space:\n" + "".join(
            f"    {yaml.safe_dump({k: v}, default_flow_style=True, sort_keys=False).strip()[1:-1]}\n"
            for k, v in space.items())
    lines = [f"# @package {target.group}", *[f"# {line}" for line in header]]
    write_atomically(path, "\n".join(lines) + "\n" + body)  # presets select it: never half-written
    return path


def describe_best(best, settings: Mapping) -> str:
    """The best trial's objective in words (score and what it is made of)."""
    m = best.user_attrs.get("metrics", {})
    if settings["objective"] == "repeatability":
        return (f"score {best.value:.4f} = repeatability {m.get('repeatability', float('nan')):.4f} - "
                f"{int(m.get('n_few', 0))} of {int(m.get('n_views', 0))} views with < {settings['min_keypoints']} "
                f"keypoints")
    return f"pose success {best.value:.4f} (precision {m.get('precision', float('nan')):.4f})"


def load_shards(dataset, settings: Mapping) -> dict:
    """The optimisation images (and, for ``pose_data: incremental``, the incremental pairs) as shards."""
    items = [{"id": s.id, "texture": s.texture, "image": s.load()} for s in dataset.images("optimisation")]
    if not items:
        raise BadInput(f"data set '{dataset.name}' has no optimisation images (dataset.n_optimisation?)")
    shards = {"synthetic": make_shard("synthetic", items)}
    if settings["objective"] == "pose_success" and settings["pose_data"] == "incremental":
        pairs = [{"id": p.id, "texture": p.texture, "reference": p.reference.load(), "test": p.test.load(),
                  "H": p.H} for p in dataset.pairs("incremental")]
        shards["pairs"] = make_shard("pairs", pairs)
    return shards


def main(cfg, output_dir: str | Path) -> list[dict]:
    """Optimise every target of ``cfg``; print a summary per study; return the summaries."""
    from omegaconf import OmegaConf

    from gtsweep.datasets import load_dataset
    from gtsweep.tracking.study import StudyTracker

    output_dir = Path(output_dir)
    settings = read_settings(cfg)
    runner_cfg = plain(cfg.get("runner")) or {}
    if runner_cfg.get("backend", "ray") not in ("ray", "serial"):
        raise BadInput(f"runner.backend must be ray or serial, got {runner_cfg.get('backend')!r}")
    targets = build_targets(cfg, settings)
    seed = int(cfg.get("seed", 0))
    cache_cfg = plain(cfg.get("cache")) or {}
    cache_dir = str(Path(cache_cfg["dir"]).resolve()) if cache_cfg.get("enabled", True) else None
    dataset = load_dataset(cfg["dataset"])
    fingerprint = dataset.fingerprint()
    shards = load_shards(dataset, settings)
    if runner_cfg.get("backend", "ray") == "ray":
        import ray

        from gtsweep.orchestration.cluster import connect

        connect(runner_cfg)
        shards = ray.put(shards)  # once for all trials of all studies
    root = Path(settings.get("tuned_root") or CONF_DIR)
    mlflow_cfg = plain(cfg.get("mlflow")) or {}
    summaries = []
    for target in targets:
        start = time.perf_counter()
        name = study_name(target, settings, fingerprint, seed, several=len(targets) > 1)
        study = open_study(settings["storage"], name)
        tracker = None
        if mlflow_cfg.get("enabled", True):
            tracker = StudyTracker(mlflow_cfg, study, target, settings, fingerprint,
                                   OmegaConf.to_yaml(cfg, resolve=True))
        try:
            counts = optimise(study, target, settings, shards, runner_cfg, seed, cache_dir,
                              on_trial=tracker.log_trial if tracker else None)
            best = study.best_trial
        except BaseException:
            if tracker is not None:
                tracker.end(study, [], status="FAILED")
            raise
        header = [f"Tuned by gtsweep experiment=optimize on {time.strftime('%Y-%m-%d %H:%M:%S')}: study '{name}'",
                  f"({settings['storage']}), best of {len(_complete(study))} complete trials: trial {best.number},",
                  f"objective {settings['objective']}: {describe_best(best, settings)}.",
                  f"Data set fingerprint {fingerprint}." + (f" Tuned on {target.detector} keypoints."
                                                             if target.group == "descriptor" else ""),
                  f"Use it: python -m gtsweep {target.group}=[tuned/{target.name}]"]
        path = write_tuned(root / target.group / "tuned" / f"{target.name}.yaml", target, best.params, header)
        copy = write_tuned(output_dir / "tuned" / target.group / f"{target.name}.yaml", target, best.params, header)
        if tracker is not None:
            tracker.end(study, [copy])
        summary = {"target": target.label, "group": target.group, "study": name, "storage": settings["storage"],
                   "best_trial": best.number, "best_value": best.value, "best_params": best.params,
                   "best": describe_best(best, settings),
                   "metrics": best.user_attrs.get("metrics", {}), "complete": len(_complete(study)),
                   "new": counts["new"], "failed": counts["failed"], "tuned_config": str(path),
                   "mlflow_run": tracker.parent_id if tracker else None, "seconds": time.perf_counter() - start}
        summaries.append(summary)
        print(format_summary(summary, settings))
    (output_dir / "optimize.json").write_text(json.dumps(summaries, indent=1, default=str))
    return summaries


def format_summary(s: Mapping, settings: Mapping) -> str:
    params = ", ".join(f"{k}={v:.6g}" if isinstance(v, float) else f"{k}={v}" for k, v in s["best_params"].items())
    lines = [f"gtsweep optimize: {s['target']} — study {s['study']} ({s['complete']} complete trials, {s['new']} "
             f"new, {s['failed']} failed, {s['seconds']:.1f} s)",
             f"  best: trial {s['best_trial']}, {s['best']}",
             f"  params: {params}",
             f"  tuned config: {s['tuned_config']} (use: {s['group']}=[tuned/{s['target'].split('+')[-1]}])"]
    if s.get("mlflow_run"):
        lines.append(f"  MLflow: study run {s['mlflow_run']}, one child run per trial")
    return "\n".join(lines)
