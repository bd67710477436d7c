"""The reproduction's portable state: its per-view rows and their records, committed in the repository.

Layout of the state folder (``docs/reproduction/state/``, append-only: each chunk of work adds two files, no file
is rewritten)::

    plan.json                 what the run is (presets, level, tuned parameters' and amended design's digests,
                              the library versions that enter the reuse keys), written once
    chunks/<name>.json        one chunk's record: its preset, the window of images or pairs, each cell's methods,
                              status and reuse key, every item's fingerprint, its wall time and peak memory
    chunks/<name>.parquet     its per-view rows (zstd; timings in float32), each (cell, image or pair) once

The rows of a cell are the union of its chunks' rows in the data set's order (texture, then image or pair number),
so a cell read from the state equals the cell a single run at its count writes (``tests/test_reproduction_state.py``).
Paths in the records are relative to the repository; nothing refers to the machine that computed them.
"""
from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from gtsweep.core.atomic import write_atomically
from gtsweep.core.errors import BadInput
from gtsweep.core.paths import PROJECT_DIR
from gtsweep.orchestration.results import summarize
from gtsweep.reproduction import task_costs
from gtsweep.reproduction.task_costs import TIMINGS

STATE_DIR = PROJECT_DIR / "docs" / "reproduction" / "state"
CELL = "cell"  # the rows' column naming their cell


#: An image or pair id's number: its last run of digits.
ITEM_NUMBER = r"(\d+)\D*$"


def item_number(item: str) -> int:
    """The number of an image or pair id (``texture/split/007`` -> 7)."""
    return int(re.search(ITEM_NUMBER, str(item))[1])


def item_numbers(items: pd.Series) -> pd.Series:
    """:func:`item_number` of each id, at once."""
    return items.str.extract(ITEM_NUMBER, expand=False).astype(np.int64)


@dataclass
class Cell:
    """One cell of a preset as the state holds it: its record and its rows (every chunk's, in order)."""

    key: str
    record: dict
    rows: list = field(default_factory=list)
    #: frames already assembled, by (textures, limit): every look, table and count reads the same few
    _frames: dict = field(default_factory=dict, repr=False)
    #: summaries already made, by (textures, the frame's rows): a limit beyond the cell's last item changes nothing
    _summaries: dict = field(default_factory=dict, repr=False)

    def frame(self, textures: list[str], limit: int | None = None) -> pd.DataFrame:
        """The cell's rows in the data set's order; ``limit``: only images or pairs numbered below it (a look of
        an earlier round, taken on the prefix it read). Read it, do not change it: it is shared."""
        key = (tuple(textures), limit)
        if key not in self._frames:
            self._frames[key] = self._assemble(textures, limit)
        return self._frames[key]

    def _assemble(self, textures: list[str], limit: int | None) -> pd.DataFrame:
        if not self.rows:
            return pd.DataFrame()
        rows = pd.concat(self.rows, ignore_index=True)
        numbers = item_numbers(rows["image"])
        if limit is not None:
            rows, numbers = rows[numbers < limit], numbers[numbers < limit]
        rank = rows["texture"].map({t: i for i, t in enumerate(textures)})
        order = np.lexsort((numbers.to_numpy(), rank.to_numpy()))
        rows = rows.iloc[order].reset_index(drop=True)
        columns = self.record.get("columns") or list(rows.columns)
        return rows.reindex(columns=columns).astype({c: "float64" for c in TIMINGS if c in columns})

    def summary(self, textures: list[str], limit: int | None = None) -> dict:
        """The cell's summary as a sweep writes it (``cells/<cell>.json``), from its rows up to ``limit``."""
        head = {"key": self.key, **{k: self.record[k] for k in ("methods", "experiment", "status", "reason")
                                    if k in self.record}}
        rows = self.frame(textures, limit)
        if self.record["status"] != "ok" or rows.empty:
            return {**head, "n_rows": int(len(rows))}
        key = (tuple(textures), len(rows))  # a prefix of the same ordered rows: its length names it
        if key not in self._summaries:
            self._summaries[key] = summarize(rows.drop(columns=["transform"], errors="ignore"),
                                             self.record["experiment"])
        return {**head, **self._summaries[key]}


