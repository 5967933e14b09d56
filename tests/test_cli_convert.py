"""Tests of ``torchhrc convert`` (APPL's pomdpconvert, both ways): round trips give the same
tensors, a MOMDP becomes its flat POMDP, APPL reads what it writes, bad input exits 2."""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import subprocess
from pathlib import Path

import pytest
import torch

from torchhrc.cli import main
from torchhrc.io.cassandra import read_pomdp, write_pomdp
from torchhrc.io.pomdpx import read_pomdpx, write_pomdpx
from torchhrc.tasks.classic import rock_sample, tiger
from torchhrc.testing import random_pomdp


def _run(capsys, *argv):
    try:
        code = main(list(map(str, argv)))
    except SystemExit as exit_:
        code = exit_.code
    out, err = capsys.readouterr()
    return code, out, err


def _same(a, b, names=True):
    for field in ("T", "Z", "R", "b0"):
        torch.testing.assert_close(getattr(a, field), getattr(b, field), rtol=0, atol=1e-12)
    assert a.discount == pytest.approx(b.discount, abs=1e-15)
    if names:
        assert (a.states, a.actions, a.observations) == (b.states, b.actions, b.observations)


def _tiger_named():
    """Tiger with names .pomdpx keeps (identifiers: the writer gives others as counts)."""
    return dataclasses.replace(
        tiger(),
        states=("left", "right"),
        actions=("listen", "open_left", "open_right"),
        observations=("hear_left", "hear_right"),
    )


@pytest.mark.parametrize("name", ["tiger", "random"])
def test_round_trip_pomdp_pomdpx_pomdp(capsys, tmp_path, name):
    model = _tiger_named() if name == "tiger" else random_pomdp(5, 3, 4, discount=0.9, seed=2)
    src = write_pomdp(model, tmp_path / f"{name}.pomdp")
    code, out, err = _run(capsys, "convert", src, "--json")  # default: the other suffix
    assert code == 0, err
    summary = json.loads(out)
    assert summary["output"] == str(tmp_path / f"{name}.pomdpx")
    middle = read_pomdpx(tmp_path / f"{name}.pomdpx")
    _same(middle, read_pomdp(src), names=name == "tiger")
    code, _, err = _run(capsys, "convert", tmp_path / f"{name}.pomdpx", tmp_path / "back.pomdp")
    assert code == 0, err
    _same(read_pomdp(tmp_path / "back.pomdp"), read_pomdp(src), names=name == "tiger")


def test_momdp_pomdpx_becomes_its_flat_pomdp(capsys, tmp_path):
    model = rock_sample(4, 2, form="momdp")
    src = write_pomdpx(model, tmp_path / "rs42.pomdpx")
    code, out, err = _run(capsys, "convert", src, tmp_path / "rs42.pomdp")
    assert code == 0, err
    assert "MOMDP" in out
    flat = read_pomdp(tmp_path / "rs42.pomdp")
    _same(flat, read_pomdpx(src).to_pomdp(), names=False)
    # and back to .pomdpx: the flat model again
    code, _, err = _run(capsys, "convert", tmp_path / "rs42.pomdp", tmp_path / "flat.pomdpx")
    assert code == 0, err
    _same(read_pomdpx(tmp_path / "flat.pomdpx"), flat, names=False)


def _read_sparse(monkeypatch):
    """``read_pomdp(sparse="auto")`` (what ``convert`` reads with) reads every model sparse."""
    import torchhrc.io.cassandra as cassandra

    monkeypatch.setattr(cassandra, "AUTO_SPARSE_ENTRIES", 0)
    monkeypatch.setattr(cassandra, "AUTO_DENSE_FRACTION", 2.0)


