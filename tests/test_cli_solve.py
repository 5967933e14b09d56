"""Tests of ``torchhrc solve``: JSON schema and values, policy files, progress, exit 2."""

from __future__ import annotations

import argparse
import json

import pytest

from torchhrc.cli import build_parser, main
from torchhrc.commands.solve import make_config
from torchhrc.io.cassandra import write_pomdp
from torchhrc.io.policyx import load_policy
from torchhrc.tasks.classic import tiger


@pytest.fixture(scope="module")
def tiger_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("models") / "tiger.pomdp"
    write_pomdp(tiger(), path)
    return path


def _run(capsys, *argv):
    code = main(list(map(str, argv)))
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize("solver", ["qmdp", "fib", "pbvi"])
def test_json_schema_and_bounds(capsys, tiger_file, tmp_path, solver):
    out_path = tmp_path / "policy.safetensors"
    code, out, err = _run(
        capsys,
        "solve",
        tiger_file,
        "--solver",
        solver,
        "--time-limit",
        "5",
        "--json",
        "--quiet",
        "--out",
        out_path,
    )
    assert code == 0 and err == ""
    report = json.loads(out)  # exactly one JSON object
    assert {"lower", "upper", "gap", "time_s", "n_alphas"} <= set(report)
    assert report["lower"] <= 19.3711 <= report["upper"]
    assert report["gap"] == pytest.approx(report["upper"] - report["lower"])
    assert report["time_s"] > 0 and report["n_alphas"] >= 1
    policy = load_policy(out_path)
    assert policy.num_vectors == report["n_alphas"]
    if solver == "qmdp":
        assert report["upper"] == pytest.approx(189.0)


def test_policyx_output_and_progress(capsys, tiger_file, tmp_path):
    out_path = tmp_path / "tiger.policyx"
    code, out, err = _run(
        capsys, "solve", tiger_file, "--solver", "pbvi", "--time-limit", "2", "--out", out_path
    )
    assert code == 0
    assert "lower" in out and "upper" in out and str(out_path) in out
    assert "lower" in err and "upper" in err  # progress on stderr
    assert load_policy(out_path).num_vectors >= 1


def test_bad_input_exits_2_with_one_line(capsys, tmp_path):
    bad = tmp_path / "bad.pomdp"
    bad.write_text("discount: 0.9\nstates: 2\nactions: 1\nobservations: 1\nT: 0 : 0 : 5 0.5\n")
    code, out, err = _run(capsys, "solve", bad)
    assert code == 2 and out == ""
    assert len(err.strip().splitlines()) == 1 and "bad.pomdp" in err
    code, _, err = _run(capsys, "solve", tmp_path / "missing.pomdp")
    assert code == 2 and len(err.strip().splitlines()) == 1
    with pytest.raises(SystemExit) as exit_info:
        main(["solve", str(bad), "--out", str(tmp_path / "p.txt")])
    assert exit_info.value.code == 2
    with pytest.raises(SystemExit) as exit_info:
        main(["solve", str(bad), "--time-limit", "-1"])
    assert exit_info.value.code == 2


