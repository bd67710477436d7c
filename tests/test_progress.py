"""orchestration/progress.py: the bar's label, and lines printed or logged while it shows land above it."""
from __future__ import annotations

import logging
import sys

import pytest

from gtsweep.orchestration.progress import Progress


@pytest.fixture(autouse=True)
def no_other_handlers(monkeypatch):
    """Each test sees only the logging handlers it adds: earlier tests in the session leave handlers bound to
    streams that are closed by now (Hydra's, pytest's captures), which the bar would redirect."""
    loggers = [logging.getLogger(), *(x for x in logging.Logger.manager.loggerDict.values()
                                      if isinstance(x, logging.Logger))]
    for logger in loggers:
        monkeypatch.setattr(logger, "handlers", [])


class Terminal:
    """What a terminal shows of the text its stdout and stderr (two streams, one screen) receive."""

    def __init__(self):
        self.text: list[str] = []
        self.out, self.err = _Stream(self.text), _Stream(self.text)

    def lines(self) -> list[str]:
        """The screen's lines: a carriage return moves back to the line's start, later text overwrites."""
        shown = []
        for line in "".join(self.text).split("\n"):
            screen, column = [], 0
            for char in line:
                if char == "\r":
                    column = 0
                    continue
                screen[column:column + 1] = [char]
                column += 1
            shown.append("".join(screen).rstrip())
        return shown


class _Stream:
    def __init__(self, text: list[str]):
        self.text = text

    def write(self, s: str) -> int:
        self.text.append(s)
        return len(s)

    def flush(self) -> None:
        pass

    def isatty(self) -> bool:
        return True


def _terminal(monkeypatch) -> Terminal:
    terminal = Terminal()
    monkeypatch.setattr(sys, "stdout", terminal.out)
    monkeypatch.setattr(sys, "stderr", terminal.err)
    monkeypatch.setenv("COLUMNS", "100")
    return terminal


def test_the_bar_names_its_phase_once(monkeypatch):
    terminal = _terminal(monkeypatch)
    progress = Progress(total=None)
    progress.phase("render data set")
    assert terminal.lines()[-1] == "render data set (00:00)"
    progress.phase("evaluate cells", total=12, done=4)
    progress.cell_done()
    progress.bar.refresh()  # tqdm redraws at most twice a second
    assert progress.bar.desc == "evaluate cells" and progress.bar.n == 5
    assert terminal.lines()[-1].startswith("evaluate cells: 5/12 |")  # not "evaluate cells: : 5/12"
    progress.close()
    assert sys.stderr is terminal.err and terminal.lines()[-1] == ""  # the bar is gone, the streams are back


def test_lines_printed_or_logged_while_the_bar_shows_are_lines_of_their_own(monkeypatch):
    terminal = _terminal(monkeypatch)
    console = logging.StreamHandler(terminal.err)  # as Hydra's console handler: bound to stderr once
    console.setFormatter(logging.Formatter("[%(levelname)s] %(message)s"))
    logger = logging.getLogger("gtsweep.test_progress")
    logger.addHandler(console)
    try:
        with Progress(total=None) as progress:
            progress.phase("evaluate cells", total=12, done=5)
            print("(raylet) a worker's line", file=sys.stderr, flush=True)
            print("to stdout, in two writes", end="")
            print()
            logger.warning("a warning")
            assert console.stream is not terminal.err  # writes through tqdm while the bar shows
        assert console.stream is terminal.err and sys.stdout is terminal.out
    finally:
        logger.removeHandler(console)
    lines = [line for line in terminal.lines() if line]
    assert lines == ["(raylet) a worker's line", "to stdout, in two writes", "[WARNING] a warning"]
    assert "evaluate cells: 5/12 |" in "".join(terminal.text)  # the bar was drawn, and drawn again below each line


def test_no_bar_and_no_redirect_off_a_terminal(monkeypatch):
    terminal = _terminal(monkeypatch)
    monkeypatch.setattr(terminal.err, "isatty", lambda: False)
    with Progress() as progress:
        progress.phase("evaluate cells", total=3)
        assert sys.stderr is terminal.err
        print("plain", file=sys.stderr)
    assert terminal.text == ["plain", "\n"]
