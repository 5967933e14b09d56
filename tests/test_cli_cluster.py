"""Tests for the ``simulate-demos`` and ``cluster`` commands, through ``torchhrc.cli.main``.

Only this module's two sub-commands are registered (the parser is the real one), so these
tests do not depend on the other commands' modules.
"""

from __future__ import annotations

import json
import math

import pytest

from torchhrc import cli
from torchhrc.data import Demonstrations
from torchhrc.metrics import adjusted_rand_index


@pytest.fixture(autouse=True)
def _only_these_commands(monkeypatch):
    monkeypatch.setattr(cli, "COMMANDS", ("simulate_demos", "cluster"))


def _run(capsys, *argv: str) -> tuple[int, str, str]:
    code = cli.main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture
def study(tmp_path, capsys):
    path = tmp_path / "study.csv"
    code, out, _ = _run(
        capsys, "simulate-demos", "--subjects", "6", "--noise", "0", "--out", str(path)
    )
    assert code == 0 and "18 sequences" in out
    return path


def test_simulate_demos_writes_the_study(tmp_path, capsys):
    path = tmp_path / "d.csv"
    code, out, err = _run(capsys, "simulate-demos", "--out", str(path), "--seed", "3")
    assert code == 0 and err == ""
    assert out.strip() == f"wrote 54 sequences (18 subjects x 3; 9 safe, 9 efficient) to {path}"
    demos = Demonstrations.read_csv(path)
    from torchhrc.tasks.place_and_drill import simulate_study

    assert demos == simulate_study(seed=3)
    json_path = tmp_path / "d.json"
    options = ["--subjects", "5", "--positions", "4", "--strategies", "safe,efficient,pairs"]
    code, _, _ = _run(capsys, "simulate-demos", *options, "--noise", "0.1", "--out", str(json_path))
    assert code == 0
    demos = Demonstrations.read_json(json_path)
    assert demos.num_symbols == 10 and set(demos.types) == {"safe", "efficient", "pairs"}


def test_simulate_demos_refuses_to_overwrite_without_force(study, capsys):
    before = study.read_text()
    code, out, err = _run(capsys, "simulate-demos", "--seed", "9", "--out", str(study))
    assert code == 2 and out == ""
    assert err.count("\n") == 1 and "--force" in err and str(study) in err
    assert study.read_text() == before
    code, _, _ = _run(capsys, "simulate-demos", "--seed", "9", "--out", str(study), "--force")
    assert code == 0 and study.read_text() != before


@pytest.mark.parametrize(
    ("argv", "match"),
    [
        (["--strategies", "safe,lazy"], "unknown strategy 'lazy'"),
        (["--subjects", "0"], "n_subjects"),
        (["--noise", "0.3,0.1"], "noise"),
    ],
)
def test_simulate_demos_bad_arguments_exit_2(tmp_path, capsys, argv, match):
    code, _, err = _run(capsys, "simulate-demos", *argv, "--out", str(tmp_path / "x.csv"))
    assert code == 2 and err.count("\n") == 1 and match in err
    assert not (tmp_path / "x.csv").exists()


def test_simulate_demos_unparsable_noise_is_a_usage_error(tmp_path, capsys):
    with pytest.raises(SystemExit) as info:
        cli.main(["simulate-demos", "--noise", "high", "--out", str(tmp_path / "x.csv")])
    assert info.value.code == 2
    assert "expected a rate" in capsys.readouterr().err