def test_sarsop_reads_and_solves_sparsely_above_the_dense_threshold(
    capsys, tiger_file, monkeypatch
):
    import torchhrc.io.cassandra as cassandra

    code, out, _ = _run(capsys, "solve", tiger_file, "--precision", "0.5", "--json", "--quiet")
    assert code == 0 and json.loads(out)["sparse"] is False
    # Tiger's dense T has 12 entries: above a threshold of 4 it is read and solved sparsely
    # (its T is dense: the fraction that would keep it dense is lifted out of reach)
    monkeypatch.setattr(cassandra, "AUTO_SPARSE_ENTRIES", 4)
    monkeypatch.setattr(cassandra, "AUTO_DENSE_FRACTION", 2.0)
    code, out, _ = _run(capsys, "solve", tiger_file, "--precision", "0.5", "--json", "--quiet")
    report = json.loads(out)
    assert code == 0 and report["sparse"] is True and report["solver"] == "sarsop"
    assert report["lower"] <= 19.3711 <= report["upper"] and report["gap"] <= 0.5
    # PBVI solves it through the same sparse form
    code, out, _ = _run(capsys, "solve", tiger_file, "--solver", "pbvi", "--json", "--quiet")
    report = json.loads(out)
    assert code == 0 and report["sparse"] is True and report["solver"] == "pbvi"
    assert report["lower"] <= 19.3711 <= report["upper"]
    # and QMDP (the same upper bound as the dense model's, 189 by hand)
    code, out, _ = _run(capsys, "solve", tiger_file, "--solver", "qmdp", "--json", "--quiet")
    report = json.loads(out)
    assert code == 0 and report["sparse"] is True and report["upper"] == pytest.approx(189.0)


def test_pomdpx_files_are_chosen_by_suffix(capsys, tmp_path, monkeypatch):
    from torchhrc.io.pomdpx import write_pomdpx
    from torchhrc.tasks.classic import rock_sample

    path = write_pomdpx(tiger(), tmp_path / "tiger.pomdpx")
    code, out, _ = _run(capsys, "solve", path, "--precision", "0.01", "--json", "--quiet")
    report = json.loads(out)
    assert code == 0 and report["model"] == "POMDP" and report["sparse"] is False
    assert report["lower"] <= 19.3714 <= report["upper"] + 1e-9 and report["gap"] <= 0.01
    # a file with an observed state variable is solved as a MOMDP, with the flat model's value
    momdp = rock_sample(2, 1, form="momdp")
    path = write_pomdpx(momdp, tmp_path / "rs.pomdpx")
    code, out, _ = _run(capsys, "solve", path, "--precision", "0.01", "--json", "--quiet")
    report = json.loads(out)
    assert code == 0 and report["model"] == "MOMDP"
    flat = tmp_path / "rs.pomdp"
    write_pomdp(momdp.to_pomdp(), flat)
    code, out, _ = _run(capsys, "solve", flat, "--precision", "0.01", "--json", "--quiet")
    ref = json.loads(out)
    assert ref["model"] == "POMDP"
    assert report["lower"] <= ref["upper"] + 1e-9 and ref["lower"] <= report["upper"] + 1e-9
    # above the dense threshold SARSOP reads it as a SparsePOMDP
    import torchhrc.io.pomdpx as pomdpx

    monkeypatch.setattr(pomdpx, "AUTO_SPARSE_ENTRIES", 4)
    code, out, _ = _run(capsys, "solve", path, "--precision", "0.01", "--json", "--quiet")
    report = json.loads(out)
    assert code == 0 and report["model"] == "SparsePOMDP" and report["sparse"] is True
    assert report["lower"] <= ref["upper"] + 1e-9 and ref["lower"] <= report["upper"] + 1e-9
    bad = tmp_path / "bad.pomdpx"
    bad.write_text(path.read_text().replace("<Discount>", "<Discount>x"))
    code, out, err = _run(capsys, "solve", bad)
    assert code == 2 and out == "" and len(err.strip().splitlines()) == 1
    assert "bad.pomdpx" in err and "Discount" in err


@pytest.mark.parametrize("solver", ["sarsop", "pbvi"])
def test_cpu_time_limits_the_solve_by_process_time(capsys, tiger_file, solver):
    code, out, _ = _run(
        capsys, "solve", tiger_file, "--solver", solver, "--cpu-time", "--time-limit", "5",
        "--json", "--quiet",
    )  # fmt: skip
    assert code == 0
    report = json.loads(out)
    assert report["lower"] <= report["upper"] + 1e-12
    ns = argparse.Namespace(solver=solver, time_limit=3.0, precision=0.1, seed=0, cpu_time=True)
    assert make_config(ns).clock == "process"
    assert make_config(argparse.Namespace(**{**vars(ns), "cpu_time": False})).clock == "wall"


