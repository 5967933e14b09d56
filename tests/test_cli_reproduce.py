"""Tests of ``torchhrc reproduce`` (the command layer; the pipeline is tested in experiments/)."""

from __future__ import annotations

import json

import pytest

from torchhrc.cli import build_parser, main
from torchhrc.commands.reproduce import PIPELINES


def test_parser_defaults_and_choices():
    args = build_parser().parse_args(["reproduce", "place-and-drill"])
    assert (args.out, args.seed, args.subjects, args.runs, args.quick, args.force) == (
        None, 0, None, None, False, False,
    )  # fmt: skip
    assert "place-and-drill" in PIPELINES
    with pytest.raises(SystemExit) as info:
        build_parser().parse_args(["reproduce", "juggling"])
    assert info.value.code == 2
    with pytest.raises(SystemExit):
        build_parser().parse_args(["reproduce", "place-and-drill", "--runs", "0"])


def test_non_empty_output_is_a_user_error(tmp_path, capsys):
    (tmp_path / "notes.txt").write_text("mine")
    code = main(["reproduce", "place-and-drill", "--quick", "--out", str(tmp_path)])
    err = capsys.readouterr().err
    assert code == 2
    assert "not empty" in err and "--force" in err and len(err.strip().splitlines()) == 1
    assert (tmp_path / "notes.txt").read_text() == "mine"


def test_quick_run_prints_a_summary(tmp_path, capsys):
    out = tmp_path / "res"
    argv = ["reproduce", "place-and-drill", "--quick", "--subjects", "4", "--runs", "3"]
    code = main([*argv, "--out", str(out), "--no-progress"])
    assert code == 0
    summary = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert summary["subjects"] == 4 and summary["out"] == str(out)
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["runs_per_subject"] == 3 and metrics["subjects"] == 4
