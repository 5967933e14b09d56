"""Scripted figures of the documentation: each marked block of README.md and docs/*.md is
the output of one function here.

The rule (docs/index.md, "Where the numbers come from"): every number in README.md and
docs/*.md either comes from a script or is labelled a one-off with its date and commit.
Scripted figures live between markers::

    <!-- figures: NAME -->
    ...the text NAME() prints...
    <!-- /figures: NAME -->

or, for one line, an inline marker at the end of the line (``<!-- figure: NAME -->``): the
line's numbers are NAME()'s, in order. ``tests/test_docs_figures.py`` regenerates every cheap
block (seconds each) and fails when a number in the docs drifts from the script's; the
expensive ones (``CHEAP[name] = False``) are checked only with ``TORCHHRC_DOC_FIGURES=all``.

Run: ``python docs/_ext/figures.py [--write] [NAME ...]`` prints the blocks (all, or those
named), or with ``--write`` rewrites them in place in the docs.
"""

from __future__ import annotations

import argparse
import functools
import re
import sys
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]

BLOCK = re.compile(
    r"<!-- figures: (?P<name>[\w-]+) -->\n(?P<body>.*?)<!-- /figures: (?P=name) -->", re.S
)
INLINE = re.compile(r"^(?P<line>.*)<!-- figure: (?P<name>[\w-]+) -->[ \t]*$", re.M)
NUMBER = re.compile(r"[-+]?\d+(?:\.\d+)?(?:e[-+]?\d+)?")


