"""What a reproduction has finished so far, saved after every preset run, so that the same command resumes an
interrupted one (a reproduction at the survey's counts runs for hours: longer than one sitting).

The record (``progress.json`` in the reproduction's work directory) holds the *plan* (size, presets, level, the
tuned parameters' digest: a resume must run the same reproduction), every finished preset run's measurements,
and the attempts cut short. A resumed run is a sweep started again in the same output directory: the sweep keeps
its finished cells (``gtsweep.orchestration.skeleton``), and the keypoint cache its detections. The wall time of a
run includes its interrupted attempts: an attempt ended by a signal says when; one killed outright (``kill -9``,
a lost machine, a session that ends) is taken to have ended at its last sign of life: the newest of its heartbeat
(``alive``, saved every minute while it runs) and the last write in its output.
"""
from __future__ import annotations

import json
import os
import shutil
import threading
import time
from pathlib import Path
from typing import Callable

from gtsweep.core.atomic import write_atomically
from gtsweep.core.errors import BadInput


class RunRecord:
    """The finished preset runs of one reproduction (``plan``) and its interrupted attempts, kept in ``path``."""

    def __init__(self, path: Path, plan: dict, clock: Callable[[], float] = time.time, heartbeat_s: float = 60.0):
        self.path, self.plan, self.clock, self.heartbeat_s = Path(path), plan, clock, heartbeat_s
        self.finished: dict[str, dict] = {}  # key -> the run's measurements
        # key -> {"output", "started", "ended" (None: killed), "alive" (its last heartbeat), "earlier_s" (its cut
        # attempts before), "tries"}
        self.attempts: dict[str, dict] = {}
        self._saving = threading.Lock()

    @classmethod
    def resume(cls, path: Path, plan: dict, clock: Callable[[], float] = time.time,
               heartbeat_s: float = 60.0) -> RunRecord:
        """The record at ``path`` when it is of the same ``plan``; a new one when there is none. Another plan's
        record is refused (:class:`BadInput`): resuming it would mix two reproductions."""
        record = cls(path, plan, clock, heartbeat_s)
        if not record.path.exists():
            return record
        try:
            saved = json.loads(record.path.read_text())
            finished, attempts, their_plan = saved["finished"], saved["attempts"], saved["plan"]
        except (OSError, ValueError, KeyError, TypeError) as e:
            raise BadInput(f"cannot read the unfinished reproduction's record {record.path} ({e}); "
                           f"pass --fresh to start again") from None
        if their_plan != plan:
            differs = ", ".join(f"{k} {their_plan.get(k)!r} (now {plan.get(k)!r})" for k in sorted(plan)
                                if their_plan.get(k) != plan.get(k))
            raise BadInput(f"{record.path.parent} holds an unfinished reproduction of another plan: {differs}; "
                           f"run it as before to resume it, or pass --fresh to discard it")
        record.finished = {k: {**r, "output": Path(r["output"])} for k, r in finished.items()}
        record.attempts = attempts
        return record

    def __len__(self) -> int:
        return len(self.finished)

    def get(self, key: str) -> dict | None:
        """The measurements of the finished run ``key`` (e.g. ``round2/table4_incremental``), else None."""
        return self.finished.get(key)

    def run(self, key: str, output: Path, start: Callable[[], dict]) -> dict:
        """``start()`` (one preset run writing to ``output``), recorded: its measurements, with the wall time of
        its earlier interrupted attempts added and their number (``attempts``)."""
        earlier = self.attempts.get(key)
        earlier_s = 0.0 if earlier is None else earlier["earlier_s"] + self._attempt_seconds(earlier)
        tries = 1 if earlier is None else earlier["tries"] + 1
        now = self.clock()
        self.attempts[key] = {"output": str(output), "started": now, "ended": None, "alive": now,
                              "earlier_s": earlier_s, "tries": tries}
        self.save()
        stop = threading.Event()
        beating = threading.Thread(target=self._beat, args=(key, stop), daemon=True, name="run-record-heartbeat")
        beating.start()
        try:
            result = start()
        except BaseException:
            self.attempts[key]["ended"] = self.clock()
            raise
        finally:
            stop.set()
            beating.join(timeout=5)  # a save hung on a lost disk must not hold the run
            self.save()
        result = {**result, "wall_s": result["wall_s"] + earlier_s, "attempts": tries}
        del self.attempts[key]
        self.finished[key] = result
        self.save()
        return result

    def interrupted_seconds(self) -> float:
        """Seconds spent in attempts not (yet) finished."""
        return sum(a["earlier_s"] + self._attempt_seconds(a) for a in self.attempts.values())

    def _attempt_seconds(self, attempt: dict) -> float:
        ended = attempt["ended"]
        if ended is None:  # killed outright: its last sign of life
            ended = max(attempt.get("alive") or 0.0, last_write(Path(attempt["output"])) or 0.0)
        return max(0.0, ended - attempt["started"]) if ended else 0.0

    def _beat(self, key: str, stop: threading.Event) -> None:
        """Save ``key``'s attempt as alive every ``heartbeat_s`` until ``stop``."""
        while not stop.wait(self.heartbeat_s):
            self.attempts[key]["alive"] = self.clock()
            try:
                self.save()
            except Exception:  # a full or lost disk: the run itself reports what it cannot write
                pass

    def save(self) -> None:
        with self._saving:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            write_atomically(self.path, json.dumps({"plan": self.plan, "finished": self.finished,
                                                    "attempts": self.attempts}, default=str, indent=1))


def last_write(directory: Path) -> float | None:
    """The newest modification time of any file in ``directory`` and of its log beside it (``<name>.log``)."""
    times = [p.stat().st_mtime for p in [*Path(directory).rglob("*"), Path(f"{directory}.log")] if p.is_file()]
    return max(times, default=None)


def copy_absent(source: str, destination: str) -> str:
    """``shutil.copytree``'s copy function that keeps a file already at ``destination`` (a resumed round's own
    newer cells are not replaced by the previous round's)."""
    return destination if os.path.exists(destination) else shutil.copy2(source, destination)