def test_cluster_json_schema_and_values(study, capsys):
    code, out, err = _run(
        capsys, "cluster", str(study), "--k-max", "4", "--restarts", "4", "--json"
    )
    assert code == 0 and err == ""
    assert out.count("\n") == 1
    report = json.loads(out)
    demos = Demonstrations.read_csv(study)
    for key in ("k", "bic", "log_likelihood", "per_k", "assignments", "adjusted_rand_index"):
        assert key in report
    assert report["k"] == 2
    assert set(report["per_k"]) == {"2", "3", "4"}
    for scores in report["per_k"].values():
        assert {"bic", "log_likelihood"} <= set(scores)
    assert report["criterion"] == "icl_or_gain"  # the soft method's default (issue 31)
    # the exact ICL's k, raised only by steps that gain strongly (none here: "heldout" unset)
    best = max(report["per_k"], key=lambda k: report["per_k"][k]["exact_icl"])
    assert "heldout" not in report["per_k"][best]
    assert int(best) == report["k"]
    assert math.isclose(report["per_k"][best]["bic"], report["bic"])
    assert math.isclose(report["per_k"][best]["log_likelihood"], report["log_likelihood"])
    assert list(report["assignments"]) == list(demos.keys)
    assert set(report["assignments"].values()) == {0, 1}
    assert report["cluster_sizes"] == [
        list(report["assignments"].values()).count(c) for c in range(2)
    ]
    clusters = [report["assignments"][key] for key in demos.keys]
    assert report["adjusted_rand_index"] == pytest.approx(
        adjusted_rand_index(demos.types, clusters)
    )
    assert report["adjusted_rand_index"] == 1.0  # noiseless study


def test_cluster_min_gain_option_sets_the_rule(study, capsys):
    """--min-gain is fit_mixture's min_gain: a huge one keeps k_min, 0 is the criterion alone."""
    argv = ["cluster", str(study), "--k-max", "4", "--restarts", "3", "--json"]
    with pytest.warns(RuntimeWarning, match="single type"):  # k = 2 gains < 100 over one
        code, out, _ = _run(capsys, *argv, "--min-gain", "100")
    assert code == 0 and json.loads(out)["k"] == 2
    code, out, _ = _run(capsys, *argv, "--min-gain", "0")
    report = json.loads(out)
    best = max(
        max(report["per_k"], key=lambda k: report["per_k"][k][c]) for c in ("bic", "exact_icl")
    )
    assert report["k"] == int(best)
    assert set(report["per_k"]["3"]) == {
        "bic",
        "icl",
        "exact_icl",
        "log_likelihood",
        "gain",
        "consistency",
    }
    code, out, _ = _run(capsys, *argv, "--min-gain", "0", "--criterion", "bic")
    report = json.loads(out)
    best = max(report["per_k"], key=lambda k: report["per_k"][k]["bic"])
    assert report["k"] == int(best) and report["criterion"] == "bic"


def test_cluster_same_seed_same_output(study, capsys):
    argv = ["cluster", str(study), "--k-max", "3", "--restarts", "3", "--json", "--seed", "7"]
    assert _run(capsys, *argv)[1] == _run(capsys, *argv)[1]


def test_cluster_relabel_objects_reports_relabelled_symbols(tmp_path, capsys):
    path = tmp_path / "three.csv"
    argv = ["simulate-demos", "--subjects", "60", "--positions", "4", "--noise", "0"]
    argv += ["--strategies", "safe,efficient,pairs", "--out", str(path)]
    assert _run(capsys, *argv)[0] == 0
    argv = ["cluster", str(path), "--k-max", "4", "--restarts", "4", "--json"]
    code, out, _ = _run(capsys, *argv, "--relabel-objects")
    report = json.loads(out)
    assert code == 0
    assert "human:place_1" in report["symbols"] and "human:place_A" not in report["symbols"]
    assert report["num_symbols"] == Demonstrations.read_csv(path).relabel_objects().num_symbols
    assert report["k"] == 3 and report["adjusted_rand_index"] == 1.0


