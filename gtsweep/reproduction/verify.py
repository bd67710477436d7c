"""The rebuilt rounds against the record they rebuild: each finding's last look of rounds 1-5, replayed on the
state's rows, must print as the round-5 interim document printed it (verdict, look, every comparison's numbers at
their printed precision), and every difference must be explained.

The reference is ``docs/reproduction/reference/round5_findings.md`` (the interim document's findings table); the
differences found and explained are listed, with their recorded and rebuilt text, in
``docs/reproduction/reference/round5_differences.md``. A difference not listed there fails the check.
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

from gtsweep.core.paths import PROJECT_DIR
from gtsweep.reproduction.sequential import Sequential

REFERENCE = PROJECT_DIR / "docs" / "reproduction" / "reference" / "round5_findings.md"
EXPLAINED = REFERENCE.with_name("round5_differences.md")


@dataclass
class Check:
    finding: str
    verdict: tuple[str, str]  # (recorded, rebuilt)
    look: tuple[str, str]
    comparisons: list[tuple[str, str]]  # (recorded, rebuilt) of each comparison that differs, unexplained
    explained: list[tuple[str, str]] = field(default_factory=list)  # those listed in EXPLAINED

    @property
    def equal(self) -> bool:
        """As recorded, apart from the differences :data:`EXPLAINED` lists."""
        return self.verdict[0] == self.verdict[1] and self.look[0] == self.look[1] and not self.comparisons


def recorded(path: Path = REFERENCE) -> dict[str, dict]:
    """The reference's findings: text -> verdict, look and comparisons (each an evidence entry)."""
    found = {}
    for line in Path(path).read_text().splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split(" | ")]
        if len(cells) < 8 or cells[0] in ("finding", "---") or set(cells[0]) <= {"-"}:
            continue
        verdict = re.sub(r"\s*\(.*", "", cells[1])
        found[cells[0]] = {"verdict": verdict, "look": cells[2], "comparisons": _comparisons(cells[-1])}
    return found


def explained(path: Path = EXPLAINED) -> set[tuple[str, str, str]]:
    """The listed differences: (finding, recorded, rebuilt) of each row of the file's table."""
    rows = set()
    for line in Path(path).read_text().splitlines() if Path(path).is_file() else []:
        cells = [c.strip() for c in line.strip().strip("|").split(" | ")]
        if len(cells) == 3 and cells[0] != "finding" and not set(cells[0]) <= {"-"}:
            rows.add(tuple(cells))
    return rows


def _comparisons(evidence: str) -> dict[str, str]:
    parts = [p.strip() for p in evidence.split("; ") if p.strip()]
    return {p.split(":", 1)[0]: p for p in parts}


def check(sequential: Sequential, path: Path = REFERENCE, listed: Path = EXPLAINED) -> list[Check]:
    """Per finding the reference holds and the replay judged: what differs (explained: what ``listed`` lists)."""
    reference, known, checks = recorded(path), explained(listed), []
    for status in sequential.status:
        text = status.hypothesis.text
        if text not in reference or status.finding is None:
            continue
        if not reference[text]["look"].startswith(f"round {status.round},"):  # rebuilt up to an earlier round so far
            continue
        mine = _comparisons(status.finding.evidence.replace("|", "/"))
        theirs = reference[text]["comparisons"]
        differs = [(theirs.get(k, "-"), mine.get(k, "-")) for k in dict.fromkeys([*theirs, *mine])
                   if theirs.get(k) != mine.get(k)]
        look = f"round {status.round}, {status.per_texture}, {status.nominal:.2g}"
        excused = [d for d in differs if (text, *d) in known]
        checks.append(Check(text, (reference[text]["verdict"], status.finding.verdict),
                            (reference[text]["look"], look), [d for d in differs if d not in excused], excused))
    return checks


def report(checks: list[Check], path: Path = REFERENCE) -> list[str]:
    """The check's lines; the findings of ``path`` (the reference :func:`check` read) not among ``checks`` wait."""
    pending = " (the others are not rebuilt that far yet)" if len(checks) < len(recorded(path)) else ""
    lines = [f"{sum(c.equal for c in checks)} of {len(checks)} findings rebuilt to their recorded last look print as "
             f"recorded{pending}"
             + (f", {sum(c.equal and bool(c.explained) for c in checks)} of them apart from the "
                f"{sum(len(c.explained) for c in checks)} comparisons whose difference "
                f"{EXPLAINED.relative_to(PROJECT_DIR)} explains" if any(c.explained for c in checks) else "")]
    for c in checks:
        if c.equal:
            continue
        lines.append(f"- {c.finding}: verdict {c.verdict[0]} -> {c.verdict[1]}, look {c.look[0]} -> {c.look[1]}")
        lines += [f"    recorded: {a}\n    rebuilt:  {b}" for a, b in c.comparisons]
    return lines
