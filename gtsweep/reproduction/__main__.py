"""``python -m gtsweep.reproduction collect``: compute the reproduction's missing rows in chunks, into its committed
state (``docs/reproduction/state/``); ``status``: what the state holds."""
from __future__ import annotations

import argparse
import sys
import time
from datetime import datetime

import yaml

from gtsweep.core.errors import BadInput
from gtsweep.core.paths import CONF_DIR, PROJECT_DIR
from gtsweep.orchestration.cache import library_versions
from gtsweep.report.reproduce import tuned_digest
from gtsweep.report.tables import ALPHA
from gtsweep.reproduction import state as states
from gtsweep.reproduction.collect import collect, done_units
from gtsweep.reproduction.design import design_digest, rebuild_units

PARTS = {"rebuild": rebuild_units}


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
                       + ", ".join(f"{k} {a} here {b}" for k, (a, b) in versions.items())
                       + "): install from docs/reproduction/state/constraints.txt (make reproduce does)")
    other = [k for k in wanted if k != "versions" and held.get(k) != wanted[k]]
    if other:
        raise BadInput(f"the committed state is of another plan: {', '.join(other)} differ "
                       f"({'; '.join(f'{k}: {held.get(k)} vs {wanted[k]}' for k in other)})")


def _until(text: str | None) -> float | None:
    if text is None:
        return None
    hour, minute = map(int, text.split(":"))
    now = datetime.now()
    target = now.replace(hour=hour, minute=minute, second=0, microsecond=0)
    return target.timestamp() + (86400 if target < now else 0)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m gtsweep.reproduction", description=__doc__.splitlines()[0])
    parser.add_argument("command", choices=["collect", "status", "verify"])
    parser.add_argument("--part", choices=sorted(PARTS), default="rebuild")
    parser.add_argument("--state", default=str(states.STATE_DIR), help="the state folder (committed)")
    parser.add_argument("--work", default=str(PROJECT_DIR / ".gtsweep_cache" / "reproduction"),
                        help="scratch sweeps, keypoint cache and MLflow store (not state)")
    parser.add_argument("--commit", action="store_true", help="git-commit each chunk as it is written")
    parser.add_argument("--until", help="HH:MM (local time): start no chunk after it")
    args = parser.parse_args(argv)
    units = PARTS[args.part]()
    try:
        wanted = plan()
        check_plan(states.read_plan(args.state), wanted)
        if args.command == "verify":
            from gtsweep.reproduction import looks, verify

            print("\n".join(verify.report(verify.check(looks.replay(states.load(args.state), ALPHA)))))
            return 0
        if args.command == "status":
            done = done_units(args.state)
            print(f"{args.part}: {sum(u.name in done for u in units)} of {len(units)} chunks in {args.state} "
                  f"({states.size_mb(args.state):.1f} MB)")
            return 0
        ran = collect(units, args.state, args.work, wanted, args.commit, _until(args.until),
                      log=lambda m: print(m, flush=True))
    except BadInput as e:
        print(f"gtsweep.reproduction: error: {e}", file=sys.stderr)
        return 2
    print(f"gtsweep.reproduction: {ran} chunk(s) this run, {time.strftime('%H:%M')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