def _rising_memory(monkeypatch):
    """The process's resident memory as the solvers and the command read it: 1 GiB, and 4 MiB
    more at each read."""
    from torchhrc.solvers import _memory

    reads = []

    def fake():
        reads.append((1 << 30) + (4 << 20) * len(reads))
        return reads[-1]

    monkeypatch.setattr(_memory, "resident_bytes", fake)
    monkeypatch.setattr(_memory, "_statm_bytes", lambda: (fake(), 0))  # the guard's one read
    monkeypatch.setattr(_memory, "peak_resident_bytes", lambda: reads[-1] if reads else 1 << 30)
    return reads


@pytest.mark.parametrize("solver", ["sarsop", "pbvi"])
def test_memory_limit_stops_the_solve_and_writes_the_policy(capsys, tiger_file, tmp_path,
                                                           monkeypatch, solver):  # fmt: skip
    reads = _rising_memory(monkeypatch)
    out_path = tmp_path / "tiger.policyx"
    code, out, err = _run(capsys, "solve", tiger_file, "--solver", solver, "--memory", "1100",
                          "--time-limit", "600", "--precision", "1e-12", "--json", "--quiet",
                          "--out", out_path)  # fmt: skip
    assert code == 0 and err == ""
    report = json.loads(out)
    assert report["stop_reason"] == "memory" and max(reads) < 1100 * 2**20
    assert report["lower"] <= 19.3711 <= report["upper"]
    policy = load_policy(out_path)  # the policy so far: its value at b0 is the lower bound
    assert float(policy.value(tiger().b0.unsqueeze(0))[0]) == pytest.approx(report["lower"])
    assert make_config(argparse.Namespace(solver=solver, time_limit=1.0, precision=0.1, seed=0,
                                          memory=2.5)).memory_limit == 2.5 * 2**20  # fmt: skip


def test_a_memory_limit_below_the_process_exits_2(capsys, tiger_file, tmp_path, monkeypatch):
    _rising_memory(monkeypatch)  # 1 GiB held
    out_path = tmp_path / "p.policyx"
    code, out, err = _run(capsys, "solve", tiger_file, "--memory", "1000", "--out", out_path)
    assert code == 2 and out == "" and not out_path.exists()
    assert err == (
        "torchhrc solve: error: --memory 1000 is below what the process holds before reading "
        "the model (1 GiB)\n"
    )


def test_a_model_over_the_memory_limit_is_refused_before_reading(capsys, tmp_path, monkeypatch):
    _rising_memory(monkeypatch)  # 1 GiB held: --memory 1500 leaves 476 MiB to the read
    model = tmp_path / "big.pomdp"
    model.write_text("discount: 0.95\nvalues: reward\nstates: 200000000\nactions: 2\n"
                     "observations: 2\nstart: uniform\nT: * : * : * 0.0\n")  # fmt: skip
    out_path = tmp_path / "p.policyx"
    code, out, err = _run(capsys, "solve", model, "--memory", "1500", "--out", out_path)
    assert code == 2 and out == "" and not out_path.exists()
    assert err.count("\n") == 1 and "more than the memory budget of 476 MiB" in err


def test_out_in_a_missing_folder_exits_2_before_solving(capsys, tiger_file, tmp_path):
    """The folder of ``--out`` is checked before the model is read: no progress line (the
    solve never started), one error line naming the folder, nothing written."""
    folder = tmp_path / "no"
    code, out, err = _run(capsys, "solve", tiger_file, "--out", folder / "p.policyx")
    assert code == 2 and out == "" and not folder.exists()
    assert err == f"torchhrc solve: error: No such file or directory: {folder}\n"


@pytest.mark.parametrize("value", ["0", "-3", "lots", "inf"])
def test_bad_memory_limit_exits_2(capsys, tiger_file, tmp_path, value):
    out_path = tmp_path / "p.policyx"
    with pytest.raises(SystemExit) as info:
        main(["solve", str(tiger_file), f"--memory={value}", "--out", str(out_path)])
    _, err = capsys.readouterr()
    assert info.value.code == 2 and "--memory" in err and not out_path.exists()


