"""The rebuild's check against the round-5 record: a comparison that prints differently counts only where the
differences file lists it, with its recorded and rebuilt text."""
from types import SimpleNamespace

from gtsweep.reproduction import verify

FINDING = "SIFT's ambiguity is large, about 1.5 (Table 3)"
RECORDED = "sift ambiguity - 1.5: +0.042 [+0.001, +0.084], p = 0.01, p(fail, Holm) = 1, n = 96: undecided"
REBUILT = RECORDED.replace("p = 0.01,", "p = 0.0098,")


def _files(tmp_path, listed: bool):
    reference = tmp_path / "findings.md"
    reference.write_text("| finding | verdict | decided at | compute | test | margin | correction | evidence |\n"
                         "|---|---|---|---|---|---|---|---|\n"
                         f"| {FINDING} | undecided (still open) | round 5, 16, 0.0057 | - | t | 0.05 | Holm | "
                         f"{RECORDED} |\n")
    differences = tmp_path / "differences.md"
    differences.write_text("| finding | recorded | rebuilt |\n|---|---|---|\n"
                           + (f"| {FINDING} | {RECORDED} | {REBUILT} |\n" if listed else ""))
    return reference, differences


def _replayed(evidence: str):
    finding = SimpleNamespace(evidence=evidence, verdict="undecided")
    status = SimpleNamespace(hypothesis=SimpleNamespace(text=FINDING), finding=finding, round=5, per_texture=16,
                             nominal=0.0057)
    return SimpleNamespace(status=[status])


def test_a_listed_difference_is_explained(tmp_path):
    [check] = verify.check(_replayed(REBUILT), *_files(tmp_path, listed=True))
    assert check.equal and check.explained == [(RECORDED, REBUILT)] and check.comparisons == []


def test_a_difference_not_listed_fails(tmp_path):
    [check] = verify.check(_replayed(REBUILT), *_files(tmp_path, listed=False))
    assert not check.equal and check.comparisons == [(RECORDED, REBUILT)]
    assert "0 of 1 findings" in verify.report([check])[0]


def test_a_listed_difference_does_not_excuse_another(tmp_path):
    other = RECORDED.replace("p = 0.01,", "p = 0.02,")
    [check] = verify.check(_replayed(other), *_files(tmp_path, listed=True))
    assert not check.equal and check.comparisons == [(RECORDED, other)]


def test_the_committed_differences_file_parses():
    rows = verify.explained()  # Table 3 at round 5 (4), Table 5 at round 2 (1)
    assert len(rows) == 5 and all(recorded != rebuilt for _, recorded, rebuilt in rows)


def test_the_report_says_others_wait_only_while_some_do():
    """One of the record's twelve findings rebuilt: the others wait; all twelve: no finding waits."""
    def done(text):
        return verify.Check(text, ("holds", "holds"), ("round 1, 1, 0.05",) * 2, [])
    assert "not rebuilt that far yet" in verify.report([done(FINDING)])[0]
    every = [done(text) for text in verify.recorded()]
    assert len(every) == 12 and verify.report(every)[0] == ("12 of 12 findings rebuilt to their recorded last "
                                                           "look print as recorded")
