"""``python -m gtsweep.reproduction`` (and ``make reproduce``): the survey's reproduction from its committed state.

- ``collect``: compute the rows the amended design still needs, in chunks, into ``docs/reproduction/state/``
  (``--commit``: each chunk committed to git as it is written);
- ``document``: regenerate ``docs/REPRODUCTION.md`` from the state alone (nothing computed);
- ``verify``: the rebuilt rounds 1-5 against the round-5 record;
- ``status``: what the state holds and what is left;
- ``audit``: render every recorded image and pair anew and name those whose bytes differ from the record here
  (exit 1 if any).
"""
from __future__ import annotations

import argparse
import signal
import sys
import time
from datetime import datetime
from pathlib import Path

import yaml

from gtsweep.core.errors import BadInput
from gtsweep.core.interrupts import SIGNALS, Interrupted, on_signal
from gtsweep.core.paths import CONF_DIR, DEFAULT_CACHE_DIR, PROJECT_DIR
from gtsweep.orchestration.cache import library_versions
from gtsweep.report.tables import ALPHA
from gtsweep.reproduction import state as states
from gtsweep.reproduction.collect import collect, done_units
from gtsweep.reproduction.design import NEW_WINDOWS, design_digest, new_units, rebuild_units
from gtsweep.reproduction.tuned import tuned_digest, tuning_fingerprint

COMMANDS = ("collect", "document", "verify", "status", "audit")


def plan() -> dict:
    """What the run is: its data set, level, tuned parameters, amended design and the versions in its reuse keys."""
    textures = yaml.safe_load((CONF_DIR / "dataset" / "survey.yaml").read_text())["textures"]
    return {"dataset": "survey", "textures": textures, "alpha": ALPHA, "tuned": tuned_digest(),
            "design": design_digest(), "versions": library_versions()}


def check_plan(held: dict | None, wanted: dict) -> None:
    """One line naming what differs between the committed plan and this checkout and install."""
    if held is None:
        return
    versions = {k: (held["versions"].get(k), v) for k, v in wanted["versions"].items() if held["versions"].get(k) != v}
    if versions:
        raise BadInput("the committed state was computed with other versions ("
                       + ", ".join(f"{k} {a}, here {b}" for k, (a, b) in versions.items())
                       + "): install from docs/reproduction/state/constraints.txt (make reproduce does)")
    other = [k for k in wanted if k != "versions" and held.get(k) != wanted[k]]
    if other:
        raise BadInput(f"the committed state is of another plan: {', '.join(other)} differ "
                       f"({'; '.join(f'{k}: {held.get(k)} vs {wanted[k]}' for k in other)})")


def units_now(folder: Path, held: states.State | None = None) -> tuple[list, str]:
    """The units to run: the rebuild's, then (once Tables 3 and 4 are rebuilt: the restated picks read them) the
    new data's; and a line on what is left. ``held``: the state of ``folder`` when already loaded."""
    from gtsweep.reproduction import amended
    from gtsweep.reproduction.looks import preset_data

    units = rebuild_units()
    done = done_units(folder)
    if not all(u.name in done for u in units):
        return units, f"{sum(u.name in done for u in units)} of {len(units)} rebuild chunks"
    held = held or states.load(folder)
    picks = amended.picks_restated(preset_data(held, "table3_detectors", ALPHA),
                                   preset_data(held, "table4_incremental", ALPHA))
    records = {p: {k: c.record for k, c in cells.items()} for p, cells in held.presets.items()}
    new = new_units(records, picks)
    return units + new, f"rebuild done; {sum(u.name in done for u in new)} of {len(new)} new-data chunks"


def done_parts(folder: Path, held: states.State | None = None) -> tuple[set[str], bool]:
    units, _ = units_now(folder, held)
    done = done_units(folder)
    parts = {p for p in NEW_WINDOWS if any(u.kind == p for u in units)
             and all(u.name in done for u in units if u.kind == p)}
    return parts, all(u.name in done for u in units) and len(parts) == len(NEW_WINDOWS)


def _until(text: str | None) -> float | None:
    if text is None:
        return None
    hour, minute = map(int, text.split(":"))
    now = datetime.now()
    target = now.replace(hour=hour, minute=minute, second=0, microsecond=0)
    return target.timestamp() + (86400 if target < now else 0)


def run(args) -> int:
    log = lambda m: print(m, flush=True)  # noqa: E731
    folder = Path(args.state)
    if args.command == "verify":
        from gtsweep.reproduction import looks, verify

        print("\n".join(verify.report(verify.check(looks.replay(states.load(folder), ALPHA)))))
        return 0
    if args.command == "document":
        from gtsweep.reproduction import checks, document

        held = states.load(folder)
        log(f"gtsweep.reproduction: the renderer gives the recorded bytes for {checks.rerender(held, args.cache)} "
            f"sampled images or pairs")
        parts, finished = done_parts(folder, held)
        print(f"wrote {document.write(held, Path(args.docs), ALPHA, parts, finished, tuning_fingerprint())}")
        return 0
    if args.command == "audit":
        from gtsweep.reproduction import checks

        compared, differ = checks.audit(states.load(folder), args.cache, args.textures)
        print(f"{compared - len(differ)} of {compared} recorded images and pairs render to their recorded bytes here"
              + (f"; other bytes: {', '.join(differ)}" if differ else ""))
        return 1 if differ else 0
    if args.command == "status":
        _, left = units_now(folder)
        print(f"{left} in {folder} ({states.size_mb(folder):.1f} MB)")
        return 0
    ran, until, before = 0, _until(args.until), len(done_units(folder))
    for s in SIGNALS:  # also in the background, where a shell leaves SIGINT ignored: SIGTERM stops it cleanly
        signal.signal(s, on_signal)
    try:
        while True:  # the new data's units exist once the rebuild's picks do
            units, _ = units_now(folder)
            more = collect(units, folder, Path(args.work), plan(), args.commit, until, log)
            ran += more
            if not more or (until is not None and time.time() >= until):
                break
    except Interrupted as e:
        ran = len(done_units(folder)) - before  # the chunks committed before the cut one
        print(f"gtsweep.reproduction: {e}; {ran} chunk(s) this run are in the state, the cut one's finished cells "
              f"wait in {args.work}: the same command resumes", file=sys.stderr)
        return 128 + e.signum
    log(f"gtsweep.reproduction: {ran} chunk(s) this run; {units_now(folder)[1]}")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m gtsweep.reproduction", description=__doc__.splitlines()[0])
    parser.add_argument("command", choices=COMMANDS)
    parser.add_argument("--state", default=str(states.STATE_DIR), help="the state folder (committed)")
    parser.add_argument("--work", default=str(PROJECT_DIR / DEFAULT_CACHE_DIR / "reproduction"),
                        help="scratch sweeps, keypoint cache and MLflow store (not state)")
    parser.add_argument("--cache", default=str(PROJECT_DIR / DEFAULT_CACHE_DIR), help="rendered data sets")
    parser.add_argument("--docs", default=str(PROJECT_DIR / "docs"), help="where REPRODUCTION.md goes")
    parser.add_argument("--commit", action="store_true", help="git-commit each chunk as it is written")
    parser.add_argument("--until", help="HH:MM (local time): start no chunk after it")
    parser.add_argument("--textures", nargs="+", help="audit: only these textures' items")
    args = parser.parse_args(argv)
    try:
        check_plan(states.read_plan(args.state), plan())
        return run(args)
    except BadInput as e:
        print(f"gtsweep.reproduction: error: {e}", file=sys.stderr)
        return 2