def test_policy_interval_needs_out_and_a_positive_number(capsys, tiger_file, tmp_path):
    code, out, err = _run(capsys, "solve", tiger_file, "--policy-interval", "5")
    assert code == 2 and out == ""
    assert (
        err == "torchhrc solve: error: --policy-interval needs --out (the policy file to write)\n"
    )
    for value in ("0", "-1", "often"):
        out_path = tmp_path / "p.policyx"
        with pytest.raises(SystemExit) as info:
            main(["solve", str(tiger_file), "--policy-interval", value, "--out", str(out_path)])
        assert info.value.code == 2 and not out_path.exists()
        assert "--policy-interval" in capsys.readouterr().err


@pytest.mark.parametrize("suffix", [".policyx", ".safetensors"])
def test_a_killed_solve_leaves_its_last_checkpoint(tmp_path, suffix):
    """``--policy-interval`` writes the policy atomically while the solve runs: SIGKILL after
    the first checkpoint leaves a complete policy (RockSample(4, 4), 600 s, precision 1e-12,
    so that only the kill ends it), whose value at b0 lies between the blind policy's and the
    optimal value. The optimum of this instance (rocks placed by ``seed=0``, not the published
    layout whose optimum is 18.04) is 19.01: APPL's pomdpsol brackets it in [19.0100, 19.0107]
    (precision 1e-3), so the bound is 19.0107 + 1e-3. How far the first checkpoint gets depends
    on the machine's speed; the bound does not."""
    import os
    import signal
    import subprocess
    import sys
    import time

    from torchhrc.tasks.classic import rock_sample

    model_path = tmp_path / "rs44.pomdp"
    model = rock_sample(4, 4, seed=0)
    write_pomdp(model, model_path)
    out_path = tmp_path / f"rs44{suffix}"
    env = dict(os.environ, OMP_NUM_THREADS="1")
    proc = subprocess.Popen(
        [sys.executable, "-m", "torchhrc.cli", "solve", str(model_path), "--time-limit", "600",
         "--precision", "1e-12", "--policy-interval", "0.2", "--out", str(out_path), "--quiet"],
        env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
    )  # fmt: skip
    try:  # (no wall-clock limit here: the solve's own --time-limit ends it)
        while not out_path.exists() and proc.poll() is None:  # the first checkpoint
            time.sleep(0.05)
        assert proc.poll() is None, proc.stderr.read().decode() if proc.stderr else ""
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    assert proc.returncode == -signal.SIGKILL
    policy = load_policy(out_path)
    b0 = model.b0.unsqueeze(0)
    value = float(policy.value(b0)[0])
    from torchhrc.solvers.blind import blind_policy

    assert float(blind_policy(model).value(b0)[0]) - 1e-9 <= value <= 19.0107 + 1e-3
    if suffix == ".policyx":
        _pomdpeval_accepts(model_path, out_path, tmp_path)


def _pomdpeval_accepts(model_path, policy_path, cwd):
    """Where APPL is installed, its ``pomdpeval`` reads the checkpoint and simulates it."""
    import os
    import shutil
    import subprocess
    from pathlib import Path

    folder = os.environ.get("TORCHHRC_APPL_BIN")
    path = Path(folder) / "pomdpeval" if folder else None
    found = str(path) if path is not None and path.is_file() else shutil.which("pomdpeval")
    if found is None:
        return  # (APPL is not installed: the policy was checked above)
    proc = subprocess.run([found, str(model_path), "--policy-file", str(policy_path),
                           "--simLen", "50", "--simNum", "100", "--srand", "1"],
                          capture_output=True, text=True, cwd=cwd)  # fmt: skip
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]