def test_cluster_readable_report_and_loo(study, capsys):
    argv = ["cluster", str(study), "--k-max", "3", "--restarts", "3", "--method", "paper"]
    code, out, _ = _run(capsys, *argv, "--loo")
    assert code == 0
    assert "selected k = 2" in out
    assert "<- selected" in out
    assert "adjusted Rand index 1.000" in out
    assert "leave-one-subject-out accuracy (vote): 1.000" in out
    assert "S01:" in out
    code, out, _ = _run(capsys, *argv, "--loo", "--json")
    loo = json.loads(out)["loo"]
    assert loo["accuracy"] == 1.0 and loo["misclassified"] == []
    assert set(loo["predictions"]) == {f"S{i:02d}" for i in range(1, 7)}


def test_cluster_saves_the_model(study, tmp_path, capsys):
    from torchhrc.mixture import MarkovChainMixture

    model_path = tmp_path / "model.json"
    argv = ["cluster", str(study), "--k-max", "3", "--restarts", "2", "--json"]
    code, out, _ = _run(capsys, *argv, "--save-model", str(model_path))
    assert code == 0
    model = MarkovChainMixture.load(model_path)
    assert model.num_clusters == json.loads(out)["k"] and model.num_symbols == 8


def test_cluster_without_types_has_no_ari(tmp_path, capsys):
    path = tmp_path / "untyped.csv"
    path.write_text(
        "subject,sequence,step,actor,action\n"
        + "".join(
            f"s{i},0,{t},{'human' if t % 2 == 0 else 'robot'},{'a' if t % 2 == 0 else 'b'}\n"
            for i in range(4)
            for t in range(4)
        )
    )
    code, out, _ = _run(capsys, "cluster", str(path), "--k-max", "2", "--restarts", "2", "--json")
    assert code == 0
    assert "adjusted_rand_index" not in json.loads(out)
    code, _, err = _run(capsys, "cluster", str(path), "--loo")
    assert code == 2 and "type" in err and err.count("\n") == 1


@pytest.mark.parametrize(
    ("content", "argv", "match"),
    [
        (None, [], "No such file"),
        ("", [], ":1: empty file"),
        ("subject,sequence,step,actor,action\ns,0,0,human,a\ns,0,2,robot,b\n", [], ":3:3: missing"),
        (
            "subject,sequence,step,actor,action\ns,0,0,human,a\ns,0,1,robot,b\n",
            ["--k-min", "3"],
            "k_min",
        ),
        (
            "subject,sequence,step,actor,action\ns,0,0,human,a\ns,0,1,robot,b\n",
            ["--k-min", "3", "--k-max", "2"],
            "k_min <= k_max",
        ),
    ],
)
def test_cluster_bad_input_exits_2_with_one_line(tmp_path, capsys, content, argv, match):
    path = tmp_path / "bad.csv"
    if content is not None:
        path.write_text(content)
    code, out, err = _run(capsys, "cluster", str(path), *argv)
    assert code == 2 and out == ""
    assert err.startswith("torchhrc cluster: error: ") and err.count("\n") == 1
    assert match in err


def test_real_entry_point_reports_a_bad_file_in_one_line(tmp_path):
    # Through the installed module, every command registered: no traceback, exit 2.
    import subprocess
    import sys

    path = tmp_path / "bad.csv"
    path.write_text("subject,sequence,step,actor,action\ns,0,0,hmn,a\n")
    completed = subprocess.run(
        [sys.executable, "-m", "torchhrc.cli", "cluster", str(path)],
        capture_output=True,
        text=True,
        timeout=300,
        check=False,
    )
    assert completed.returncode == 2 and completed.stdout == ""
    assert completed.stderr == (
        f"torchhrc cluster: error: {path}:2:4: unknown actor 'hmn' (expected one of human, robot)\n"
    )