def online_cross_training_by_type(seed: int = 0) -> str:
    """Online cross-training of the default place-and-drill study split by the true type.

    The same runs as ``reward_online["cross_training"]`` of ``torchhrc reproduce
    place-and-drill`` (default settings): per fold the pooled cross-training MDP of the
    training subjects, the held-out subject's turn taking, the online case's generator
    (seeded ``seed``, shared by the folds in order; the MOMDP controllers draw nothing, so
    leaving them out leaves every draw as in the study).
    """
    import torch

    from torchhrc.experiments.online import human_chunk_size, pooled_cross_training
    from torchhrc.experiments.place_and_drill import StudySettings
    from torchhrc.experiments.robustness import simulate_subject
    from torchhrc.tasks.place_and_drill.demos import simulate_study
    from torchhrc.tasks.place_and_drill.hand_coded import load_expert_model
    from torchhrc.tasks.place_and_drill.model import EMPTY, PLACED
    from torchhrc.tasks.place_and_drill.simulate import demonstrated_orders

    s = StudySettings(seed=seed)
    demos = simulate_study(
        n_subjects=s.subjects, n_demos=s.demos, n_positions=s.positions, noise=s.noise, seed=seed
    )
    expert = load_expert_model()
    task = expert.task
    labels: dict[str, str] = {}
    for subject, label in zip(demos.subjects, demos.types or ()):
        labels.setdefault(subject, label)
    orders = demonstrated_orders(task, demos)
    score = expert.reward()
    generator = torch.Generator().manual_seed(seed)
    status = task.status
    E = len(s.epsilons)
    rows: dict[str, list[torch.Tensor]] = {"safe": [], "efficient": []}
    traces = []
    for subject in demos.unique_subjects:
        label = labels[subject]
        train = demos.subset(torch.tensor([x != subject for x in demos.subjects]))
        policy = pooled_cross_training(task, train, discount=expert.discount)
        result = simulate_subject(
            task,
            momdp_policies={},
            cross_training=policy,
            subject_index=0,
            orders=orders[subject],
            score=score[..., expert.type_names.index(label)],
            epsilons=s.epsilons,
            runs=s.runs,
            generator=generator,
            human_chunk=human_chunk_size(task, label),
            on_trace=lambda trace, eps, label=label: traces.append((label, trace)),
        )
        rows[label].append(result["cross_training"])  # (E, R)
    stuck: dict[str, list[torch.Tensor]] = {"safe": [], "efficient": []}
    idle_actions = [0, 0]  # efficient, epsilon 0, both idle: robot waits / drills no screw
    done: dict[str, list[torch.Tensor]] = {"safe": [], "efficient": []}
    for label, trace in traces:
        x = trace.states["cross_training"]  # (H + 1, B)
        a = trace.actions["cross_training"]  # (H, B)
        before, after = x[:-1], x[1:]
        pending = (status[before] == PLACED).any(-1) & (status[before] == EMPTY).any(-1)
        idle = task.robot_effect[a, before] == before  # a wait or a drill of no placed screw
        both_wait = idle & pending & (after == before)  # neither the robot nor the person acts
        stuck[label].append(both_wait.sum(0).double().view(E, -1))
        if label == "efficient":
            first = both_wait.view(-1, E, both_wait.shape[-1] // E)[:, 0]  # epsilon 0
            acts = a.view(-1, E, a.shape[-1] // E)[:, 0][first]
            idle_actions[0] += int((acts == 0).sum())
            idle_actions[1] += int((acts != 0).sum())
        done[label].append((x[-1] == task.terminal_state).double().view(E, -1))
    lines = [
        "| epsilon | safe: reward | safe: finished | efficient: reward | efficient: finished "
        "| efficient: steps neither acts | all: reward |",
        "|---:|---:|---:|---:|---:|---:|---:|",
    ]
    safe, efficient = torch.stack(rows["safe"], 1), torch.stack(rows["efficient"], 1)
    both = torch.cat([safe, efficient], 1)  # (E, S, R)
    fin = {k: torch.stack(v, 1) for k, v in done.items()}
    st = torch.stack(stuck["efficient"], 1)
    for e, eps in enumerate(s.epsilons):
        lines.append(
            f"| {eps:.1f} | {float(safe[e].mean()):.2f} | {float(fin['safe'][e].mean()):.2f} "
            f"| {float(efficient[e].mean()):.2f} | {float(fin['efficient'][e].mean()):.2f} "
            f"| {float(st[e].mean()):.2f} | {float(both[e].mean()):.2f} |"
        )
    lines.append("")
    lines.append(
        f"Epsilon 0, efficient subjects, steps where neither acts: the robot waits in "
        f"{idle_actions[0]}, drills a position with no placed screw in {idle_actions[1]}."
    )
    return "\n".join(lines) + "\n"


@functools.cache
def _example(name: str) -> str:
    """What ``examples/NAME.py`` prints (run in this process, warnings silenced)."""
    import contextlib
    import io
    import runpy
    import warnings

    out = io.StringIO()
    with contextlib.redirect_stdout(out), warnings.catch_warnings():
        warnings.simplefilter("ignore")
        runpy.run_path(str(ROOT / "examples" / f"{name}.py"), run_name="__main__")
    return out.getvalue()


def _your_own_task(robot: str) -> str:
    line = next(x for x in _example("your_own_task").splitlines() if x.startswith(robot))
    mean, half = (float(v) for v in re.findall(r"[-+]?\d+\.\d+", line)[:2])
    return f"({mean:.2f} ± {half:.2f})"


def your_own_task_aware() -> str:
    """Mean reward ± 95% CI of the type-aware robot (``examples/your_own_task.py``)."""
    return _your_own_task("type-aware")


def your_own_task_agnostic() -> str:
    """Mean reward ± 95% CI of the type-agnostic robot (``examples/your_own_task.py``)."""
    return _your_own_task("type-agnostic")


def your_own_task_true_model() -> str:
    """Mean reward ± 95% CI of the robot on the cooks' true model
    (``examples/your_own_task.py``, ``evaluate_task(true_model=True)``)."""
    return _your_own_task("true model")


@functools.cache
def _report(command: str) -> str:
    """``report.md`` of ``torchhrc reproduce COMMAND`` (default settings, seed 0), run in a
    temporary directory on one thread, as the command line runs it."""
    import tempfile

    import torch

    from torchhrc.commands.reproduce import PIPELINES  # type: ignore[attr-defined]

    module, _, function = PIPELINES[command].partition(":")
    run = getattr(__import__(module, fromlist=[function]), function)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        with tempfile.TemporaryDirectory() as out:
            run(out, seed=0)
            return (Path(out) / "report.md").read_text()
    finally:
        torch.set_num_threads(threads)


_TIMING = re.compile(r" \d+(?:\.\d+)? s,")


def _rows(lines: list[str], start: int) -> list[str]:
    """The table that begins at or after line ``start``."""
    first = next(i for i in range(start, len(lines)) if lines[i].startswith("|"))
    end = next((i for i in range(first, len(lines)) if not lines[i].startswith("|")), len(lines))
    return lines[first:end]


def hand_finishing_summary() -> str:
    """The default hand-finishing run's summary list, without its timings (the SARSOP solve
    time; the factored-vs-flat line, whose flat solve stops on a time limit)."""
    lines = _report("hand-finishing").splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("- MOMDP:"))
    end = next(i for i in range(start, len(lines)) if not lines[i].startswith("- "))
    keep = [_TIMING.sub("", line) for line in lines[start:end]
            if not line.startswith("- Factored vs flat")]  # fmt: skip
    return "\n".join(keep) + "\n"


def hand_finishing_noise_table() -> str:
    """The table of waiting and accuracy against observation noise (default run)."""
    lines = _report("hand-finishing").splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("| noise (m) |"))
    return "\n".join(_rows(lines, start)) + "\n"