def test_a_pomdpsol_command_line_runs(capsys, tiger_file, tmp_path):
    """pomdpsol's own options, with ``pomdpsol`` replaced by ``torchhrc solve``."""
    out_path = tmp_path / "out.policyx"
    code, out, err = _run(
        capsys, "solve", tiger_file, "--fast", "-p", "0.01", "--randomization", "--timeout", "5",
        "--trial-improvement-factor", "0.4", "-o", out_path, "--json", "--quiet",
    )  # fmt: skip
    assert code == 0 and err == ""
    report = json.loads(out)
    assert report["policy"] == str(out_path) and load_policy(out_path).num_vectors >= 1
    assert report["lower"] <= 19.3714 <= report["upper"] + 1e-9 and report["gap"] <= 0.01
    args = build_parser().parse_args(
        ["solve", "m.pomdp", "--timeout", "7", "--trial-improvement-factor", "0.4", "-p", "0.2",
         "--output", "p.policyx", "--randomization"]
    )  # fmt: skip
    config = make_config(args)
    assert (config.time_limit, config.clock, config.kappa) == (7.0, "process", 0.4)
    assert (config.precision, config.tie_break, args.out) == (0.2, "random", "p.policyx")


def test_search_options_reach_sarsop(capsys, tiger_file):
    parse = build_parser().parse_args
    config = make_config(parse(["solve", "m.pomdp"]))
    assert (config.tie_break, config.explore_after, config.explore_within) == (
        "random",
        "auto",
        0.9,
    )
    assert (config.kappa, config.time_limit, config.clock) == (0.5, 10.0, "wall")
    config = make_config(
        parse(["solve", "m.pomdp", "--tie-break", "first", "--explore-after", "never"])
    )
    assert (config.tie_break, config.explore_after) == ("first", None)
    config = make_config(
        parse(["solve", "m.pomdp", "--explore-after", "3", "--explore-within", "1"])
    )
    assert (config.explore_after, config.explore_within) == (3, 1.0)
    assert (
        make_config(parse(["solve", "m.pomdp", "--explore-after", "auto"])).explore_after == "auto"
    )
    # in the solve: a draw from the first trial draws in every trial, never draws in none
    explored = {}
    for value in ("0", "never"):
        code, out, _ = _run(
            capsys, "solve", tiger_file, "--explore-after", value, "--tie-break", "first",
            "--json", "--quiet",
        )  # fmt: skip
        assert code == 0
        report = json.loads(out)
        assert report["lower"] <= 19.3714 <= report["upper"] + 1e-9  # V*(b0), discount 0.95
        explored[value] = (report["explore_after"], report["explored_trials"])
    assert explored["never"] == (None, 0) and explored["0"][0] == 0 and explored["0"][1] >= 1


@pytest.mark.parametrize(
    "argv, option",
    [
        (["--explore-within", "0"], "--explore-within"),
        (["--explore-within", "1.5"], "--explore-within"),
        (["--explore-after", "-1"], "--explore-after"),
        (["--explore-after", "sometimes"], "--explore-after"),
        (["--trial-improvement-factor", "0"], "--trial-improvement-factor"),
        (["--tie-break", "last"], "--tie-break"),
        (["--tie-break", "first", "--randomization"], "--randomization"),
        (["--timeout", "5", "--time-limit", "5"], "--time-limit"),
    ],
)
def test_bad_search_options_exit_2(capsys, tiger_file, argv, option):
    with pytest.raises(SystemExit) as info:
        main(["solve", str(tiger_file), *argv])
    assert info.value.code == 2 and option in capsys.readouterr().err


@pytest.mark.parametrize("option", ["--explore-after=3", "--tie-break=first", "--randomization"])
def test_sarsop_options_for_another_solver_exit_2(capsys, tiger_file, option):
    code, out, err = _run(capsys, "solve", tiger_file, "--solver", "pbvi", option)
    assert code == 2 and out == ""
    assert err.startswith("torchhrc solve: error: --") and "sarsop only, not pbvi" in err