def test_a_model_read_sparse_is_written_one_entry_a_nonzero(capsys, tmp_path, monkeypatch):
    # a .pomdp read as a SparsePOMDP (as one too large to hold densely is: the thresholds
    # set so that any is); its .pomdpx holds one entry per nonzero and reads back the same
    _read_sparse(monkeypatch)
    model = random_pomdp(7, 3, 4, discount=0.9, seed=4, sparsity=0.5)
    src = write_pomdp(model, tmp_path / "big.pomdp")
    code, out, err = _run(capsys, "convert", src, "--json")
    assert code == 0, err
    assert json.loads(out)["model"] == "SparsePOMDP"
    text = (tmp_path / "big.pomdpx").read_text(encoding="iso-8859-1")
    assert "<Instance>- - -</Instance>" not in text  # no full table of T
    _same(read_pomdpx(tmp_path / "big.pomdpx", sparse=False), read_pomdp(src), names=False)


@pytest.mark.parametrize(
    "argv, message",
    [
        (["{tmp}/none.pomdp"], "No such file"),
        (["{tmp}/m.txt"], "expected a .pomdp or .pomdpx file"),
        (["{src}", "{tmp}/out.xml"], "expected a .pomdp or .pomdpx file"),
        (["{src}", "{src}"], "is the input"),
        (["{src}", "{tmp}/exists.pomdpx"], "file exists"),
        (["{src}", "{tmp}/no/out.pomdpx"], "No such file"),
        (["{bad}", "{tmp}/bad.pomdpx"], "bad.pomdp:5:1: T[0, 0, 0] = 2 is not a probability"),
    ],
)
def test_bad_input_exits_2_without_writing(capsys, tmp_path, argv, message):
    src = write_pomdp(tiger(), tmp_path / "t.pomdp")
    (tmp_path / "exists.pomdpx").write_text("keep")
    bad = tmp_path / "bad.pomdp"
    bad.write_text("discount: 0.9\nstates: 2\nactions: 1\nobservations: 1\nT: 0 : 0 : 0 2.0\n")
    before = sorted(p.name for p in tmp_path.iterdir())
    args = [a.format(tmp=tmp_path, src=src, bad=bad) for a in argv]
    code, _, err = _run(capsys, "convert", *args)
    assert code == 2 and len(err.strip().splitlines()) == 1 and message in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == before
    assert (tmp_path / "exists.pomdpx").read_text() == "keep"


def _appl(name: str) -> str:
    folder = os.environ.get("TORCHHRC_APPL_BIN")
    path = Path(folder) / name if folder else None
    found = str(path) if path is not None and path.is_file() else shutil.which(name)
    if found is None:
        pytest.skip(f"APPL's {name} is not installed (set TORCHHRC_APPL_BIN to its folder)")
    return found


@pytest.mark.parametrize("direction", ["pomdpx", "pomdp", "sparse pomdpx"])
def test_appl_solves_what_convert_writes(capsys, tmp_path, direction, monkeypatch):
    """pomdpsol reads the converted file and finds Tiger's optimum (19.37 at discount 0.95);
    ``sparse pomdpx``: Tiger read as a SparsePOMDP, written one entry a nonzero."""
    binary = _appl("pomdpsol")
    src = write_pomdp(tiger(), tmp_path / "t.pomdp")
    if direction == "sparse pomdpx":
        _read_sparse(monkeypatch)
        direction = "pomdpx"
    if direction == "pomdp":  # .pomdpx -> .pomdp
        code, _, _ = _run(capsys, "convert", src, tmp_path / "t.pomdpx")
        src = tmp_path / "t.pomdpx"
    out = tmp_path / f"converted.{direction}"
    code, _, err = _run(capsys, "convert", src, out)
    assert code == 0, err
    proc = subprocess.run(
        [binary, str(out), "--precision", "0.01", "--output", str(tmp_path / "p.policyx")],
        capture_output=True, text=True, cwd=tmp_path,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stdout[-2000:]
    last = [line for line in proc.stdout.splitlines() if line.strip()[:1].isdigit()][-1]
    lower, upper = (float(v) for v in last.split()[3:5])
    assert lower - 0.02 <= 19.3713 <= upper + 0.02, last
