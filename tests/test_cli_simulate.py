"""Tests of ``torchhrc simulate`` and ``torchhrc evaluate`` (APPL's pomdpsim and pomdpeval):
the mean against Tiger's exact policy value, the trace against the Bayes filter, a MOMDP
trace, APPL's pomdpeval on the same files, and exit 2 with nothing written on bad input."""

from __future__ import annotations

import itertools
import json
import math
import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest
import torch

from torchhrc.cli import main
from torchhrc.io.cassandra import write_pomdp
from torchhrc.io.policyx import save_policy
from torchhrc.io.pomdpx import read_pomdpx, write_pomdpx
from torchhrc.pomdp.belief import momdp_update, update
from torchhrc.solvers import SARSOPConfig, solve
from torchhrc.solvers.policy import AlphaVectorPolicy
from torchhrc.solvers.policy_graph import controller_value, policy_graph
from torchhrc.solvers.qmdp import qmdp_policy
from torchhrc.tasks.classic import rock_sample, tiger


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """Tiger, its SARSOP policy in both formats, and the policy's exact value (the linear
    solve over its closed policy graph, KLC98's five-node controller)."""
    folder = tmp_path_factory.mktemp("tiger")
    model = tiger()
    # converges by precision in about a second: the policy does not depend on the machine
    sol = solve(model, SARSOPConfig(time_limit=600.0, precision=1e-5, seed=0))
    exact = controller_value(model, policy_graph(model, sol.policy))
    return {
        "model": write_pomdp(model, folder / "tiger.pomdp"),
        "policyx": save_policy(sol.policy, folder / "tiger.policyx"),
        "safetensors": save_policy(sol.policy, folder / "tiger.safetensors"),
        "exact": exact,
    }


def _run(capsys, *argv):
    try:
        code = main(list(map(str, argv)))
    except SystemExit as exit_:  # argparse's own errors
        code = exit_.code
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize("kind", ["policyx", "safetensors"])
def test_evaluate_ci_holds_the_exact_value(capsys, files, kind):
    code, out, err = _run(
        capsys, "evaluate", files["model"], "--policy", files[kind], "--episodes", "2000",
        "--json",
    )  # fmt: skip
    assert code == 0, err
    r = json.loads(out)
    assert r["ci_low"] <= files["exact"] <= r["ci_high"], (r, files["exact"])
    assert r["episodes"] == 2000 and r["horizon"] == 283  # 0.95^283 * 10 / 0.05 < 1e-3
    half = 1.959963984540054 * r["std_error"]
    assert r["ci_high"] - r["mean"] == pytest.approx(half + r["truncation"])


def test_evaluate_is_seeded_and_prints_the_summary(capsys, files):
    argv = ["evaluate", files["model"], "--policy", files["policyx"], "--episodes", "50"]
    a = json.loads(_run(capsys, *argv, "--json", "--seed", "3")[1])
    b = json.loads(_run(capsys, *argv, "--json", "--seed", "3")[1])
    c = json.loads(_run(capsys, *argv, "--json", "--seed", "4")[1])
    assert a["mean"] == b["mean"] != c["mean"]
    code, out, _ = _run(capsys, *argv, "--horizon", "7")
    assert code == 0 and out.splitlines()[0].startswith("mean ")
    assert "horizon    7 " in out


def test_simulate_trace_is_the_bayes_filter(capsys, files, tmp_path):
    trace = tmp_path / "trace.jsonl"
    code, out, err = _run(
        capsys, "simulate", files["model"], "--policy", files["safetensors"], "--episodes", "3",
        "--horizon", "6", "--seed", "1", "--trace", trace, "--json",
    )  # fmt: skip
    assert code == 0, err
    summary = json.loads(out)
    lines = [json.loads(line) for line in trace.read_text().splitlines()]
    assert len(lines) == 3 * 6
    model = tiger()
    states, actions, observations = model.states, model.actions, model.observations
    for e in range(3):
        steps = sorted((x for x in lines if x["episode"] == e), key=lambda x: x["step"])
        assert [s["step"] for s in steps] == list(range(6))
        ret = sum(0.95**t * s["reward"] for t, s in enumerate(steps))
        assert ret == pytest.approx(summary["returns"][e], abs=1e-9)
        for now, nxt in itertools.pairwise(steps):
            b = torch.tensor([now["belief"].get(s, 0.0) for s in states], dtype=torch.float64)
            a, o = actions.index(now["action"]), observations.index(now["observation"])
            expected = update(model, b, a, o).belief
            got = torch.tensor([nxt["belief"].get(s, 0.0) for s in states], dtype=torch.float64)
            torch.testing.assert_close(got, expected, rtol=0, atol=1e-12)
            # the reward is the true state's
            assert now["reward"] == float(model.R[a, states.index(now["state"])])


