"""Sweeps: grid parsing, streaming and resume, executors agree, CLI errors (exit 2)."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest

from torchhrc.cli import main
from torchhrc.errors import ModelError
from torchhrc.experiments import sweep as sweep_module
from torchhrc.experiments.sweep import (
    LocalExecutor,
    SerialExecutor,
    SweepSpec,
    flatten_scalars,
    is_timing_column,
    parse_seeds,
    read_results,
    run_sweep,
)

#: Small place-and-drill jobs (quick study, 2 runs per subject): a second or two each.
GRID = ["subjects=2,4", "runs=2"]


def _untimed(rows: list[dict]) -> list[dict]:
    return [{k: v for k, v in row.items() if not is_timing_column(k)} for row in rows]


def _csv_rows(path: Path) -> list[dict]:
    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))


def test_grid_is_the_product_of_the_values_with_seeds_innermost() -> None:
    spec = SweepSpec.create("place-and-drill", ["subjects=2,4", "noise=0,0.1"], seeds="3-4")
    jobs = spec.jobs()
    assert len(jobs) == 2 * 2 * 2
    assert [dict(j.params) for j in jobs[:2]] == [{"subjects": 2, "noise": 0.0}] * 2
    assert [j.seed for j in jobs[:2]] == [3, 4]
    assert {type(v) for j in jobs for _, v in j.params} == {int, float}
    assert len({j.key for j in jobs}) == len(jobs)


@pytest.mark.parametrize(
    ("params", "match"),
    [
        (["bogus=1"], "no sweep parameter 'bogus'"),
        (["subjects=2.5"], "of type int"),
        (["noise=abc"], "of type float"),
        (["noise=1.5"], r"in \[0.0, 1.0\]"),
        (["subjects=1"], "in \\[2, None\\]"),
        (["subjects=2,2"], "repeats a value"),
        (["subjects=2", "subjects=4"], "given twice"),
        (["subjects"], "NAME=V1,V2"),
    ],
)
def test_bad_parameters_are_rejected_by_name(params: list[str], match: str) -> None:
    with pytest.raises(ModelError, match=match):
        SweepSpec.create("place-and-drill", params)


def test_unknown_task_and_bad_seeds() -> None:
    with pytest.raises(ModelError, match="expected a task"):
        SweepSpec.create("juggling", [])
    for bad in ("", "a-b", "4-2", "-1"):
        with pytest.raises(ModelError, match="seeds"):
            parse_seeds(bad)
    assert parse_seeds("0-2,5,1") == (0, 1, 2, 5)


def test_flatten_keeps_numbers_only() -> None:
    flat = flatten_scalars(
        {"a": 1, "b": {"c": [1.0, 3.0], "d": "x", "e": None, "f": [{"g": 1}]}, "h": True}
    )
    assert flat == {"a": 1, "b.c.0": 1.0, "b.c.1": 3.0, "b.c.mean": 2.0, "h": True}


def test_serial_and_two_process_sweeps_write_the_same_results(tmp_path: Path) -> None:
    spec = SweepSpec.create("place-and-drill", GRID, seeds="0-1", quick=True)
    serial = run_sweep(spec, tmp_path / "serial", executor=SerialExecutor(), summary=False)
    pooled = run_sweep(spec, tmp_path / "pooled", executor=LocalExecutor(workers=2))
    assert not serial.failed and not pooled.failed
    assert len(serial.rows) == 4
    assert _untimed(serial.rows) == _untimed(pooled.rows)
    # the CSV holds one row per job, parameters and seed first, timing last
    rows = _csv_rows(tmp_path / "pooled" / "results.csv")
    assert len(rows) == 4
    header = list(rows[0])
    assert header[:3] == ["subjects", "runs", "seed"] and header[-1] == "wall_s"
    assert {(r["subjects"], r["seed"]) for r in rows} == {("2", "0"), ("2", "1"), ("4", "0"),
                                                          ("4", "1")}  # fmt: skip
    # the summary and one plot per varying headline metric
    summary = (tmp_path / "pooled" / "summary.md").read_text()
    assert "## loo_accuracy" in summary and "| 4 | 2 |" in summary
    assert (tmp_path / "pooled" / "loo_accuracy.png").stat().st_size > 1000


def test_resume_after_a_crash_runs_only_the_missing_jobs(tmp_path: Path) -> None:
    spec = SweepSpec.create("place-and-drill", GRID, seeds="0-1", quick=True)
    full = run_sweep(spec, tmp_path / "full", executor=SerialExecutor(), summary=False)
    out = tmp_path / "crashed"
    out.mkdir()
    (out / "sweep.json").write_text(json.dumps(spec.to_json()))
    lines = (tmp_path / "full" / "results.jsonl").read_text().splitlines()
    # the driver died while writing the third row: two whole rows and a torn line remain
    (out / "results.jsonl").write_text("\n".join(lines[:2]) + "\n" + lines[2][:25])
    assert len(read_results(out)) == 2
    resumed = run_sweep(spec, out, executor=SerialExecutor(), resume=True, summary=False)
    assert resumed.skipped == 2
    assert _untimed(resumed.rows) == _untimed(full.rows)
    assert len(_csv_rows(out / "results.csv")) == 4
    # a finished sweep resumes to nothing
    again = run_sweep(spec, out, executor=SerialExecutor(), resume=True, summary=False)
    assert again.skipped == 4


def test_resume_refuses_another_sweep_and_new_sweeps_refuse_a_full_dir(tmp_path: Path) -> None:
    spec = SweepSpec.create("place-and-drill", ["subjects=2", "runs=2"], quick=True)
    run_sweep(spec, tmp_path, executor=SerialExecutor(), summary=False)
    other = SweepSpec.create("place-and-drill", ["subjects=4", "runs=2"], quick=True)
    with pytest.raises(ModelError, match="another sweep"):
        run_sweep(other, tmp_path, executor=SerialExecutor(), resume=True)
    with pytest.raises(ModelError, match="not empty"):
        run_sweep(spec, tmp_path, executor=SerialExecutor())
    with pytest.raises(ModelError, match=r"no sweep\.json"):
        run_sweep(spec, tmp_path / "fresh", executor=SerialExecutor(), resume=True)


def test_a_failing_job_is_retried_then_reported(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    calls: list[int] = []

    def flaky(params: dict, seed: int, quick: bool) -> dict:
        calls.append(seed)
        if seed == 1 or calls.count(seed) == 1:  # seed 0 fails once, seed 1 always
            raise RuntimeError(f"boom {seed}")
        return {"value": float(seed)}

    monkeypatch.setitem(sweep_module._RUNNERS, "place-and-drill", flaky)
    spec = SweepSpec.create("place-and-drill", [], seeds="0-1")
    result = run_sweep(spec, tmp_path, executor=SerialExecutor(retries=1))
    assert calls == [0, 0, 1, 1]
    assert [r["value"] for r in result.rows] == [0.0]
    assert list(result.failed) == ["|seed=1"] and "boom 1" in result.failed["|seed=1"]
    assert "Failed jobs" in (tmp_path / "summary.md").read_text()


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--param", "bogus=1"], "no sweep parameter 'bogus'"),
        (["--param", "subjects=two"], "of type int"),
        (["--seeds", "x"], "seeds"),
        (["--ray", "127.0.0.1:1"], "cannot reach the Ray cluster"),
        (["--ray", "nonsense"], "HOST:PORT"),
        (["--ray", "127.0.0.1:1", "--workers", "2"], "sets the CPUs of a local Ray cluster"),
        (["--retries", "-1"], "--retries >= 0"),
    ],
)
def test_cli_bad_input_is_one_line_exit_2_and_writes_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], argv: list[str], message: str
) -> None:
    out = tmp_path / "out"
    if argv[0] == "--ray":
        pytest.importorskip("ray", reason="the [ray] extra is not installed")
    code = main(["sweep", "place-and-drill", "--out", str(out), "--no-progress", *argv])
    err = capsys.readouterr().err
    assert code == 2
    assert message in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_cli_runs_a_small_sweep(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "cli"
    argv = ["sweep", "place-and-drill", "--param", "subjects=2", "--param", "runs=2",
            "--quick", "--workers", "1", "--out", str(out), "--no-progress"]  # fmt: skip
    assert main(argv) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["finished"] == 1 and summary["failed"] == []
    assert main(argv) == 2  # the directory is not empty now
    assert main([*argv, "--resume"]) == 0
    assert json.loads(capsys.readouterr().out.strip().splitlines()[-1])["skipped"] == 1


_DIES_ONCE = """
import os
import time
from pathlib import Path

