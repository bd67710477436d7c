"""The reproduction's portable state: chunks of rows on windows of images, read back as the cells of one run at
the full count (rows and every summary metric equal, timings aside), restricted to a prefix for an earlier look,
and restored into an empty work directory."""
import json

import pandas as pd
import pytest

from gtsweep.core.errors import BadInput
from gtsweep.report.samples import load_views
from gtsweep.report.tables import load_summaries
from gtsweep.reproduction import rounds as preset_runs
from gtsweep.reproduction import state as states
from gtsweep.reproduction.collect import collect, done_units
from gtsweep.reproduction.design import Unit, design_digest, rebuild_units

SMALL = ["dataset.textures=[gravel,wood]", "dataset.view_size=[256,192]", "detector=[tuned/orb]",
         "transform=[rotation]", "transform.rotation.strengths=[0,90]", "runner.backend=serial"]
PLAN = {"textures": ["gravel", "wood"], "design": "test"}


@pytest.fixture(scope="module")
def run(tmp_path_factory, existing_store):
    root = tmp_path_factory.mktemp("reproduction")
    (root / "work").mkdir()
    existing_store(root / "work" / "mlflow.db", root / "work")  # the stores as earlier runs left them (migrated
    existing_store(root / "single.db", root / "single")  # once per session): these tests read rows, not runs
    first = Unit("rebuild", "table3_detectors", 0, 1)
    collect([first], root / "state", root / "work", PLAN, extra=SMALL)
    keys = tuple(k for k in states.load(root / "state").presets["table3_detectors"] if "__nms__" in k)
    second = Unit("rebuild", "table3_detectors", 1, 3, keys)
    ran = collect([first, second], root / "state", root / "work", PLAN, extra=SMALL)
    single = preset_runs.run_preset("table3_detectors", ["dataset=survey", "dataset.n_synthetic=3",
                                                         "dataset.n_incremental=0", "dataset.n_absolute=0", *SMALL],
                                    root / "single", f"sqlite:///{root / 'single.db'}", root / "work" / "cache")
    return root, keys, ran, single["output"]


def _no_timings(frame):
    return frame.drop(columns=[c for c in frame if c.startswith("t_")])


@pytest.mark.slow
def test_chunks_equal_one_run_at_the_full_count(run):
    root, keys, ran, single = run
    assert ran == 1  # the first unit was in the state already: not run again
    held = states.load(root / "state")
    views, summaries = load_views(single), {s["key"]: s for s in load_summaries(single)}
    mine = held.views("table3_detectors")
    mine_summaries = {s["key"]: s for s in held.summaries("table3_detectors")}
    for key in keys:
        pd.testing.assert_frame_equal(_no_timings(mine[key]), _no_timings(views[key]), check_dtype=False)
        theirs = {k: v for k, v in summaries[key]["metrics"].items() if not k.startswith("t_")}
        assert {k: mine_summaries[key]["metrics"][k] for k in theirs} == theirs


@pytest.mark.slow
def test_targeted_rows_count(run):
    """Each chunk holds exactly its cells on its window: 1 image per texture for every cell, then images 1-2 of
    the NMS cells only (rows per image: the transform's strengths)."""
    root, keys, _, _ = run
    records = [json.loads(p.read_text()) for p in sorted((root / "state" / "chunks").glob("*.json"))]
    assert [r["window"] for r in records] == [[0, 1], [1, 3]]
    assert set(records[1]["cells"]) == set(keys) and len(records[0]["cells"]) == 2 * len(keys)
    held = states.load(root / "state")
    images = {k: sorted(set(v["image"])) for k, v in held.views("table3_detectors").items()}
    for key in keys:
        assert images[key] == [f"{t}/synthetic/00{i}" for t in ("gravel", "wood") for i in range(3)]
    assert all(len(v) == 2 for k, v in images.items() if k not in keys)
    earlier = held.views("table3_detectors", limit=1)
    assert all(sorted(set(v["image"])) == ["gravel/synthetic/000", "wood/synthetic/000"] for v in earlier.values())


@pytest.mark.slow
def test_restore_into_an_empty_directory(run, tmp_path):
    root, keys, _, single = run
    held = states.load(root / "state")
    (written,) = states.restore(held, tmp_path)
    restored = load_views(written)
    for key in keys:
        pd.testing.assert_frame_equal(_no_timings(restored[key]), _no_timings(load_views(single)[key]),
                                      check_dtype=False)
    assert done_units(root / "state") == {"rebuild/table3_detectors/0-1/all", "rebuild/table3_detectors/1-3/1cells"}


def test_another_plan_is_refused(tmp_path):
    states.write_plan(tmp_path, PLAN)
    states.write_plan(tmp_path, PLAN)  # the same plan again: fine
    with pytest.raises(BadInput, match="differs in: design"):
        states.write_plan(tmp_path, {**PLAN, "design": "other"})


def test_rebuild_units_follow_the_recorded_counts():
    """The rebuild takes each cell to the count round 5 recorded, in windows ending at the rounds' counts."""
    units = rebuild_units()
    table3 = [u for u in units if u.preset == "table3_detectors"]
    assert [(u.start, u.stop) for u in table3] == [(0, 1), (1, 4), (4, 8), (8, 12), (12, 16)]
    assert table3[0].cells is None and all(len(u.cells) == 52 for u in table3[1:])
    table5 = [u for u in units if u.preset == "table5_absolute"]
    assert [(u.start, u.stop, len(u.cells or ())) for u in table5] == [(0, 6, 0), (6, 12, 101), (12, 25, 28),
                                                                         (25, 50, 28)]
    assert table3[1].overrides()[-1] == "dataset.skip_first={synthetic:1}"


