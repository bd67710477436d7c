"""What a run logs as MLflow params, so that every dimension of a sweep filters in the UI and in ``search_runs``.

- A sweep's (parent) run: the composed config, flattened (``dataset.n_incremental``, ``detector.sift.params.sigma``),
  and the data set's fingerprint (``dataset.fingerprint``).
- A cell's (child) run: each method as the user selected it (``detector = tuned/sift``, not the registry name
  ``sift``: the name is the tag ``gtsweep.method.detector``), the seed, the data set (its name, its top-level
  settings and its fingerprint), and every method's configuration (``detector.params.contrastThreshold``).

``params.seed = '1'``, ``params.detector = 'tuned/sift'`` or ``params.`dataset.name` = 'microgps'`` then find the
runs. Where a method came from is read from Hydra's defaults list of the running job (:func:`written_options`);
outside a Hydra job (scripts, tests) the registry names are what was written.
"""
from __future__ import annotations

from typing import Iterable, Iterator, Mapping

import yaml

from gtsweep.core.config import METHOD_GROUPS
from gtsweep.tracking.store import flatten

#: The tag that keeps a method's registry name when the param holds the option as written (``tuned/sift``).
METHOD_TAG = "gtsweep.method."
FINGERPRINT = "dataset.fingerprint"
#: Data-set settings that say where files are kept, not which data: left out of a cell's params.
DATASET_PLUMBING = ("cache_dir",)
#: The method configurations a cell logs (``<group>.params.<name>``), besides the method names.
CONFIGURED = (*METHOD_GROUPS, "experiment")
#: MLflow accepts at most 100 params (and 100 tags) per ``log_batch`` call.
MAX_PER_BATCH = 100
MAX_KEY, MAX_VALUE = 250, 6000


def parsed_config(config_yaml: str) -> dict:
    """The composed config a sweep logs as ``config.yaml`` (a mapping; anything else reads as empty)."""
    try:
        config = yaml.safe_load(config_yaml)
    except yaml.YAMLError:
        return {}
    return config if isinstance(config, dict) else {}


def config_params(config: Mapping, fingerprint: str) -> dict[str, str]:
    """A sweep's params: its composed config, flattened, and the data set's fingerprint."""
    return {**flatten(config), FINGERPRINT: fingerprint}


def dataset_params(config: Mapping, fingerprint: str) -> dict[str, str]:
    """The data set of a cell: its name (``dataset``, as the methods: the sweep's run has ``dataset.name`` from its
    config only), its top-level settings (loader, root, sizes, counts, seed; not the nested laws of its pose
    generator, which the fingerprint covers) and its fingerprint."""
    dataset = config.get("dataset") or {}
    settings = {k: v for k, v in dataset.items() if not isinstance(v, Mapping) and k not in DATASET_PLUMBING}
    named = {"dataset": str(dataset["name"])} if dataset.get("name") is not None else {}
    return {**named, **flatten({"dataset": settings}), FINGERPRINT: fingerprint}


def cell_params(cell, method_config: Mapping, config: Mapping, fingerprint: str,
                written: Mapping[str, Mapping[str, str]]) -> dict[str, str]:
    """A cell's params: its methods as written (``tuned/sift``), the seed, the data set, the methods' configs.

    ``method_config`` is the cell's configuration (:meth:`gtsweep.orchestration.grid.MethodGrid.cell_config`),
    ``config`` the sweep's composed config, ``written`` :func:`written_options`.
    """
    params = {group: as_written(written, group, name) for group, name in cell.methods.items() if name is not None}
    if config.get("seed") is not None:
        params["seed"] = str(config["seed"])
    params.update(dataset_params(config, fingerprint))
    params.update(flatten({k: method_config[k] for k in CONFIGURED if method_config.get(k) is not None}))
    return params


def method_tags(cell) -> dict[str, str]:
    """The registry name of each of a cell's methods (``gtsweep.method.detector = sift``)."""
    return {METHOD_TAG + group: name for group, name in cell.methods.items() if name is not None}


def as_written(written: Mapping[str, Mapping[str, str]], group: str, name: str) -> str:
    return (written.get(group) or {}).get(name, name)


def options_by_name(loaded: Iterable[tuple[str, str]]) -> dict[str, dict[str, str]]:
    """``{group: {name: option}}`` from the ``(package, config path)`` of the config files a job loaded:
    ``("detector", "detector/tuned/sift")`` -> ``{"detector": {"sift": "tuned/sift"}}``. A method file is keyed
    by its own name in its group's package, so the file loaded last for a name is the one in the config."""
    written: dict[str, dict[str, str]] = {}
    for package, path in loaded:
        group, _, option = path.partition("/")
        if package == group and option and group != "hydra":  # Hydra's own configs are no method
            written.setdefault(group, {})[option.split("/")[-1]] = option
    return written


def written_options() -> dict[str, dict[str, str]]:
    """:func:`options_by_name` of the running Hydra job (Hydra's defaults list: its ``runtime.choices`` leave out
    the groups that take a list); {} outside a Hydra job."""
    from hydra.core.global_hydra import GlobalHydra
    from hydra.core.hydra_config import HydraConfig
    from hydra.types import RunMode

    if not HydraConfig.initialized() or not GlobalHydra.instance().is_initialized():
        return {}
    job = HydraConfig.get()
    try:
        defaults = GlobalHydra.instance().config_loader().compute_defaults_list(
            job.job.config_name, list(job.overrides.task), RunMode.RUN)
    except Exception:  # the job composed already; a defaults list that cannot be rebuilt only loses the names
        return {}
    # A method file with a defaults list (its schema first) is listed as its own ``_self_`` entry: kept.
    return options_by_name((d.package or "", d.config_path) for d in defaults.defaults if d.config_path)


def batches(params: Mapping[str, str], size: int = MAX_PER_BATCH) -> Iterator[list]:
    """``params`` as MLflow ``Param`` lists of at most ``size`` (keys and values cut to MLflow's limits)."""
    from mlflow.entities import Param

    items = [Param(k[:MAX_KEY], str(v)[:MAX_VALUE]) for k, v in params.items()]
    for start in range(0, len(items), size):
        yield items[start:start + size]