HERE = Path(__file__).parent


def job(task, params, seed, quick):
    tries = len(list(HERE.glob(f"start-{seed}-*")))
    (HERE / f"start-{seed}-{tries}").touch()
    if seed == 0 and tries == 0:
        # die once the driver holds every other job's result (at most 5 minutes)
        for _ in range(6000):
            if all((HERE / f"received-{s}").exists() for s in range(1, 6)):
                break
            time.sleep(0.05)
        os._exit(3)  # the worker process dies
    return {"value": float(seed)}
"""


def test_local_executor_survives_a_dead_worker_and_reruns_nothing_that_finished(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Seed 0 kills its worker after the other 5 jobs finished: it alone runs again."""
    import importlib
    import sys

    (tmp_path / "dies_once.py").write_text(_DIES_ONCE)
    monkeypatch.syspath_prepend(str(tmp_path))  # spawn workers inherit sys.path
    module = importlib.import_module("dies_once")
    spec = SweepSpec.create("place-and-drill", [], seeds="0-5")
    executor = LocalExecutor(workers=2, retries=1, function=module.job)
    results = {}
    for job, row in executor.run(spec, spec.jobs()):
        results[job.seed] = row
        (tmp_path / f"received-{job.seed}").touch()
    sys.modules.pop("dies_once")
    assert results == {s: {"value": float(s)} for s in range(6)}
    starts = {s: len(list(tmp_path.glob(f"start-{s}-*"))) for s in range(6)}
    assert starts == {0: 2, 1: 1, 2: 1, 3: 1, 4: 1, 5: 1}  # the crash and its retry only