def test_cluster_detects_exchangeable_objects_and_reports_the_choice(tmp_path, capsys):
    """The default (--objects auto) on a study with a fresh placement order in every
    demonstration keeps the exchangeable form and says so; --objects raw forces the recorded
    symbols; --relabel-objects keeps its meaning (the relabelled file, fitted as it is)."""
    path = tmp_path / "orders.csv"
    argv = ["simulate-demos", "--subjects", "18", "--positions", "4", "--noise", "0.1"]
    argv += ["--strategies", "safe,efficient,lagging", "--out", str(path), "--seed", "60"]
    argv += ["--order-change", "1"]
    assert _run(capsys, *argv)[0] == 0
    base = ["cluster", str(path), "--k-max", "5", "--restarts", "5"]
    code, out, _ = _run(capsys, *base, "--json")
    report = json.loads(out)
    assert code == 0 and report["objects"] == "exchangeable"
    assert set(report["object_comparison"]) == {"raw", "exchangeable"}
    assert report["symbols"] == list(Demonstrations.read_csv(path).symbol_names)  # recorded
    code, out, _ = _run(capsys, *base)
    assert code == 0 and "objects: exchangeable (" in out
    code, out, _ = _run(capsys, *base, "--json", "--objects", "raw")
    raw = json.loads(out)
    assert raw["objects"] == "raw" and "object_comparison" not in raw
    code, out, _ = _run(capsys, *base, "--json", "--relabel-objects")
    relabelled = json.loads(out)
    assert relabelled["objects"] == "raw" and "human:place_1" in relabelled["symbols"]
    code, _, err = _run(capsys, *base, "--relabel-objects", "--objects", "exchangeable")
    assert code == 2 and "--relabel-objects" in err


def test_cluster_order_option_finds_types_only_a_second_order_chain_sees(tmp_path, capsys):
    """Two types with the same first-order counts (p1 q1 p2 q2 or p2 q2 p1 q1, a robot wait
    before every step): --order 1 (the default) finds one type, --order auto two, and says
    which order it kept (the second: the third finds the same two types, with a smaller
    exact ICL); --order 3 finds them too; --order 2 with --loo is refused with the reason."""
    wait = ("robot", "wait")
    a = [wait, ("human", "p1"), wait, ("human", "q1"), wait, ("human", "p2"), wait, ("human", "q2")]
    b = [wait, ("human", "p2"), wait, ("human", "q2"), wait, ("human", "p1"), wait, ("human", "q1")]
    seqs = [a if s % 2 == 0 else b for s in range(12) for _ in range(3)]
    subjects = [f"s{s}" for s in range(12) for _ in range(3)]
    types = ["ab" if s % 2 == 0 else "ba" for s in range(12) for _ in range(3)]
    path = tmp_path / "orders.csv"
    Demonstrations.from_lists(seqs, subjects=subjects, types=types).write_csv(path)
    base = ["cluster", str(path), "--k-min", "1", "--k-max", "3", "--restarts", "5", "--json"]
    code, out, _ = _run(capsys, *base)
    first = json.loads(out)
    assert code == 0 and first["k"] == 1 and first["order"] == 1
    assert "order_comparison" not in first
    # why not two types in first order: the step's thresholds, as MixtureFit.next_step
    names = {"min_gain", "strong_gain", "heldout_gain", "consistency", "split_consistency"}
    assert first["next_step"]["k"] == 2 and set(first["next_step"]["short_of"]) <= names
    code, out, _ = _run(capsys, *base, "--order", "auto")
    auto = json.loads(out)
    assert code == 0 and auto["k"] == 2 and auto["order"] == 2
    assert auto["adjusted_rand_index"] == pytest.approx(1.0)
    assert {o: c["k"] for o, c in auto["order_comparison"].items()} == {"1": 1, "2": 2, "3": 2}
    assert auto["next_step"]["k"] == 3
    code, out, _ = _run(capsys, *base, "--order", "3")
    third = json.loads(out)
    assert code == 0 and third["k"] == 2 and third["order"] == 3
    assert third["adjusted_rand_index"] == pytest.approx(1.0)
    code, _, err = _run(capsys, *base, "--order", "2", "--loo")
    assert code == 2 and "--order 1 with --loo" in err
