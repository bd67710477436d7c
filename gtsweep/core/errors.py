"""Error types. A :class:`GtsweepError` is a user-facing problem: the CLI prints its message as one line."""


class GtsweepError(Exception):
    """A problem the user can fix (bad input, unknown name, bad file); printed as one line, exit code 2."""


class UnknownMethod(GtsweepError):
    """A method name that no registry knows."""

    def __init__(self, family: str, name: str, choices):
        self.family, self.name, self.choices = family, name, sorted(choices)
        super().__init__(f"unknown {family} '{name}'; valid choices: {', '.join(self.choices)}"
                         + "".join(f" (did you mean '{near}'?)" for near in nearest(name, self.choices)))


def nearest(word: str, candidates) -> list[str]:
    """The candidate closest to a mistyped ``word`` (``detectr`` -> ``detector``), as a list of at most one."""
    import difflib

    return difflib.get_close_matches(str(word), [str(c) for c in candidates], n=1, cutoff=0.6)


def causes(error: BaseException | None):
    """``error`` and the exceptions behind it (its cause, else its context), each once."""
    seen = set()
    while error is not None and id(error) not in seen:
        seen.add(id(error))
        yield error
        error = error.__cause__ or error.__context__


class BadInput(GtsweepError):
    """Missing, unreadable or malformed input (image, pose file, data set folder, override)."""


class NotApplicable(GtsweepError):
    """A method pairing that cannot be evaluated (the survey's NA cells); ``reason`` says why."""

    def __init__(self, reason: str):
        self.reason = reason
        super().__init__(reason)