def test_simulate_momdp_trace_shows_the_observed_state(capsys, tmp_path):
    model = rock_sample(4, 2, form="momdp")
    path = write_pomdpx(model, tmp_path / "rs42.pomdpx")
    policy = save_policy(qmdp_policy(model), tmp_path / "rs42.safetensors")
    trace = tmp_path / "t.jsonl"
    code, out, err = _run(
        capsys, "simulate", path, "--policy", policy, "--episodes", "4", "--horizon", "8",
        "--trace", trace,
    )  # fmt: skip
    assert code == 0, err
    assert out.splitlines()[0].startswith("episode    0  return ")
    lines = [json.loads(line) for line in trace.read_text().splitlines()]
    assert lines and {"x", "next_x", "state", "belief"} <= set(lines[0])
    read = read_pomdpx(path)  # the names as the file has them
    X, Y = list(read.observed_states), list(read.hidden_states)
    A, O = list(read.actions), list(read.observations)
    for e in range(4):
        steps = sorted((x for x in lines if x["episode"] == e), key=lambda x: x["step"])
        for now, nxt in itertools.pairwise(steps):
            assert nxt["x"] == now["next_x"]
            b = torch.tensor([now["belief"].get(y, 0.0) for y in Y], dtype=torch.float64)
            expected = momdp_update(
                model, X.index(now["x"]), b, A.index(now["action"]), X.index(now["next_x"]),
                O.index(now["observation"]),
            ).belief  # fmt: skip
            got = torch.tensor([nxt["belief"].get(y, 0.0) for y in Y], dtype=torch.float64)
            torch.testing.assert_close(got, expected, rtol=0, atol=1e-12)
            assert math.isclose(sum(nxt["belief"].values()), 1.0, abs_tol=1e-12)


def test_simulate_traces_a_flat_policy_of_a_momdp(capsys, tmp_path):
    """A flat policy of a MOMDP (solved through ``to_pomdp()``) runs on the flat model: the
    trace names its states and observations as ``to_pomdp()`` does (``x|y``, ``x2|o``), and
    each belief is the flat Bayes filter of the one before."""
    model = rock_sample(4, 2, form="momdp")
    path = write_pomdpx(model, tmp_path / "rs42.pomdpx")
    # random vectors over the 68 flat states, one per action: moves, checks and samples
    g = torch.Generator().manual_seed(5)
    vectors = torch.rand(14, 68, generator=g, dtype=torch.float64)
    flat_policy = AlphaVectorPolicy(vectors, torch.arange(14) % model.num_actions)
    policy = save_policy(flat_policy, tmp_path / "flat.policyx")
    trace = tmp_path / "t.jsonl"
    code, out, err = _run(
        capsys, "simulate", path, "--policy", policy, "--episodes", "3", "--horizon", "5",
        "--seed", "2", "--trace", trace, "--json",
    )  # fmt: skip
    assert code == 0, err
    flat = read_pomdpx(path).to_pomdp()  # the names as the file has them, flattened
    S, A, O = list(flat.states), list(flat.actions), list(flat.observations)
    lines = [json.loads(line) for line in trace.read_text().splitlines()]
    assert len(lines) == 3 * 5 and "x" not in lines[0]
    assert len({x["action"] for x in lines}) > 2 and any(x["reward"] != 0 for x in lines)
    returns = json.loads(out)["returns"]
    for e in range(3):
        steps = sorted((x for x in lines if x["episode"] == e), key=lambda x: x["step"])
        ret = sum(flat.discount**t * s["reward"] for t, s in enumerate(steps))
        assert ret == pytest.approx(returns[e], abs=1e-9)
        for now, nxt in itertools.pairwise(steps):
            b = torch.tensor([now["belief"].get(s, 0.0) for s in S], dtype=torch.float64)
            a, o = A.index(now["action"]), O.index(now["observation"])
            expected = update(flat, b, a, o).belief
            got = torch.tensor([nxt["belief"].get(s, 0.0) for s in S], dtype=torch.float64)
            torch.testing.assert_close(got, expected, rtol=0, atol=1e-12)
            assert now["reward"] == float(flat.R[a, S.index(now["state"])])


