"""How a sweep's MLflow runs end and start again: closed with a status and why, reopened by a resume.

A run that stops (bad input, a failure, an interrupt) is closed FAILED or KILLED with its reason as the tag
:data:`REASON_TAG`. The next run in the same output directory reopens it; one it finds still RUNNING was left so by
a process that was killed (an output directory is locked for one run at a time) and is first closed KILLED with
:data:`LEFT_RUNNING`. When a resume finishes the run, the old reason moves to :data:`RESUMED_AFTER_TAG`.
"""
from __future__ import annotations

REASON_TAG = "gtsweep.reason"
#: The reason a parent run is closed with when the next run in its directory finds it RUNNING.
LEFT_RUNNING = "the process running it ended without closing it (killed)"
RESUMED_AFTER_TAG = "gtsweep.resumed_after"  # why the run had stopped before the resume that finished it


def reopen(client, run_id: str) -> None:
    """Set ``run_id`` RUNNING again for a resume. A run still RUNNING was left so by a process that was killed
    (an output directory is locked for one run at a time): it is first closed KILLED with :data:`LEFT_RUNNING`."""
    if client.get_run(run_id).info.status == "RUNNING":
        mark_ended(client, run_id, LEFT_RUNNING, "KILLED")
    client.update_run(run_id, status="RUNNING")


def clear_reason(client, run_id: str) -> None:
    """A run that finishes after a resume no longer carries why it had stopped as its reason: the reason moves to
    :data:`RESUMED_AFTER_TAG`."""
    reason = client.get_run(run_id).data.tags.get(REASON_TAG)
    if reason is not None:
        client.set_tag(run_id, RESUMED_AFTER_TAG, reason)
        client.delete_tag(run_id, REASON_TAG)


def mark_ended(client, run_id: str, reason: str, status: str) -> str:
    """Close ``run_id`` with ``status`` and why (``client``: an MlflowClient or a tracking URI). Never raises: the
    store itself may be what failed; then the returned note says the run is left open for the resume to close
    ("" when it was closed)."""
    try:
        if isinstance(client, str):
            from mlflow.tracking import MlflowClient

            client = MlflowClient(client)
        client.set_tag(run_id, REASON_TAG, reason[:5000])
        client.set_terminated(run_id, status)
    except Exception as e:  # noqa: BLE001 - a locked or lost store: the resume closes the run
        return f" (the MLflow run {run_id} could not be marked {status}: " \
               f"{(str(e).strip().splitlines() or [type(e).__name__])[0][:200]})"
    return ""
