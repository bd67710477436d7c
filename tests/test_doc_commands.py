"""Every ``gtsweep ...`` / ``python -m gtsweep ...`` command line in README.md and docs/*.md composes: the command
line gtsweep's own checks accept (``all`` and globs expanded, every job composed and checked by the sweeper before
any runs, the run settings checked), run as ``-m`` with a task that runs nothing."""
import re
import shlex
from pathlib import Path

import pytest

from gtsweep.orchestration.grid import REGISTRIES

ROOT = Path(__file__).resolve().parent.parent
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
COMMAND = re.compile(r"^(?:[A-Z_]+=\S+\s+)*(?:gtsweep|python -m gtsweep)(?:\s|$)")
#: Commands the test cannot compose, and why. The long runs (`make reproduce`, `make tune`) are make targets, not
#: gtsweep lines; their gtsweep commands (gtsweep.report.reproduce, the Makefile's TUNE) are not in the pages.
EXEMPT = {
    "gtsweep -sc install=bash": "prints the shell completion script: nothing to compose",
}


INLINE = re.compile(r"`((?:python -m gtsweep|gtsweep) [^`]*)`")
#: A code block that shows a config file of the user's starts with its path: ``# myconf/detector/x.yaml: ...``.
CONFIG_FILE = re.compile(r"^# (\S+\.yaml)(?::|$)")


def commands() -> list[tuple[str, str]]:
    """(page:line, command) of every gtsweep command line of the pages: in a code block, or inline in backticks."""
    found = []
    for page in PAGES:
        inside = False
        for number, line in enumerate(page.read_text().splitlines(), 1):
            if line.lstrip().startswith("```"):
                inside = not inside
                continue
            text = re.sub(r"\s+#\s.*$", "", line.strip())  # a trailing comment
            candidates = [text] if inside else INLINE.findall(line)
            found += [(f"{page.relative_to(ROOT)}:{number}", c) for c in candidates
                      if COMMAND.match(c) and c not in EXEMPT]
    return found


def write_shown_configs(folder: Path) -> None:
    """The config files the pages show (a code block whose first line names the file), written under ``folder``."""
    for page in PAGES:
        for block in re.findall(r"```ya?ml\n(.*?)```", page.read_text(), flags=re.S):
            named = CONFIG_FILE.match(block)
            if named:
                (folder / named[1]).parent.mkdir(parents=True, exist_ok=True)
                (folder / named[1]).write_text(block)


def test_the_pages_hold_the_commands_a_newcomer_copies():
    lines = [command for _, command in commands()]
    assert "python -m gtsweep sweeps=smoke detector=[orb] --cfg job" in lines
    assert "python -m gtsweep -m dataset.seed=0,1 detector=all" in lines
    assert len(lines) >= 28  # 28 when written: a page that loses commands fails here


@pytest.mark.slow
@pytest.mark.parametrize("where, command", commands(), ids=lambda value: str(value))
def test_every_documented_command_composes(where, command, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # a user's --config-dir holds the config files the pages show
    write_shown_configs(tmp_path)
    words = shlex.split(command)
    while "=" in words[0] and not words[0].startswith("-"):  # RAY_ADDRESS=... python -m gtsweep
        words.pop(0)
    args = words[3:] if words[0] == "python" else words[1:]
    for flag in ("--config-dir", "-cd"):
        if flag in args:
            (tmp_path / args[args.index(flag) + 1]).mkdir(parents=True, exist_ok=True)
    registered = {group: set(registry.names()) for group, registry in REGISTRIES.items()}
    try:
        _compose(args, monkeypatch)
    except SystemExit as done:
        if done.code not in (None, 0):
            pytest.fail(f"{where}: {command}: exit {done.code}")
    finally:  # a method the command declared in YAML leaves the registries as they were
        for group, registry in REGISTRIES.items():
            for name in set(registry.names()) - registered[group]:
                registry.unregister(name)


def _compose(args: list[str], monkeypatch) -> None:
    """The command's jobs composed and checked as ``-m`` composes and checks them, with a task that runs nothing."""
    import gtsweep.cli.app
    from gtsweep.cli import main

    monkeypatch.setattr(gtsweep.cli.app, "app", lambda cfg: None)
    flags = ("--cfg", "-c")
    args = [a for i, a in enumerate(args) if a not in flags and (i == 0 or args[i - 1] not in flags)]
    multirun = [] if {"-m", "--multirun"} & set(args) else ["-m"]  # --cfg job: the same composition
    main([*multirun, *args, "mlflow.enabled=false", "hydra/hydra_logging=none", "hydra/job_logging=none"])