def _place_and_drill_table(head: str) -> str:
    lines = _report("place-and-drill").splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(head))
    return "\n".join(_rows(lines, start)) + "\n"


def place_and_drill_offline_table() -> str:
    """The offline reward table (Fig. 3) of ``torchhrc reproduce place-and-drill``."""
    return _place_and_drill_table("Mean accumulated reward ± 95% CI half-width (over all runs")


def place_and_drill_online_table() -> str:
    """The online reward table of ``torchhrc reproduce place-and-drill``."""
    return _place_and_drill_table("Mean accumulated reward ± 95% CI half-width, online")


def place_and_drill_separation_table() -> str:
    """The SAPIEN separation table of ``torchhrc reproduce place-and-drill``."""
    return _place_and_drill_table("| case | policy | true type |")


def place_and_drill_irl_table() -> str:
    """The IRL weights of the first two folds (``torchhrc reproduce place-and-drill``)."""
    return _place_and_drill_table("| fold subject | cluster |")


#: name -> the function that prints the block.
FIGURES: dict[str, Callable[[], str]] = {
    "online-cross-training-by-type": online_cross_training_by_type,
    "your-own-task-aware": your_own_task_aware,
    "your-own-task-agnostic": your_own_task_agnostic,
    "your-own-task-true-model": your_own_task_true_model,
    "hand-finishing-summary": hand_finishing_summary,
    "hand-finishing-noise-table": hand_finishing_noise_table,
    "place-and-drill-offline-table": place_and_drill_offline_table,
    "place-and-drill-online-table": place_and_drill_online_table,
    "place-and-drill-separation-table": place_and_drill_separation_table,
    "place-and-drill-irl-table": place_and_drill_irl_table,
}
#: name -> cheap enough for the default test run (seconds).
CHEAP: dict[str, bool] = {
    "online-cross-training-by-type": True,
    "your-own-task-aware": True,  # the example: a few seconds
    "your-own-task-agnostic": True,
    "your-own-task-true-model": True,
    "hand-finishing-summary": False,  # the default run: 60-200 s
    "hand-finishing-noise-table": False,
    "place-and-drill-offline-table": False,  # the default run: 45-70 s
    "place-and-drill-online-table": False,
    "place-and-drill-separation-table": False,
    "place-and-drill-irl-table": False,
}


def blocks(text: str) -> list[tuple[str, str]]:
    """``[(name, body)]`` of the marked blocks and inline figures of a document."""
    out = [(m["name"], m["body"]) for m in BLOCK.finditer(text)]
    out += [(m["name"], m["line"]) for m in INLINE.finditer(text)]
    return out


def numbers(text: str) -> list[float]:
    """The numbers of ``text``, in order (markdown and HTML comments ignored)."""
    text = re.sub(r"<!--.*?-->", "", text, flags=re.S)
    return [float(v) for v in NUMBER.findall(text)]


#: A one-off label: "one-off", a date and a commit, in any order, on one line.
ONE_OFF = (
    re.compile(r"one-off", re.I),
    re.compile(r"\b\d{4}-\d{2}-\d{2}\b"),
    re.compile(r"\bcommit [0-9a-f]{7,40}\b"),
)


def is_label(line: str) -> bool:
    """Whether ``line`` holds a one-off label (:data:`ONE_OFF`)."""
    return all(p.search(line) for p in ONE_OFF)


#: A measured-looking number: decimals (counts and settings are integers or in code spans).
DECIMAL = re.compile(r"(?<![\w.])\d+\.\d+(?!\w|\.\d)")  # a full stop may follow
HEADING = re.compile(r"^(#{1,6}) ")
#: Decimals that are names, not figures: versions, issue and section numbers.
NOT_A_FIGURE = re.compile(
    r"\b(?:Python|Ray|SAPIEN|torch|gymnasium|numpy|version|issue|issues|section|goal|goals)"
    r"\s*(?:>=|==|<=)?\s*\d+(?:\.\d+)+|>=\s*3\.\d+|\b3\.1[0-9]\b",
    re.I,
)


