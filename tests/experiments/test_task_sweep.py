"""Sweeps of a task with simulated people (torchhrc/experiments/task_sweep.py and the task
side of torchhrc/experiments/sweep.py): a suite task by name, a user's factory by file path,
the same rows through the Python API and the CLI, resume, and errors that name the parameter.
"""

from __future__ import annotations

import csv
import json
import math
import sys
from pathlib import Path

import pytest

import torchhrc
from torchhrc.cli import main
from torchhrc.errors import ModelError
from torchhrc.experiments.sweep import (
    SerialExecutor,
    canonical_task,
    is_timing_column,
    load_callable,
    read_results,
)
from torchhrc.experiments.task_sweep import QUICK, task_metrics
from torchhrc.tasks.human_model_choice import STATE_SMOOTHING_GRID
from torchhrc.tasks.suite import make_task

pytestmark = pytest.mark.filterwarnings("ignore::UserWarning", "ignore::RuntimeWarning")

WORLD_FILE = str(Path(__file__).with_name("sweep_world.py"))
#: Tiny cells: 4 subjects x 2 demonstrations, 10 episodes per type, quick learning.
GRID = {"noise": [0.0, 0.1], "subjects": [4], "per_subject": [2], "episodes": [10]}


def _untimed(rows: list[dict]) -> list[dict]:
    return [{k: v for k, v in r.items() if not is_timing_column(k)} for r in rows]


def _csv_rows(path: Path) -> list[dict]:
    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))


def _check_row(row: dict, world: torchhrc.tasks.people.TaskWithPeople) -> None:
    """Properties every row of a task sweep has, whatever the learning found."""
    names = world.type_names
    assert row["true_k"] == world.num_types
    assert 1 <= row["k"] <= 6 and row["k_correct"] == int(row["k"] == row["true_k"])
    assert -1.0 <= row["ari"] <= 1.0
    assert row["human_model.chain"] + row["human_model.state"] <= 1
    # the state model's smoothing, one of the grid learn() chooses from
    assert (row["human_model.habit_weight"], row["human_model.prior_strength"]) in (
        STATE_SMOOTHING_GRID
    )
    for robot in ("type-aware", "type-agnostic"):
        per_type = [row[f"return.{robot}.by_type.{n}"] for n in names]
        # the types in equal shares: the overall mean is the mean of the per-type means
        assert row[f"return.{robot}.mean"] == pytest.approx(sum(per_type) / len(per_type))
        assert row[f"return.{robot}.ci95"] >= 0.0
    assert row["gain.mean"] == pytest.approx(
        row["return.type-aware.mean"] - row["return.type-agnostic.mean"]
    )
    for n in names:
        assert row[f"gain.by_type.{n}"] == pytest.approx(
            row[f"return.type-aware.by_type.{n}"] - row[f"return.type-agnostic.by_type.{n}"]
        )
    assert row["gain.beyond_ci"] in (-1, 0, 1)
    for n in (1, 3, 5):
        assert 0.0 <= row[f"belief.accuracy.after_{n}"] <= 1.0
    assert 1.0 / row["k"] - 1e-9 <= row["belief.max_posterior"] <= 1.0 + 1e-9
    by_type = [row[f"belief.by_type.{n}"] for n in names]
    assert row["belief.accuracy.after_5"] == pytest.approx(sum(by_type) / len(by_type))
    shares = row["belief.identified"] + row["belief.split"] + row["belief.merged"]
    assert 0.0 <= shares <= 1.0 + 1e-9