def _pomdpeval() -> str:
    folder = os.environ.get("TORCHHRC_APPL_BIN")
    path = Path(folder) / "pomdpeval" if folder else None
    found = str(path) if path is not None and path.is_file() else shutil.which("pomdpeval")
    if found is None:
        pytest.skip("APPL's pomdpeval is not installed (set TORCHHRC_APPL_BIN to its folder)")
    return found


def test_evaluate_agrees_with_pomdpeval(capsys, files, tmp_path):
    """APPL's pomdpeval on the same files: both 95 % intervals hold the exact value, so they
    overlap (pomdpeval's is narrower: it averages over the belief tree, not only samples)."""
    binary = _pomdpeval()
    proc = subprocess.run(
        [binary, str(files["model"]), "--policy-file", str(files["policyx"]), "--simLen", "283",
         "--simNum", "2000", "--srand", "1"],
        capture_output=True, text=True, cwd=tmp_path,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stdout[-2000:]
    row = re.compile(r"^\s*(\d+)\s+([-0-9.eE+]+)\s+\(([-0-9.eE+]+),\s*([-0-9.eE+]+)\)")
    rows = [m for m in map(row.match, proc.stdout.splitlines()) if m]
    appl_mean, appl_lo, appl_hi = (float(rows[-1].group(i)) for i in (2, 3, 4))
    _, out, _ = _run(
        capsys, "evaluate", files["model"], "--policy", files["policyx"], "--episodes", "2000",
        "--json",
    )  # fmt: skip
    ours = json.loads(out)
    assert appl_lo - 1e-3 <= files["exact"] <= appl_hi + 1e-3
    assert ours["ci_low"] <= appl_hi and appl_lo <= ours["ci_high"], (ours, appl_mean)
    assert ours["ci_low"] <= appl_mean <= ours["ci_high"]


# -- bad input: one line on stderr, exit 2, nothing written ---------------------------------------
@pytest.mark.parametrize(
    "argv, message",
    [
        (["{missing}", "--policy", "{policyx}"], "No such file"),
        (["{model_txt}", "--policy", "{policyx}"], "expected a .pomdp or .pomdpx file"),
        (["{model}", "--policy", "{model}"], "expected a .policyx or .safetensors file"),
        (["{model}", "--policy", "{other_policy}"], "o.policyx does not fit the model"),
        (["{model}", "--policy", "{bad_actions}"], "expected policy actions < A=3, got 7"),
        (["{model}", "--policy", "{garbage_policy}"], "not a safetensors file"),
        (["{model}", "--policy", "{policyx}", "--episodes", "1"], "at least 2"),
        (["{model}", "--policy", "{policyx}", "--horizon", "0"], "positive integer"),
        (["{bad_model}", "--policy", "{policyx}"], "bad.pomdp:5:1: T[0, 0, 0] = 2 is not a"),
        (["{undiscounted}", "--policy", "{policyx}"], "u.pomdp has discount 1: give --horizon"),
    ],
)
@pytest.mark.parametrize("command", ["simulate", "evaluate"])
def test_bad_input_exits_2_without_writing(capsys, files, tmp_path, command, argv, message):
    other = save_policy(
        qmdp_policy(rock_sample(4, 2, form="momdp").to_pomdp()), tmp_path / "o.policyx"
    )
    garbage = tmp_path / "g.safetensors"
    garbage.write_bytes(b"not safetensors")
    two_states = AlphaVectorPolicy(torch.eye(2, dtype=torch.float64), torch.tensor([0, 7]))
    bad_actions = save_policy(two_states, tmp_path / "a.safetensors")  # Tiger has 3 actions
    bad = tmp_path / "bad.pomdp"
    bad.write_text("discount: 0.9\nstates: 2\nactions: 1\nobservations: 1\nT: 0 : 0 : 0 2.0\n")
    undiscounted = tmp_path / "u.pomdp"
    undiscounted.write_text(
        Path(files["model"]).read_text().replace("discount: 0.95", "discount: 1")
    )
    names = {
        "undiscounted": undiscounted,
        "missing": tmp_path / "missing.pomdp",
        "model_txt": tmp_path / "m.txt",
        "model": files["model"],
        "policyx": files["policyx"],
        "other_policy": other,
        "garbage_policy": garbage,
        "bad_actions": bad_actions,
        "bad_model": bad,
    }
    args = [a.format(**names) for a in argv]
    trace = tmp_path / "trace.jsonl"
    extra = ["--trace", str(trace)] if command == "simulate" else []
    code, _, err = _run(capsys, command, *args, *extra)
    assert code == 2
    assert len(err.strip().splitlines()) == 1 and message in err, err
    assert not trace.exists() and not list(tmp_path.glob(".trace*"))


def test_trace_is_not_overwritten_and_its_folder_must_exist(capsys, files, tmp_path):
    trace = tmp_path / "trace.jsonl"
    trace.write_text("keep\n")
    argv = ["simulate", files["model"], "--policy", files["policyx"], "--horizon", "3"]
    code, _, err = _run(capsys, *argv, "--trace", trace)
    assert code == 2 and "file exists" in err and trace.read_text() == "keep\n"
    code, _, err = _run(capsys, *argv, "--trace", tmp_path / "no" / "t.jsonl")
    assert code == 2 and "No such file" in err
    code, _, err = _run(capsys, *argv, "--trace", trace, "--force")
    assert code == 0 and len(trace.read_text().splitlines()) == 10 * 3


def test_pomdpsim_and_pomdpeval_command_lines_run(capsys, files, tmp_path):
    """APPL's options, with ``pomdpsim`` / ``pomdpeval`` replaced by ``torchhrc simulate`` /
    ``torchhrc evaluate``: the same runs as torchhrc's own names give."""
    trace = tmp_path / "t.jsonl"
    appl = ["--fast", "--policy-file", files["policyx"], "--simLen", "4", "--simNum", "3"]
    code, out, err = _run(
        capsys, "simulate", files["model"], *appl, "--srand", "5", "--output-file", trace, "--json"
    )
    assert code == 0, err
    assert len(trace.read_text().splitlines()) == 3 * 4
    ours = ["--policy", files["policyx"], "--horizon", "4", "--episodes", "3", "--seed", "5"]
    code, same, _ = _run(capsys, "simulate", files["model"], *ours, "--json")
    assert code == 0 and json.loads(same)["returns"] == json.loads(out)["returns"]
    code, out, err = _run(capsys, "evaluate", files["model"], *appl, "--srand", "5", "--json")
    assert code == 0, err
    code, same, _ = _run(capsys, "evaluate", files["model"], *ours, "--json")
    assert json.loads(same)["mean"] == json.loads(out)["mean"]
    code, other, _ = _run(capsys, "evaluate", files["model"], *appl, "--srand", "6", "--json")
    assert json.loads(other)["mean"] != json.loads(out)["mean"]  # --srand is the seed


def test_help_names_the_appl_equivalents(capsys):
    for command in ("simulate", "evaluate"):
        with pytest.raises(SystemExit) as info:
            main([command, "--help"])
        assert info.value.code == 0
        out = capsys.readouterr().out
        assert "--policy POLICY" in out and "--simNum" in out and "--seed" in out
        assert "%" not in out.replace("95 %", "").replace("95%", "")  # (argparse's %%)
    with pytest.raises(SystemExit):
        main(["--help"])
    out = capsys.readouterr().out
    assert "pomdpsim" in out and "pomdpeval" in out and "simulate-demos" in out