def unlabelled(text: str) -> list[tuple[int, str]]:
    """``[(line number, line)]`` of the lines with a decimal number that is neither scripted
    (inside a figures block or on a line with an inline marker) nor covered by a one-off
    label (:data:`ONE_OFF`), in code fences and code spans excepted.

    A label covers the section it is written in (from its heading to the next heading of the
    same or a higher level) with all its subsections; a label above the first ``##`` heading
    covers the introduction, or the whole page when its line says "page".
    """
    lines = text.splitlines()
    scripted = [False] * len(lines)
    offsets = [0]
    for line in lines:
        offsets.append(offsets[-1] + len(line) + 1)
    for m in BLOCK.finditer(text):
        for i, start in enumerate(offsets[:-1]):
            if m.start() <= start < m.end():
                scripted[i] = True
    headings = []  # (line, level)
    fence = False
    for i, line in enumerate(lines):
        if line.startswith("```"):
            fence = not fence
        elif not fence and HEADING.match(line):
            headings.append((i, len(HEADING.match(line)[1])))

    def scope(i: int) -> tuple[int, int]:
        """The section (start, end) of line ``i`` at its innermost heading."""
        before = [(h, lv) for h, lv in headings if h <= i]
        if not before:
            return 0, len(lines)
        h, lv = before[-1]
        end = next((g for g, lg in headings if g > h and lg <= lv), len(lines))
        return h, end

    labels = [i for i, line in enumerate(lines) if is_label(line)]
    covered = [False] * len(lines)
    for i in labels:
        h, end = scope(i)
        if not [g for g, lv in headings if g <= i and lv >= 2]:
            first = next((g for g, lv in headings if lv >= 2), len(lines))
            # above the first ## heading: the introduction, or the page when it says so
            h, end = 0, len(lines) if "page" in lines[i].lower() else first
        for j in range(h, end):
            covered[j] = True
    out = []
    fence = False
    for i, line in enumerate(lines):
        if line.startswith("```"):
            fence = not fence
            continue
        if fence or scripted[i] or covered[i] or INLINE.match(line):
            continue
        bare = re.sub(r"`[^`]*`|<!--.*?-->|\]\([^)]*\)", "", line)
        bare = NOT_A_FIGURE.sub("", bare)
        if DECIMAL.search(bare):
            out.append((i + 1, line))
    return out


def write(names: list[str]) -> None:
    """Rewrite the named blocks in every document."""
    cache: dict[str, str] = {}
    for path in DOCS:
        text = path.read_text()

        def fill(m: re.Match[str]) -> str:
            name = m["name"]
            if names and name not in names:
                return m.group(0)
            cache.setdefault(name, FIGURES[name]())
            return f"<!-- figures: {name} -->\n{cache[name]}<!-- /figures: {name} -->"

        def fill_line(m: re.Match[str]) -> str:
            name = m["name"]
            if names and name not in names:
                return m.group(0)
            cache.setdefault(name, FIGURES[name]())
            tokens = iter(NUMBER.findall(cache[name]))
            line = NUMBER.sub(lambda _: next(tokens), m["line"])
            if next(tokens, None) is not None:
                raise SystemExit(f"the line of {name} has fewer numbers than it prints")
            return f"{line}<!-- figure: {name} -->"

        new = INLINE.sub(fill_line, BLOCK.sub(fill, text))
        if new != text:
            path.write_text(new)
            print(f"updated {path.relative_to(ROOT)}", file=sys.stderr)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="*", help=f"blocks (default all: {', '.join(FIGURES)})")
    parser.add_argument("--write", action="store_true", help="rewrite the blocks in the docs")
    parser.add_argument(
        "--unlabelled", action="store_true", help="list the numbers neither scripted nor labelled"
    )
    args = parser.parse_args()
    if args.unlabelled:
        for path in DOCS:
            for i, line in unlabelled(path.read_text()):
                print(f"{path.relative_to(ROOT)}:{i}: {line[:100]}")
        return
    unknown = [n for n in args.names if n not in FIGURES]
    if unknown:
        parser.error(f"unknown figures {unknown}; known: {', '.join(FIGURES)}")
    if args.write:
        write(args.names)
        return
    for name in args.names or FIGURES:
        print(f"<!-- figures: {name} -->\n{FIGURES[name]()}<!-- /figures: {name} -->")


if __name__ == "__main__":
    main()
