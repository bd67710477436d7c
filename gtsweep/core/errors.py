"""Error types. A :class:`GtsweepError` is a user-facing problem: the CLI prints its message as one line; any other
error that stops a run is said in one line too (:func:`failure_cause`, :func:`failure_line`)."""
import traceback


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


RAYLET_LOST = "the Ray cluster was lost (raylet died)"


def failure_cause(error: BaseException) -> str:
    """Why a run stopped, in one line: a file error with its file (``No space left on device: cells/x.csv``), a
    locked or broken MLflow store, a lost Ray cluster, else the exception's type, message and where it was raised."""
    if isinstance(error, OSError) and error.strerror:
        where = f": {error.filename}" if error.filename else ""
        return f"{error.strerror}{where}"
    message = " ".join((str(error).strip().splitlines() or [""])[0].split())
    kind = type(error).__name__
    module = type(error).__module__ or ""
    if "database is locked" in str(error):
        return "the MLflow store is locked by another process (database is locked)"
    if kind == "LocalRayletDiedError":
        return RAYLET_LOST
    if module.startswith("ray"):
        return f"the Ray cluster was lost ({kind}: {message})"
    if module.startswith(("mlflow", "sqlalchemy")):
        return f"the MLflow store failed ({kind}: {message})"
    frames = traceback.extract_tb(error.__traceback__)
    where = f" (at {frames[-1].filename}:{frames[-1].lineno})" if frames else ""
    return f"{kind}: {message}{where}"


def failure_line(cause: str, kept: str, marked: str, resume: str) -> str:
    """The one line a failed run ends with: the cause, what is kept, what became of its MLflow run, how to continue."""
    return f"gtsweep: error: {cause}; {kept}{marked}; to continue: {resume}"
