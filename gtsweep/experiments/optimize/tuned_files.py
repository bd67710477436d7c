"""What a study leaves behind: the tuned config (``./tuned/<group>/tuned/<name>.yaml`` by default, loadable as
``<group>=[tuned/<name>]``) and its summary."""
from __future__ import annotations

import json
import os
import time
from pathlib import Path
from typing import Mapping

from gtsweep.core.atomic import write_atomically
from gtsweep.experiments.optimize.targets import Target


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
    if "factory" not in node:  # a method of the code: its values typed by its schema (gtsweep.orchestration.schemas)
        lines.append(f"defaults: [/schema/{target.group}/{target.name}@_here_, _self_]")
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


def storage_label(storage: str) -> str:
    """The study's storage as a tuned config's header names it: no path of this machine (a SQLite file relative
    to the working directory, or by its name only), no password."""
    if not storage.startswith("sqlite:///"):
        from gtsweep.tracking.study import safe_storage

        return safe_storage(storage)
    path = storage[len("sqlite:///"):]
    if not os.path.isabs(path):
        return storage
    relative = os.path.relpath(path)
    return f"sqlite:///{relative if not relative.startswith('..') else os.path.basename(path)}"


def stop_reason(complete: int, settings: Mapping) -> str:
    """Why the study stopped (:mod:`gtsweep.experiments.optimize.stopping`): its best settled, or the trial maximum."""
    patience, gain = settings.get("patience"), settings.get("min_improvement") or 0
    if patience and complete < settings["n_trials"]:
        return f"stopped: no gain > {gain:g} in the last {patience} trials"
    return f"stopped: n_trials = {settings['n_trials']} reached" + (f" (patience {patience})" if patience else "")


def tuned_header(target: Target, settings: Mapping, name: str, best, complete: int, fingerprint: str,
                 defaults=None) -> list[str]:
    """The comment lines on top of a tuned config: which study, which trial, on what data, why it stopped, and
    the defaults' own score (``defaults``: the study's enqueued trial of the method's default parameters)."""
    lines = [f"Tuned by gtsweep experiment=optimize on {time.strftime('%Y-%m-%d %H:%M:%S')}: study '{name}'",
             f"({storage_label(settings['storage'])}), best of {complete} complete trials: trial {best.number},",
             f"objective {settings['objective']}: {describe_best(best, settings)}; {stop_reason(complete, settings)}.",
             f"Data set fingerprint {fingerprint}." + (f" Tuned on {target.detector} keypoints."
                                                        if target.group == "descriptor" else "")]
    if defaults is not None:
        lines.append(f"Defaults (trial {defaults.number}): {describe_best(defaults, settings)}.")
    if settings.get("selector") and target.group == "detector":
        lines.append(f"Selector: {settings['selector']['name']} to n = "
                     f"{(settings['selector'].get('params') or {}).get('n', 1000)}.")
    return [*lines, f"Use it: python -m gtsweep {target.group}=[tuned/{target.name}]"]


def defaults_trial(trials):
    """The complete trial of the default parameters (enqueued as trial 0), or None."""
    return next((t for t in trials if t.user_attrs.get("defaults") and t.value is not None), None)


def format_summary(s: Mapping, settings: Mapping) -> str:
    """A study's summary as printed after it."""
    params = ", ".join(f"{k}={v:.6g}" if isinstance(v, float) else f"{k}={v}" for k, v in s["best_params"].items())
    lines = [f"gtsweep optimize: {s['target']} — study {s['study']} ({s['complete']} complete trials, {s['new']} "
             f"new, {s['failed']} failed, {s['seconds']:.1f} s)",
             f"  best: trial {s['best_trial']}, {s['best']}",
             f"  params: {params}",
             f"  tuned config: {s['tuned_config']} (use: {s['group']}=[tuned/{s['target'].split('+')[-1]}])"]
    if s.get("mlflow_run"):
        lines.append(f"  MLflow: study run {s['mlflow_run']}, one child run per trial")
    return "\n".join(lines)
