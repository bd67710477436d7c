"""Bash completion of ``gtsweep`` and ``python -m gtsweep`` (README, "Shell completion"): ``-sc install=bash``
prints the script (completion.bash); on TAB it runs ``<command> -sc query=bash`` with ``COMP_LINE``/``COMP_POINT``,
and :func:`query` answers a config group's value (``detector=s``, ``detector=[sift,o``, ``detector=tuned/``), whole
words from where bash's current word starts; any other word is left to Hydra's completion (its config keys)."""
from __future__ import annotations

import os
import shlex
from importlib import resources

from gtsweep.cli.search import configs

#: ``-sc install=bash`` prints this script (completion.bash beside this module).
SCRIPT = resources.files(__package__).joinpath("completion.bash").read_text()
UNINSTALL = """complete -r gtsweep python python3 2>/dev/null
eval "$_GTSWEEP_PREVIOUS"
unset -f _gtsweep_completion
unset _GTSWEEP_PREVIOUS _GTSWEEP_PYTHON_COMPLETION
"""
#: Hydra's prefixes of an override: append, delete, force-add.
PREFIXES = ("++", "+", "~")


def current_word(line: str, point: int | None = None) -> str:
    """The word under the cursor: the text of ``line`` up to ``point`` after its last unquoted blank."""
    before = line[:len(line) if point is None else point]
    if not before or before[-1].isspace():
        return ""
    try:
        return shlex.split(before)[-1]
    except ValueError:  # an open quote: the raw text after the last blank
        return before.split()[-1]


def group_options(group: str, argv=(), typed: str = "") -> list[str]:
    """The options of a config group; a subgroup as ``tuned/`` (like a folder), or its options (``tuned/sift``)
    once ``typed`` (the value typed so far) names it."""
    found = configs(argv)
    names = list(found.options(group))
    for subgroup in found.groups(group):
        folder = subgroup[len(group) + 1:] + "/"
        names += [folder + name for name in found.options(subgroup)] if typed.startswith(folder) else [folder]
    return sorted(set(names))


def top_groups(argv=()) -> list[str]:
    """The config groups one can select on the command line (Hydra's own left out)."""
    return sorted({g.split("/")[0] for g in configs(argv).groups() if g.split("/")[0] != "hydra"})


def value_candidates(word: str, argv=()) -> list[str] | None:
    """Completions of ``group=value`` (a single value, ``[a,b`` list or ``a,b`` sweep), whole words; None when
    ``word`` is not a config group's value."""
    key, equals, value = word.partition("=")
    group = key
    for prefix in PREFIXES:
        group = group.removeprefix(prefix)
    if not equals or group not in top_groups(argv):
        return None
    opening = "[" if value.startswith("[") else ""
    *chosen, last = value[len(opening):].split(",")
    head = f"{key}={opening}" + "".join(f"{name}," for name in chosen)
    return [head + name for name in group_options(group, argv, last) if name.startswith(last) and name not in chosen]


def query(line: str, point: int | None = None) -> list[str] | None:
    """Candidates (whole words) for the word under the cursor of ``line``, a ``gtsweep`` or ``python -m gtsweep``
    command line; None when Hydra's completion should answer."""
    word = current_word(line, point)
    try:
        argv = shlex.split(line[:len(line) if point is None else point])
    except ValueError:  # an open quote
        argv = line.split()
    start = 3 if argv[1:3] == ["-m", "gtsweep"] else 1  # the command's own words
    return value_candidates(word, argv[start:])


def handled(argv: list[str]) -> bool:
    """Answer ``-sc install=bash``, ``-sc uninstall=bash`` and ``-sc query=bash`` (a group's value) here; True
    when done, False to leave the command line to Hydra."""
    if len(argv) != 2 or argv[0] not in ("-sc", "--shell-completion"):
        return False
    if argv[1] == "install=bash":
        print(SCRIPT, end="")
        return True
    if argv[1] == "uninstall=bash":
        print(UNINSTALL, end="")
        return True
    if argv[1] != "query=bash" or "COMP_LINE" not in os.environ:
        return False
    point = os.environ.get("COMP_POINT", "")
    line = os.environ["COMP_LINE"]
    candidates = query(line, int(point) if point.isdigit() else None)
    if candidates is None:  # Hydra answers; it reads "python -m gtsweep" as two arguments
        words = line.split(maxsplit=3)
        if words[1:3] == ["-m", "gtsweep"]:
            os.environ["COMP_LINE"] = " ".join(["gtsweep", *words[3:]]) + (" " if line.endswith(" ") else "")
        return False
    print("\n".join(candidates))
    return True
