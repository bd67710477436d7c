"""Shell completion of ``gtsweep`` / ``python -m gtsweep``: config groups' options, list syntax and ``tuned/`` names,
as the query answers them and as bash completes them through the installed script."""
from __future__ import annotations

import os
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from gtsweep.cli.completion import current_word, query


def test_current_word_is_the_text_before_the_cursor_after_the_last_blank():
    assert current_word("gtsweep detector=[sift,o") == "detector=[sift,o"
    assert current_word("gtsweep detector=s ", None) == ""
    assert current_word("gtsweep detector=sift seed=1", len("gtsweep detector=si")) == "detector=si"


def test_a_groups_options_single_list_and_sweep_syntax():
    assert query("gtsweep detector=s") == ["detector=sift", "detector=surf"]
    assert query("gtsweep detector=[s") == ["detector=[sift", "detector=[surf"]
    # options already in the list are not offered again
    assert query("gtsweep detector=[sift,o") == ["detector=[sift,orb"]
    assert query("gtsweep detector=[orb,s") == ["detector=[orb,sift", "detector=[orb,surf"]
    assert query("python -m gtsweep -m +descriptor=sift,o") == ["+descriptor=sift,orb"]
    assert query("gtsweep sweeps=smo") == ["sweeps=smoke"]


def test_tuned_names_are_a_folder_then_its_options():
    everything = query("gtsweep detector=")
    assert "detector=tuned/" in everything and "detector=sift" in everything
    assert not any(c.startswith("detector=tuned/s") for c in everything)  # one entry for the folder
    tuned = query("gtsweep detector=tuned/")
    assert {"detector=tuned/sift", "detector=tuned/orb"} <= set(tuned) and "detector=sift" not in tuned
    assert query("gtsweep detector=[orb,tuned/s") == ["detector=[orb,tuned/sift", "detector=[orb,tuned/surf"]


def test_a_users_config_dir_adds_its_options(tmp_path):
    (tmp_path / "detector").mkdir()
    (tmp_path / "detector" / "my_star.yaml").write_text("factory: cv2.xfeatures2d.StarDetector_create\n")
    assert query(f"gtsweep --config-dir {tmp_path} detector=[sift,my") == ["detector=[sift,my_star"]


def test_other_words_are_left_to_hydra():
    assert query("gtsweep dataset.n_") is None and query("gtsweep det") is None
    assert query("gtsweep dataset.root=/data") is None  # a key, not a group: Hydra (and file names) answer


def _bash_completions(command: list[str], words: list[str]) -> list[str]:
    """Install the script in a bash, set COMP_WORDS as bash splits the line (at "=": COMP_WORDBREAKS) and call
    the completion function as bash would: what it leaves in COMPREPLY."""
    line = " ".join([*command, *words])
    split = [*command]
    for word in words:
        key, equals, value = word.partition("=")
        split += [key, "=", value] if equals else [key]
    if split[-1] == "" and split[-2] == "=":  # "detector=": the cursor word is "="
        split.pop()
    script = "\n".join([
        f'eval "$({shlex.join([*command, "-sc", "install=bash"])})"',
        f"COMP_LINE={shlex.quote(line)}; COMP_POINT=${{#COMP_LINE}}",
        f"COMP_WORDS=({' '.join(shlex.quote(w) for w in split)}); COMP_CWORD=$(( ${{#COMP_WORDS[@]}} - 1 ))",
        '_gtsweep_completion "${COMP_WORDS[0]}" "${COMP_WORDS[COMP_CWORD]}" "${COMP_WORDS[COMP_CWORD-1]}"',
        "printf '%s\\n' \"${COMPREPLY[@]}\"",
    ])
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"}
    done = subprocess.run(["bash", "--norc", "--noprofile", "-c", script], capture_output=True, text=True, env=env,
                          timeout=120)
    assert done.returncode == 0, done.stderr
    return [line for line in done.stdout.splitlines() if line]


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("bash") is None, reason="needs bash")
def test_bash_completes_groups_lists_and_tuned_names():
    gtsweep = str(Path(sys.executable).parent / "gtsweep")
    assert Path(gtsweep).exists(), "the console script: pip install -e ."
    # bash replaces its own current word: what follows the "=" (COMP_WORDBREAKS), so the replies start there
    assert _bash_completions([gtsweep], ["detector=s"]) == ["sift", "surf"]
    # right after "detector=" bash's word is "=" but readline replaces the empty text after it: no second "="
    assert "agast" in _bash_completions([gtsweep], ["detector="])
    assert _bash_completions([gtsweep], ["detector=[s"]) == ["[sift", "[surf"]
    assert _bash_completions([gtsweep], ["-m", "detector=[sift,o"]) == ["[sift,orb"]
    tuned = _bash_completions([gtsweep], ["detector=tuned/"])
    assert {"tuned/sift", "tuned/orb"} <= set(tuned) and all(t.startswith("tuned/") for t in tuned)
    # python -m gtsweep too, with the interpreter typed
    assert _bash_completions([sys.executable, "-m", "gtsweep"], ["detector=[s"]) == ["[sift", "[surf"]
    # a key is Hydra's: its config keys
    assert "n_absolute=" in " ".join(_bash_completions([gtsweep], ["dataset.n_"]))


@pytest.mark.slow
@pytest.mark.skipif(shutil.which("bash") is None, reason="needs bash")
def test_other_python_commands_keep_their_completion_and_uninstall_restores_it():
    gtsweep = shlex.quote(str(Path(sys.executable).parent / "gtsweep"))
    script = "\n".join([
        "_earlier() { COMPREPLY=(from-the-earlier-completion); }",
        "complete -F _earlier python",
        f'eval "$({gtsweep} -sc install=bash)"',
        f'eval "$({gtsweep} -sc install=bash)"',  # twice (a profile read again): still the earlier one behind it
        'COMP_LINE="python script.py"; COMP_POINT=${#COMP_LINE}; COMP_WORDS=(python script.py); COMP_CWORD=1',
        "_gtsweep_completion python script.py python",
        'echo "reply: ${COMPREPLY[*]}"',
        f'eval "$({gtsweep} -sc uninstall=bash)"',
        "complete -p python",
        "complete -p gtsweep || echo 'gtsweep: none'",
    ])
    done = subprocess.run(["bash", "--norc", "--noprofile", "-c", script], capture_output=True, text=True,
                          timeout=120)
    assert done.stdout.splitlines() == ["reply: from-the-earlier-completion", "complete -F _earlier python",
                                        "gtsweep: none"], done.stderr
