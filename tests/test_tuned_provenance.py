"""Tuned detector parameters carry the fingerprint of the data set they were tuned on; the reproduction states
which files were not tuned on dataset=survey's optimisation views, and a check fails until they are."""
import pytest

from gtsweep.experiments.optimize.stopping import settled
from gtsweep.reproduction.tuned import tuned_fingerprints, tuned_line, tuning_fingerprint


def _tuned(directory, name, fingerprint):
    header = f"# @package detector\n# Data set fingerprint {fingerprint}.\n"
    (directory / f"{name}.yaml").write_text(header + f"{name}: {{}}\n")


def test_the_document_names_tuned_files_of_another_data_set(tmp_path):
    _tuned(tmp_path, "sift", "aaaa")
    _tuned(tmp_path, "surf", "bbbb")
    assert tuned_fingerprints(tmp_path) == {"sift": "aaaa", "surf": "bbbb"}
    line = tuned_line("aaaa", tmp_path)
    assert "1 of 2 tuned files" in line and "surf on bbbb" in line and "fingerprint aaaa" in line
    _tuned(tmp_path, "surf", "aaaa")
    assert tuned_line("aaaa", tmp_path).startswith("Detector parameters: all 2 tuned files were tuned on this")


def test_a_study_stops_when_its_best_has_stopped_moving():
    rising = [0.5, 0.6, 0.7, 0.8]
    assert not settled(rising, 2, 0.005)  # the last 2 raised the best
    flat = [0.5, 0.7, 0.702, 0.703, 0.701]
    assert settled(flat, 3, 0.005)  # the last 3 raised 0.7 by 0.003 at most
    assert not settled(flat, 3, 0.001) and not settled(flat, None, 0.005) and not settled(flat[:3], 3, 0.005)


@pytest.mark.slow
def test_every_tuned_file_was_tuned_on_the_survey_optimisation_views():
    expected = tuning_fingerprint()
    stale = {k: v for k, v in tuned_fingerprints().items() if v != expected}
    assert not stale, f"not tuned on dataset=survey's optimisation views ({expected}): {stale}"