@dataclass
class State:
    """Every preset's cells, read from the state folder."""

    plan: dict
    chunks: list[dict]
    presets: dict[str, dict[str, Cell]]

    def textures(self) -> list[str]:
        return list(self.plan["textures"])

    def summaries(self, preset: str, limit: int | None = None) -> list[dict]:
        return [c.summary(self.textures(), limit) for _, c in sorted(self.presets.get(preset, {}).items())]

    def views(self, preset: str, limit: int | None = None) -> dict[str, pd.DataFrame]:
        found = {k: c.frame(self.textures(), limit) for k, c in sorted(self.presets.get(preset, {}).items())}
        return {k: v for k, v in found.items() if len(v)}

    def reached(self, preset: str) -> int:
        """The count per texture the preset's rows reach: one past the largest image or pair number of any cell."""
        numbers = [int(item_numbers(r["image"]).max()) for c in self.presets.get(preset, {}).values()
                   for r in c.rows if len(r)]
        return max(numbers, default=-1) + 1

    def fingerprints(self) -> dict[str, str | None]:
        """Every recorded image's or pair's fingerprint, as the first chunk that computed it recorded it."""
        found: dict[str, str | None] = {}
        for chunk in self.chunks:
            for item, fingerprint in chunk.get("items", {}).items():
                found.setdefault(item, fingerprint)
        return found

    def covered(self, preset: str, key: str) -> set[str]:
        """The images or pairs a cell's rows cover."""
        cell = self.presets.get(preset, {}).get(key)
        return set().union(*(set(r["image"].astype(str)) for r in cell.rows)) if cell and cell.rows else set()


def write_plan(folder: Path, plan: dict) -> None:
    """The plan, written once; a different plan already there is refused in one line."""
    path = Path(folder) / "plan.json"
    if path.exists():
        held = json.loads(path.read_text())
        if held != plan:
            differs = ", ".join(sorted(k for k in set(held) | set(plan) if held.get(k) != plan.get(k)))
            raise BadInput(f"the reproduction's state in {folder} is of another plan (differs in: {differs})")
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    write_atomically(path, json.dumps(plan, indent=1, sort_keys=True) + "\n")


def read_plan(folder: Path) -> dict | None:
    path = Path(folder) / "plan.json"
    return json.loads(path.read_text()) if path.exists() else None


def next_name(folder: Path, label: str) -> str:
    """The next chunk's file name: a running number and a label (``0007-table3_detectors``)."""
    names = sorted(p.stem for p in (Path(folder) / "chunks").glob("*.json"))
    number = int(names[-1].split("-", 1)[0]) + 1 if names else 1
    return f"{number:04d}-{re.sub(r'[^A-Za-z0-9_.-]+', '_', label)}"


def write_chunk(folder: Path, label: str, record: dict, rows: pd.DataFrame) -> str:
    """Add one chunk: its rows (zstd parquet, timings as float32), then its record (the completion marker)."""
    chunks = Path(folder) / "chunks"
    chunks.mkdir(parents=True, exist_ok=True)
    name = next_name(folder, label)
    rows = rows.astype({c: "float32" for c in TIMINGS if c in rows})
    temporary = chunks / f".{name}.parquet.part"
    rows.to_parquet(temporary, compression="zstd", index=False)
    temporary.replace(chunks / f"{name}.parquet")
    write_atomically(chunks / f"{name}.json", json.dumps(record, indent=1, sort_keys=True) + "\n")
    return name