def test_design_digest_reads_the_amendment():
    assert len(design_digest()) == 16


@pytest.mark.slow
def test_committed_state_restores_to_the_recorded_verdicts(tmp_path):
    """The committed state, restored into an empty work directory and judged again look by look, gives every
    finding it has rebuilt to its recorded last look the verdict and numbers the round-5 record prints."""
    from gtsweep.reproduction import looks, verify

    held = states.load(states.STATE_DIR)
    written = states.restore(held, tmp_path)
    assert {p.name for p in written} == set(held.presets)
    checks = verify.check(looks.replay(held, 0.05))
    assert all(c.equal for c in checks), "\n".join(verify.report(checks))


def test_committing_files_already_committed_is_done_at_once(tmp_path):
    import subprocess

    from gtsweep.reproduction.collect import commit_state

    subprocess.run(["git", "init", "-q", str(tmp_path)], check=True)
    subprocess.run(["git", "-C", str(tmp_path), "config", "user.email", "t@t"], check=True)
    subprocess.run(["git", "-C", str(tmp_path), "config", "user.name", "t"], check=True)
    (tmp_path / "plan.json").write_text("{}\n")
    assert commit_state(tmp_path, [tmp_path / "plan.json"], "plan", tries=1)
    assert commit_state(tmp_path, [tmp_path / "plan.json"], "plan again", tries=1)  # unchanged: no retries
    log = subprocess.run(["git", "-C", str(tmp_path), "log", "--oneline"], capture_output=True, text=True).stdout
    assert len(log.splitlines()) == 1


def test_collect_stops_in_one_line_on_sigterm(monkeypatch, tmp_path, capsys):
    """A background run ignores SIGINT: SIGTERM stops collect cleanly, with one line and 128 + 15, counting the
    chunks it committed before the cut one."""
    import signal

    from gtsweep.core.interrupts import Interrupted
    from gtsweep.reproduction import cli

    done = set()

    def cut(*args, **kwargs):
        done.update({"rebuild/a", "rebuild/b"})  # two chunks committed, then the third cut
        raise Interrupted(signal.SIGTERM)

    monkeypatch.setattr(cli, "collect", cut)
    monkeypatch.setattr(cli, "done_units", lambda folder: set(done))
    monkeypatch.setattr(cli, "check_plan", lambda held, wanted: None)
    monkeypatch.setattr(cli, "plan", lambda: PLAN)
    previous = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        assert cli.main(["collect", "--state", str(tmp_path / "state"), "--work", str(tmp_path / "work")]) == 143
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and "SIGTERM" in lines[0] and "the same command resumes" in lines[0]
    assert "; 2 chunk(s) this run are in the state" in lines[0]


@pytest.mark.slow
def test_document_is_written_from_the_committed_state(tmp_path):
    """``document`` on the committed state's first chunk (a fixed size, however far the run has gone): the interim
    REPRODUCTION.md with the tuned configs' table, every finding's row, and its tables and plots beside it."""
    import shutil

    from gtsweep.reproduction import document
    from gtsweep.reproduction.tuned import tuning_fingerprint

    first = tmp_path / "state"
    (first / "chunks").mkdir(parents=True)
    shutil.copy(states.STATE_DIR / "plan.json", first)
    for part in sorted((states.STATE_DIR / "chunks").glob("0001-*")):
        shutil.copy(part, first / "chunks")
    held = states.load(first)
    docs = tmp_path / "docs"
    path = document.write(held, docs, 0.05, set(), False, tuning_fingerprint())
    text = path.read_text()
    assert path == docs / "REPRODUCTION.md" and "## The survey's findings" in text
    assert "**The run is not finished**" in text and f"(digest {held.plan['design']})" in text
    findings = [line for line in text.splitlines() if line.startswith("| ") and "| not rebuilt yet |" in line]
    assert 0 < len(findings) < 12  # Table 3's rebuilt findings are judged, the others wait for their rows
    assert any((docs / "reproduction").iterdir())


def test_item_numbers_read_every_id_as_item_number_does():
    ids = pd.Series(["gravel/synthetic/007", "wood/absolute/12", "carpet/incremental/003-004", "tiles/x9/0"],
                    dtype="str")
    assert states.item_numbers(ids).tolist() == [states.item_number(i) for i in ids] == [7, 12, 4, 0]


def test_a_detection_an_earlier_chunk_paid_for_is_not_counted_again():
    def chunk(selector):
        record = {"cells": {"c": {"methods": {"detector": "sift", "selector": selector, "transform": "rotation"}}}}
        rows = pd.DataFrame({states.CELL: ["c", "c"], "view": ["w/s/000/rotation/0", "w/s/000/rotation/90"],
                             "image": ["w/s/000"] * 2, "t_detect": [1.0, 3.0]})
        return record, rows

    paid = set()
    assert states.task_seconds(*chunk("nms"), paid) == 6.0  # two test images, the reference at their mean
    assert states.task_seconds(*chunk("anms"), paid) == 0.0  # the keypoint cache held both detections
    assert states.task_seconds(*chunk("anms")) == 6.0


def test_the_header_counts_the_parts_of_the_new_data_done_and_to_come():
    from gtsweep.reproduction.document import _parts_line

    assert _parts_line({"extension"}) == ("Parts of the new data complete: 1 of 4 (extension); to come: round6, "
                                          "round6-pairings, restated.")
    assert _parts_line({"extension", "round6", "round6-pairings", "restated"}).endswith(
        "4 of 4 (extension, round6, round6-pairings, restated).")