def test_a_suite_task_sweeps_through_the_api_and_the_cli(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    world = make_task("tool_handover")
    api = torchhrc.sweep("tool_handover", GRID, seeds="0-1", quick=True, out=tmp_path / "api",
                         executor=SerialExecutor(), summary=False)  # fmt: skip
    assert not api.failed and len(api.rows) == 2 * 2
    assert [(r["noise"], r["seed"]) for r in api.rows] == [(0.0, 0), (0.0, 1), (0.1, 0), (0.1, 1)]
    for row in api.rows:
        _check_row(row, world)
    # a row is task_metrics of its cell and seed (the job passes every parameter on)
    row = api.rows[3]
    cell = {name: row[name] for name in GRID}
    direct = task_metrics(world, seed=1, quick=True, **cell)
    assert row["return.type-aware.mean"] == pytest.approx(direct["return"]["type-aware"]["mean"])
    assert row["belief.accuracy.after_5"] == pytest.approx(direct["belief"]["accuracy"]["after_5"])
    # k and ARI by an independent path: the cell's demonstrations, learn(), the ARI
    demos, truth = world.demonstrations(subjects=4, per_subject=2, noise=0.1, seed=1)
    model = torchhrc.learn(world.task, demos, seed=1, restarts=QUICK["restarts"],
                           solver_time=QUICK["solver_time"])  # fmt: skip
    assert row["k"] == model.num_types
    assert row["ari"] == pytest.approx(
        torchhrc.adjusted_rand_index(truth.tolist(), model.assignments.tolist())
    )
    # the CLI, in a worker process: the same rows; --resume runs nothing new
    argv = ["sweep", "tool_handover", "--param", "noise=0,0.1", "--param", "subjects=4",
            "--param", "per_subject=2", "--param", "episodes=10", "--seeds", "0-1", "--quick",
            "--workers", "1", "--out", str(tmp_path / "cli"), "--no-progress"]  # fmt: skip
    assert main(argv) == 0
    assert json.loads(capsys.readouterr().out)["finished"] == 4
    cli_rows = _csv_rows(tmp_path / "cli" / "results.csv")
    api_rows = _csv_rows(tmp_path / "api" / "results.csv")
    assert _untimed(cli_rows) == _untimed(api_rows)
    assert "ari" in cli_rows[0] and "k" in cli_rows[0] and "true_k" in cli_rows[0]
    summary = (tmp_path / "cli" / "summary.md").read_text()
    assert "# Sweep: tool_handover" in summary and "true_k = 2" in summary
    assert "by_type" not in summary  # per-type columns stay in results.csv
    # resume (the API on the CLI's directory): nothing runs again
    finished = read_results(tmp_path / "cli")
    again = torchhrc.sweep(
        "tool_handover",
        GRID,
        seeds="0-1",
        quick=True,
        resume=True,
        out=tmp_path / "cli",
        executor=SerialExecutor(),
        summary=False,
    )
    assert again.skipped == 4 and read_results(tmp_path / "cli") == finished


def test_a_users_factory_from_a_file_sweeps(tmp_path: Path) -> None:
    """A factory named by its file's path, and the same factory given itself."""
    task = f"{WORLD_FILE}:assembly"
    grid = {"subjects": [4, 6], "per_subject": [2], "episodes": [6]}
    by_name = torchhrc.sweep(task, grid, seeds=[0], quick=True, out=tmp_path / "name",
                             executor=SerialExecutor(), summary=False)  # fmt: skip
    factory = load_callable(task)
    world = factory()
    assert not by_name.failed and [r["subjects"] for r in by_name.rows] == [4, 6]
    for row in by_name.rows:
        _check_row(row, world)
    assert json.loads((tmp_path / "name" / "sweep.json").read_text())["task"] == task
    itself = torchhrc.sweep(factory, grid, seeds=[0], quick=True, out=tmp_path / "itself",
                            executor=SerialExecutor(), summary=False)  # fmt: skip
    assert _untimed(itself.rows) == _untimed(by_name.rows)
    # a suite task's factory given itself is recorded by its name
    assert canonical_task(torchhrc.tasks.suite.SUITE["pace"]) == "pace"


def test_a_module_next_to_the_caller_is_found_as_its_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # `torchhrc sweep my_world:make` from the folder of my_world.py: a console script does
    # not put that folder on sys.path, so the name resolves to the file (the same task
    # string as `./my_world.py:make`, so both spellings resume the same sweep)
    (tmp_path / "my_world_26.py").write_text(
        "from torchhrc.tasks.suite import make_task\n\n\ndef make():\n"
        "    return make_task('pace')\n"
    )
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr("sys.path", [p for p in sys.path if p not in ("", ".", str(tmp_path))])
    by_module = canonical_task("my_world_26:make")
    assert by_module == canonical_task("./my_world_26.py:make")
    assert by_module == f"{(tmp_path / 'my_world_26.py').resolve()}:make"
    assert load_callable(by_module)().task.name == "pace"
    # a module the interpreter can import keeps its module form (relative imports work)
    assert canonical_task("torchhrc.tasks.suite:make_task") == "torchhrc.tasks.suite:make_task"
    with pytest.raises(ModelError, match=r"name the file, 'path/to/nowhere_26\.py:make'"):
        load_callable("nowhere_26:make")


@pytest.mark.parametrize(
    ("params", "match"),
    [
        ({"bogus": [1]}, "no sweep parameter 'bogus'"),
        ({"subjects": [2.5]}, "--param subjects values of type int"),
        ({"noise": [1.5]}, r"--param noise values in \[0.0, 1.0\]"),
        ({"criterion": ["aic"]}, "--param criterion values in {icl_or_gain, "),
        ({"human_model": ["markov"]}, "--param human_model values in {auto, chain, state}"),
        ({"order": ["4"]}, "--param order values in {1, 2, 3, auto}"),
        ({"episodes": [1]}, "--param episodes values in"),
        ({"k": [0]}, "--param k values in"),
        ({"k_min": [2, 4], "k_max": [3]}, "k_min <= k_max in every cell, got k_min = 4, k_max = 3"),
        ({"k_min": [7]}, r"k_max = 6 \(learn\(\)'s default\)"),
    ],
)
def test_a_bad_task_parameter_is_named(tmp_path: Path, params: dict, match: str) -> None:
    with pytest.raises(ModelError, match=match):
        torchhrc.sweep("pace", params, out=tmp_path / "x")
    assert not (tmp_path / "x").exists()


def test_what_cannot_be_swept_is_refused_before_anything_is_written(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "x"
    with pytest.raises(TypeError, match="pass the module-level function that builds it"):
        torchhrc.sweep(make_task("pace"), {}, out=out)
    with pytest.raises(ModelError, match="read as a task factory, but it returned dict"):
        torchhrc.sweep(f"{WORLD_FILE}:not_a_world", {}, out=out)
    with pytest.raises(ModelError, match=r"'seed' keyword argument .* or no argument"):
        torchhrc.sweep(f"{WORLD_FILE}:needs_size", {}, out=out)
    with pytest.raises(ModelError, match="expected a task"):
        torchhrc.sweep("no_such_suite_task", {}, out=out)
    with pytest.raises(ModelError, match="no parameter 'bogus'"):
        task_metrics(make_task("pace"), seed=0, bogus=1)
    assert not out.exists()
    assert main(["sweep", "pace", "--param", "criterion=aic", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--param criterion values in" in err
    assert not out.exists()


def test_a_jobs_warnings_are_counted_not_printed(
    recwarn: pytest.WarningsRecorder, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Noise-free demonstrations of fetch_order at 30 x 4: under Abbeel-Ng's projection IRL
    (learn()'s rule forced to "dominant"; its default "maxent" does not warn) the margin
    stays above its noise floor (0), so learn() warns; the row counts the warnings and none
    escapes."""
    import functools
    import warnings

    from torchhrc.tasks import pipeline

    monkeypatch.setattr(pipeline, "IRLConfig", functools.partial(pipeline.IRLConfig,
                                                                 rule="dominant"))  # fmt: skip
    world = make_task("fetch_order")
    with warnings.catch_warnings():
        warnings.simplefilter("always")
        metrics = task_metrics(world, seed=0, quick=True, subjects=30, per_subject=4, noise=0.0,
                               episodes=4)  # fmt: skip
    assert metrics["warnings"].get("IRLConvergenceWarning", 0) >= 1
    assert sum(metrics["warnings"].values()) <= 8
    assert not [w for w in recwarn if w.category.__name__ == "IRLConvergenceWarning"]


def test_quick_settings_reach_learn_and_the_evaluation() -> None:
    """quick: 3 restarts, a 1 s solver limit, 50 episodes; a cell's own value wins."""
    world = make_task("pace")
    quick = task_metrics(world, seed=0, quick=True, subjects=3, per_subject=2, k=1)
    assert math.isfinite(quick["return"]["type-aware"]["mean"])
    # one learned type: the type-aware robot is the type-agnostic one (same settings)
    assert quick["k"] == 1 and quick["gain"]["mean"] == pytest.approx(0.0, abs=1e-12)
    assert quick["ari"] == pytest.approx(0.0)


def test_text_parameters_are_plotted_at_their_grid_positions(tmp_path: Path) -> None:
    """A summary over a text parameter (criterion=bic,icl_or_gain) plots categories in grid
    order instead of failing to read them as numbers (the function sweep's ``label``)."""
    from torchhrc.experiments.sweep import SweepSpec, write_summary

    task = str(Path(__file__).with_name("sweep_task.py")) + ":simulate"
    grid = {"label": ["bb", "a", "ccc"], "subjects": [3, 5]}
    result = torchhrc.sweep(task, grid, seeds=[0], out=tmp_path / "s", executor=SerialExecutor(),
                            summary=False)  # fmt: skip
    spec = SweepSpec.create(task, grid, seeds=[0])
    write_summary(tmp_path / "s", spec, [{k: v for k, v in r.items() if k != "pid"}
                                         for r in result.rows])  # fmt: skip
    summary = (tmp_path / "s" / "summary.md").read_text()
    assert "## long_label" in summary and "| bb | 3 | 2 |" in summary
    assert (tmp_path / "s" / "long_label.png").stat().st_size > 1000


def test_the_sweep_docstring_names_every_task_parameter() -> None:
    # help(torchhrc.sweep) is where a user looks first: it lists what a cell can set
    from torchhrc.experiments.task_sweep import TASK_PARAMETERS

    missing = [name for name in TASK_PARAMETERS if f"``{name}``" not in torchhrc.sweep.__doc__]
    assert not missing, f"torchhrc.sweep's docstring does not name {missing}"