def chunk_records(folder: Path) -> list[dict]:
    """Every finished chunk's record, in order (no rows read)."""
    return [{**json.loads(p.read_text()), "name": p.stem} for p in sorted((Path(folder) / "chunks").glob("*.json"))]


def cell_records(folder: Path) -> dict[str, dict[str, dict]]:
    """Per preset, each cell's record as the chunks hold it (its first chunk's; no rows read)."""
    found: dict[str, dict[str, dict]] = {}
    for record in chunk_records(folder):
        for key, meta in record["cells"].items():
            found.setdefault(record["preset"], {}).setdefault(key, meta)
    return found


def load(folder: Path = STATE_DIR) -> State:
    """The state in ``folder``: its plan and every finished chunk's cells and rows (a chunk whose record is missing,
    one cut while it was written, is ignored)."""
    folder = Path(folder)
    plan = read_plan(folder)
    if plan is None:
        raise BadInput(f"no reproduction state in {folder} (missing plan.json)")
    chunks, presets, paid = [], {}, set()
    for record in chunk_records(folder):
        path = folder / "chunks" / f"{record['name']}.json"
        rows = pd.read_parquet(path.with_suffix(".parquet"))
        chunks.append({**record, "task_s": task_seconds(record, rows, paid)})
        by_cell = dict(tuple(rows.groupby(CELL, sort=False))) if len(rows) else {}
        for key, meta in record["cells"].items():
            cell = presets.setdefault(record["preset"], {}).setdefault(key, Cell(key, meta))
            _check_same(cell, meta, path)
            if meta["status"] != "ok":
                cell.record = {**cell.record, "status": meta["status"], "reason": meta.get("reason")}
            if key in by_cell:
                cell.rows.append(by_cell[key].drop(columns=[CELL]))
    return State(plan, chunks, presets)


def task_seconds(record: dict, rows: pd.DataFrame, paid: set | None = None) -> float:
    """The chunk's recorded task CPU-seconds (detection, description, matching, pose; :mod:`task_costs`).
    ``paid``: the (detector, view) detections of earlier chunks, which this chunk took from the keypoint cache
    (not counted again); its own are added to it."""
    if rows.empty:
        return 0.0
    methods = pd.DataFrame([record["cells"][k]["methods"] for k in rows[CELL]], index=rows.index)
    frame = pd.concat([rows.drop(columns=[CELL]), methods.drop(columns=[c for c in methods if c in rows])], axis=1)
    frame = frame.astype({c: "float64" for c in TIMINGS if c in frame})
    seconds = task_costs.work_seconds(frame, paid)
    if paid is not None:
        paid.update(zip(frame["detector"], frame["view"]))
    return float(sum(seconds.values()))


def _check_same(cell: Cell, meta: dict, path: Path) -> None:
    if cell.record.get("reuse_key") != meta.get("reuse_key"):
        raise BadInput(f"{path.name}: cell {cell.key} was computed with another configuration than in an earlier "
                       f"chunk (reuse key {meta.get('reuse_key')} vs {cell.record.get('reuse_key')})")


def restore(state: State, work: Path) -> list[Path]:
    """Write each preset's cells as a sweep's output directory (``work/<preset>/cells``, ``reuse``) from the
    state: what the sweeps of a resumed run and the report read."""
    from gtsweep.orchestration.results import ResultStore

    written, fingerprints = [], state.fingerprints()
    for preset, cells in state.presets.items():
        store = ResultStore(Path(work) / preset)
        for key, cell in sorted(cells.items()):
            rows = cell.frame(state.textures())
            items = {i: fingerprints.get(i) for i in state.covered(preset, key)}
            store.write_cell(key, cell.summary(state.textures()), rows if len(rows) else None,
                             {"reuse_key": cell.record.get("reuse_key"), "items": items})
        written.append(store.directory)
    return written


def size_mb(folder: Path = STATE_DIR) -> float:
    return sum(p.stat().st_size for p in Path(folder).rglob("*") if p.is_file()) / 2**20
