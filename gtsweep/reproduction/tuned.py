"""Which detector parameters a reproduction ran with: the tuned files' data set fingerprints and digest."""
from __future__ import annotations

import hashlib
import re
from pathlib import Path

from gtsweep.core.paths import CONF_DIR

TUNED = CONF_DIR / "detector" / "tuned"
#: ``make tune``'s data set: dataset=survey with its optimisation views only.
TUNING_DATA = {"n_synthetic": 0, "n_incremental": 0, "n_absolute": 0}


def tuning_fingerprint() -> str:
    """The fingerprint of the data set ``make tune`` tunes on (dataset=survey, optimisation views only)."""
    import yaml

    from gtsweep.datasets import load_dataset

    options = yaml.safe_load((CONF_DIR / "dataset" / "survey.yaml").read_text())
    return load_dataset({**options, **TUNING_DATA}).fingerprint()


def tuned_fingerprints(directory: Path = TUNED) -> dict[str, str]:
    """Each tuned detector file's data set fingerprint, from its header ("Data set fingerprint X.")."""
    found = {}
    for path in sorted(Path(directory).glob("*.yaml")):
        match = re.search(r"Data set fingerprint ([0-9a-f]+)", path.read_text())
        found[path.stem] = match.group(1) if match else "none"
    return found


def tuned_line(expected: str | None, directory: Path = TUNED) -> str:
    """What the document states about the detectors' tuned parameters: on which data set they were tuned."""
    found = tuned_fingerprints(directory)
    if expected is None:
        return ""
    stale = {k: v for k, v in found.items() if v != expected}
    if not stale:
        return (f"Detector parameters: all {len(found)} tuned files were tuned on this data set's optimisation "
                f"views (fingerprint {expected}).")
    by = {}
    for name, fingerprint in stale.items():
        by.setdefault(fingerprint, []).append(name)
    which = "; ".join(f"{', '.join(names)} on {fp}" for fp, names in by.items())
    return (f"**Detector parameters not tuned on this data set**: {len(stale)} of {len(found)} tuned files carry "
            f"another data set's fingerprint ({which}); `make tune` on dataset=survey's optimisation views "
            f"(fingerprint {expected}) re-tunes them.")


def tuned_digest(directory: Path = TUNED) -> str:
    """A digest of the tuned detector files: a reproduction resumed after re-tuning would mix parameters."""
    digest = hashlib.sha256()
    for path in sorted(Path(directory).glob("*.yaml")):
        digest.update(path.name.encode() + b"\0" + path.read_bytes())
    return digest.hexdigest()[:16]