def test_local_executor_reports_a_job_whose_worker_always_dies(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import importlib
    import sys

    (tmp_path / "dying_job.py").write_text(
        "import os\n\ndef job(task, params, seed, quick):\n"
        "    if seed == 1:\n        os._exit(3)\n    return {'value': float(seed)}\n"
    )
    monkeypatch.syspath_prepend(str(tmp_path))
    module = importlib.import_module("dying_job")
    spec = SweepSpec.create("place-and-drill", [], seeds="0-2")
    results = dict(LocalExecutor(workers=1, retries=1, function=module.job).run(spec, spec.jobs()))
    sys.modules.pop("dying_job")
    by_seed = {job.seed: row for job, row in results.items()}
    assert by_seed[0] == {"value": 0.0} and by_seed[2] == {"value": 2.0}
    assert "BrokenProcessPool" in type(by_seed[1]).__name__


# --- a user's own task: torchhrc.sweep and `torchhrc sweep module:function` ------------------

USER_TASK = str(Path(__file__).with_name("sweep_task.py")) + ":simulate"
USER_GRID = {"subjects": [4, 8], "noise": [0.1, 0.5]}


def _comparable(rows: list[dict]) -> list[dict]:
    """Rows without the timing and the worker's process id."""
    return [{k: v for k, v in r.items() if k != "pid" and not is_timing_column(k)} for r in rows]


def test_a_users_function_sweeps_like_a_study(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """torchhrc.sweep over a function: the studies' files, resume; the CLI gives the same."""
    import torchhrc
    from torchhrc.experiments.sweep import load_callable

    function = load_callable(USER_TASK)
    api = torchhrc.sweep(function, USER_GRID, seeds="0-2", out=tmp_path / "api",
                         executor=SerialExecutor())  # fmt: skip
    assert not api.failed and len(api.rows) == 2 * 2 * 3
    # each row is the function's own value for its cell and seed
    for row in api.rows:
        expected = function(seed=row["seed"], subjects=row["subjects"], noise=row["noise"])
        assert row["error_rate"] == expected["error_rate"]
        assert row["score.mean"] == expected["score"]["mean"]
    assert json.loads((tmp_path / "api" / "sweep.json").read_text())["task"] == USER_TASK
    summary = (tmp_path / "api" / "summary.md").read_text()
    assert "## error_rate" in summary and "| 8 | 0.5 |" in summary
    assert (tmp_path / "api" / "error_rate.png").stat().st_size > 1000
    # the CLI, in a worker process, by the file's path
    argv = ["sweep", USER_TASK, "--param", "subjects=4,8", "--param", "noise=0.1,0.5",
            "--seeds", "0-2", "--workers", "1", "--out", str(tmp_path / "cli"),
            "--no-progress"]  # fmt: skip
    assert main(argv) == 0
    assert json.loads(capsys.readouterr().out)["finished"] == 12
    assert _comparable(_csv_rows(tmp_path / "cli" / "results.csv")) == _comparable(
        _csv_rows(tmp_path / "api" / "results.csv")
    )
    before = (tmp_path / "cli" / "summary.md").stat().st_mtime_ns
    assert main([*argv, "--resume"]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed["skipped"] == 12 and printed["ran"] == 0 and printed["finished"] == 12
    # nothing left to run: the summary and its plots are kept as they are
    assert (tmp_path / "cli" / "summary.md").stat().st_mtime_ns == before


def test_a_users_function_parameters_are_checked_against_its_signature(tmp_path: Path) -> None:
    from torchhrc.experiments.sweep import sweep

    task_file = str(Path(__file__).with_name("sweep_task.py"))
    for params, match in (
        ({"bogus": [1]}, "no sweep parameter 'bogus'"),
        ({"subjects": [2.5]}, "of type int"),
        ({"noise": ["x"]}, "of type float"),
        ({"subjects": [4, 4]}, "repeats a value"),
    ):
        with pytest.raises(ModelError, match=match):
            sweep(USER_TASK, params, out=tmp_path / "x")
    with pytest.raises(ModelError, match="'seed' keyword"):
        sweep(f"{task_file}:no_seed", {}, out=tmp_path / "x")
    with pytest.raises(ModelError, match="has no function 'missing'"):
        sweep(f"{task_file}:missing", {}, out=tmp_path / "x")
    with pytest.raises(ModelError, match="cannot import"):
        sweep("no_such_module_here:run", {}, out=tmp_path / "x")
    with pytest.raises(ModelError, match="module-level function"):
        sweep(lambda seed: {}, {}, out=tmp_path / "x")
    assert not (tmp_path / "x").exists()
    # **kwargs: any name, values read as int, float or text
    spec = SweepSpec.create(f"{task_file}:anything", ["n=1,2.5,abc"])
    assert [dict(j.params)["n"] for j in spec.jobs()] == [1, 2.5, "abc"]
    rows = run_sweep(spec, tmp_path / "any", executor=SerialExecutor(), summary=False).rows
    assert [r["count"] for r in rows] == [1.0] * 3


def test_killing_the_driver_then_resume_gives_the_uninterrupted_results(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """SIGKILL the sweep CLI (its process group) after 2 of 6 jobs; --resume finishes."""
    import os
    import signal
    import subprocess
    import sys
    import time

    from torchhrc.experiments.sweep import sweep

    sweep(
        USER_TASK,
        {"subjects": [4, 8]},
        seeds="0-2",
        out=tmp_path / "ref",
        executor=SerialExecutor(),
    )  # the reference, uninterrupted
    out, gate = tmp_path / "killed", tmp_path / "gate"
    gate.mkdir()
    argv = ["sweep", USER_TASK, "--param", "subjects=4,8", "--seeds", "0-2", "--workers", "1",
            "--out", str(out), "--no-progress"]  # fmt: skip
    env = {**os.environ, "SWEEP_TEST_GATE": str(gate)}  # seeds >= 2 wait for gate/go
    driver = subprocess.Popen([sys.executable, "-m", "torchhrc.cli", *argv], env=env,
                              start_new_session=True, stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL)  # fmt: skip
    try:
        for _ in range(6000):  # until 2 jobs finished (at most 5 minutes)
            if len(read_results(out)) >= 2 or driver.poll() is not None:
                break
            time.sleep(0.05)
    finally:
        os.killpg(driver.pid, signal.SIGKILL)  # the driver and its worker
        driver.wait()
    assert driver.returncode == -signal.SIGKILL
    assert len(read_results(out)) == 2  # (4, seed 0), (4, seed 1); (4, seed 2) was waiting
    (gate / "go").touch()
    assert main([*argv, "--resume"]) == 0
    assert json.loads(capsys.readouterr().out)["skipped"] == 2
    assert _comparable(_csv_rows(out / "results.csv")) == _comparable(
        _csv_rows(tmp_path / "ref" / "results.csv")
    )


def test_ray_runs_jobs_on_workers_and_retries_a_killed_worker(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Jobs run as Ray tasks in Ray worker processes (not the driver); seed 0's worker is
    SIGKILLed on its first try, Ray retries it, and the rows equal the serial ones. Issue 30:
    RayExecutor.run replaced by a serial run fails the pid check, by a local process pool
    fails the Ray task ids."""
    import os

    ray = pytest.importorskip("ray", reason="the [ray] extra is not installed")
    from torchhrc.experiments.sweep import sweep

    grid = {"subjects": [4]}
    serial = sweep(USER_TASK, grid, seeds="0-3", out=tmp_path / "serial",
                   executor=SerialExecutor())  # fmt: skip
    markers = tmp_path / "markers"
    markers.mkdir()
    monkeypatch.setenv("SWEEP_TEST_MARKERS", str(markers))  # Ray's workers inherit it
    monkeypatch.setenv("SWEEP_TEST_KILL", "1")
    monkeypatch.setenv("SWEEP_TEST_DRIVER", str(os.getpid()))  # never kill the test itself
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        on_ray = sweep(USER_TASK, grid, seeds="0-3", out=tmp_path / "ray", ray="local",
                       retries=2)  # fmt: skip
        assert ray.is_initialized()  # the executor leaves a cluster it did not start
    finally:
        ray.shutdown()
    assert not on_ray.failed
    assert {row["pid"] for row in on_ray.rows}.isdisjoint({os.getpid()})
    assert len(list(markers.glob("start-0-*"))) == 2  # killed, then retried by Ray
    # each job ended as a Ray task (a local process pool in RayExecutor.run's place: pids
    # other than the driver's, seed 0 retried, the same rows; but no Ray task id)
    tasks = {seed: (markers / f"end-{seed}").read_text() for seed in range(4)}
    assert all(tasks.values()) and len(set(tasks.values())) == 4, tasks
    assert _comparable(on_ray.rows) == _comparable(serial.rows)


def test_a_sweep_started_while_a_worker_imports_the_script_says_to_guard_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    # a spawn worker runs the user's script as __mp_main__ with _inheriting set; an unguarded
    # top-level sweep() there used to fail on the non-empty out ("use --resume"), every job
    # then reported only as a dead worker (BrokenProcessPool)
    import multiprocessing

    from torchhrc.experiments.sweep import sweep

    out = tmp_path / "sweep"
    monkeypatch.setattr(multiprocessing.current_process(), "_inheriting", True, raising=False)
    with pytest.raises(RuntimeError, match=r"if __name__ == \"__main__\""):
        sweep("tool_handover", {"subjects": [4]}, out=out, quick=True, executor=SerialExecutor())
    assert not out.exists()  # nothing written


def test_an_interrupted_local_sweep_ends_its_workers_at_once(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Ctrl-C while seed 2 runs: the worker is ended, not waited for (seed 2 never ends,
    though its gate opens 1 s after the interrupt, which a waiting shutdown would see)."""
    import os
    import signal
    import threading
    import time

    markers, gate = tmp_path / "markers", tmp_path / "gate"
    markers.mkdir()
    gate.mkdir()
    monkeypatch.setenv("SWEEP_TEST_MARKERS", str(markers))
    monkeypatch.setenv("SWEEP_TEST_GATE", str(gate))  # seeds >= 2 wait for gate/go
    spec = SweepSpec.create(USER_TASK, [], seeds="0-2")

    def interrupt_when_seed_2_runs() -> None:
        for _ in range(1200):
            if list(markers.glob("start-2-*")):
                break
            time.sleep(0.05)
        os.kill(os.getpid(), signal.SIGINT)  # the main thread waits on the pool
        time.sleep(1.0)
        (gate / "go").touch()

    if threading.current_thread() is not threading.main_thread():
        pytest.skip("a signal reaches only the main thread")
    # Python's own Ctrl-C handler: pytest-xdist's workers ignore SIGINT (their controller
    # stops them), where a user's script gets KeyboardInterrupt
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    rows = {}
    threading.Thread(target=interrupt_when_seed_2_runs, daemon=True).start()
    try:
        with pytest.raises(KeyboardInterrupt):
            for job, row in LocalExecutor(workers=1, retries=0).run(spec, spec.jobs()):
                rows[job.seed] = row
    finally:
        signal.signal(signal.SIGINT, previous)
    assert sorted(rows) == [0, 1]
    time.sleep(1.5)  # past the gate's opening: a worker still alive would end seed 2 now
    assert list(markers.glob("start-2-*")) and not (markers / "end-2").exists()
