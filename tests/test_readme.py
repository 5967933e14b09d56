"""The README's ```python blocks run as written, and the ten-line example's claims hold."""

from __future__ import annotations

import contextlib
import io
import re
from pathlib import Path

import pytest

README = Path(__file__).resolve().parents[1] / "README.md"


def python_blocks(text: str) -> list[str]:
    """The bodies of the fenced ```python blocks of a markdown text, in order."""
    return re.findall(r"^```python[ \t]*\n(.*?)^```[ \t]*$", text, flags=re.M | re.S)


def test_python_blocks_are_found():
    text = "a\n```python\nx = 1\n```\n```bash\nls\n```\n```python\ny = 2\n```\n"
    assert python_blocks(text) == ["x = 1\n", "y = 2\n"]


BLOCKS = python_blocks(README.read_text(encoding="utf-8"))


def test_readme_has_python_blocks():
    assert BLOCKS, "README.md has no ```python block"


def _run(block: str) -> tuple[dict, str]:
    namespace: dict = {"__name__": "__readme__"}
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        exec(compile(block, str(README), "exec"), namespace)
    return namespace, out.getvalue()


@pytest.mark.slow
@pytest.mark.parametrize("index", range(len(BLOCKS)))
def test_readme_block_runs(index):
    namespace, printed = _run(BLOCKS[index])
    assert printed.strip(), "the block prints nothing"
    if "fit_mixture" in BLOCKS[index]:
        _check_ten_line_example(namespace)


def _check_ten_line_example(ns: dict) -> None:
    """The comments of the example: 2 types by BIC, the new user is held out, its posterior."""
    import torch

    from torchhrc.mixture import infer_type

    fit, train, new, demos = ns["fit"], ns["train"], ns["new"], ns["demos"]
    assert fit.k == 2
    held_out = set(new.unique_subjects)
    assert held_out and not held_out & set(train.unique_subjects)  # a true new user
    assert set(train.unique_subjects) | held_out == set(demos.unique_subjects)
    # the posterior's most likely cluster is the one that holds most training subjects of
    # the new user's true type
    mine = fit.model.prepare(new)  # the form the model is over (fit.objects)
    posterior = infer_type(fit.model, mine.sequences, mine.lengths)
    label = new.types[0]
    mine = torch.tensor([t == label for t in train.types])
    majority = int(fit.assignments[mine].mode().values)
    assert int(posterior.argmax()) == majority
    assert float(posterior.max()) > 0.9


def test_command_line_section_lists_every_command_with_real_options():
    """The README's "Command line" block names every sub-command of ``torchhrc``, and every
    ``--option`` it shows is one that command's parser takes."""
    from torchhrc.cli import build_parser

    text = README.read_text(encoding="utf-8")
    block = re.search(r"^## Command line\n+```\n(.*?)^```", text, flags=re.M | re.S)
    assert block, "README.md has no '## Command line' block"
    lines = [line.split() for line in block.group(1).splitlines() if line.startswith("torchhrc ")]
    parser = build_parser()
    commands = next(a for a in parser._actions if a.dest == "command").choices
    assert {words[1] for words in lines} == set(commands)
    for words in lines:
        known = set(commands[words[1]]._option_string_actions)
        shown = {m for w in words for m in re.findall(r"--[a-z][a-z-]*", w)}
        assert shown <= known, (words[1], shown - known)
