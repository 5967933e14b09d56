"""Build the public SARSOP benchmark suite (``bench_sarsop.py --suite DIR``) into a folder.

Third-party problem files are not part of torchhrc: this script converts copies a user has
fetched. Each given folder is scanned for Cassandra ``.pomdp``/``.POMDP`` files (and
``.pomdpx`` files, copied as they are for a ``.pomdpx`` reader); every file is read with
:func:`torchhrc.io.read_pomdp` and re-written with :func:`torchhrc.io.write_pomdp` (one
normalised form that both torchhrc and APPL's ``pomdpsol`` read), except:

* undiscounted problems (``discount: 1``): SARSOP needs ``discount < 1`` (APPL's
  ``pomdpsol`` asserts it too), so they are skipped with a printed reason;
* files that do not parse (e.g. ``ejs4``-``ejs7`` of pomdp-solve, whose ``values: rewards``
  is outside the format's grammar and is rejected by APPL's parser as well): skipped with the
  parser's message;
* duplicates of a problem already in the suite (same sizes, discount and tensors).

Sources used for ``docs/benchmarks.md`` (both public):

* APPL SARSOP's ``examples/POMDP`` (Tiger, Hallway, Hallway2, TagAvoid) and
  ``examples/POMDPX`` (RockSample ``.pomdpx``);
* pomdp-solve's ``examples/pomdp-files`` (Cassandra; 1d, 4x3.95, aloha-10max, cheese.95,
  parr95.95, shuttle.95, tiger.aaai, uav-search, ...).

A held-out set of the classic pomdp.org files (``docs/benchmarks.md``, eleventh session) came
from the copies in the test sources of JuliaPOMDP's ``POMDPFiles.jl`` (its history holds
them under ``test/sources``; ``baseball`` gzipped under ``test``): ``--from`` a folder of
them re-writes each file that parses and is discounted (the ``cheng`` and ``learning``
problems, ``concert``, ``bulkhead.A`` and others have ``discount: 1``; ``mini-hall2`` and
``pomdp-ex`` are malformed, as APPL's parser reports too). A file too large to hold densely
(``baseball``, 7,681 states) is read and re-written in sparse form.

Random problems are generated from seeds with :func:`torchhrc.testing.random_pomdp`
(``random_S<S>_A<A>_O<O>_<dense|sparse>.pomdp``), so they need no source.

A second, generated **check set** (``--check-set``) holds problems never used to tune the
solver: four random POMDPs of other shapes and densities (one with peaked rows and discount
0.9), RockSample(5,5) with another rock layout, Tag with the opponent moving away with
probability 0.6 at discount 0.9, and RockSample(6,6) (rocks from seed 11) as a MOMDP
``.pomdpx``. Three more generated sets, added in the seventh session to look for failures
(``--check-set NAME``): ``mixed`` (random POMDPs of other shapes, one at discount 0.99,
RockSample(4,4) with another layout, Tag at 0.8, RockSample(7,5) as a MOMDP), ``momdp``
(random MOMDPs, static and dynamic hidden values, Tag and RockSample(5,7), (8,4) as MOMDPs,
all ``.pomdpx``), ``starts`` (MOMDPs whose first observed value is random: Tag from any cell,
RockSample(5,5) from its first column, random MOMDPs; ``.pomdpx``) and ``shapes`` (random
POMDPs with many actions, many observations, 600
sparse states, discount 0.99 and 0.999). The ninth session added ``structured``
(``structured.py``: two random mazes after Hallway, the tiger problem with 3 and 5 doors, a
machine-maintenance problem at discount 0.99 after bridge-repair, and RockSample(6,4) with
rocks from seed 77), the tenth ``edges`` (one observation, near-deterministic moves, a
40-cell corridor with three landmarks, RockSample(10,1) as a MOMDP, discount 0.9999,
rewards all negative, a MOMDP with two hidden values), the twelfth ``tasks`` (torchhrc's own
hand-finishing MOMDP at three hand-noise levels and the place-and-drill MOMDP) and ``scale``
(random sparse POMDPs of 2,000 to 100,000 states).
``docs/benchmarks.md`` reports both solvers on each beside the suite.

Usage::

    python benchmarks/problems/make_suite.py --out SUITE_DIR [--from DIR ...] [--no-random]
    python benchmarks/problems/make_suite.py --out CHECK_DIR \\
        --check-set [edges|mixed|momdp|scale|shapes|starts|structured|tasks]
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib.util
import shutil
from pathlib import Path

import torch

from torchhrc.errors import ParseError
from torchhrc.io.cassandra import read_pomdp, write_pomdp
from torchhrc.io.pomdpx import write_pomdpx
from torchhrc.pomdp import POMDP
from torchhrc.pomdp.sparse import SparsePOMDP
from torchhrc.tasks.classic import rock_sample, tag
from torchhrc.testing import random_momdp, random_pomdp


def _load_structured():  # type: ignore[no-untyped-def]
    """The sibling module ``structured.py`` (this script is also loaded by path, from the
    tests, where its folder is not on ``sys.path``)."""
    spec = importlib.util.spec_from_file_location(
        "structured_problems", Path(__file__).with_name("structured.py")
    )
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


_STRUCTURED = _load_structured()

# (states, actions, observations, sparsity of T and Z, seed): small to medium, dense and sparse
RANDOM = [
    (20, 4, 4, 0.0, 1),
    (50, 5, 5, 0.0, 2),
    (100, 6, 8, 0.8, 3),
]


def random_problems() -> dict[str, object]:
    """The generated problems of the suite, by file stem (rebuilt from their seeds)."""
    out = {}
    for S, A, O, sparsity, seed in RANDOM:
        kind = "sparse" if sparsity > 0 else "dense"
        out[f"random_S{S}_A{A}_O{O}_{kind}"] = random_pomdp(
            S, A, O, sparsity=sparsity, seed=seed, discount=0.95
        )
    return out


def check_problems() -> dict[str, object]:
    """The check set, by file name (see the module docstring); rebuilt from seeds."""
    return {
        "rnd_S30_A3_O6.pomdp": random_pomdp(30, 3, 6, seed=101, discount=0.95),
        "rnd_S80_A4_O10_sp.pomdp": random_pomdp(80, 4, 10, sparsity=0.9, seed=102, discount=0.95),
        "rnd_S200_A5_O6_sp.pomdp": random_pomdp(200, 5, 6, sparsity=0.95, seed=103, discount=0.95),
        "rnd_S40_A8_O3_peaky.pomdp": random_pomdp(
            40, 8, 3, concentration=0.3, seed=104, discount=0.9
        ),
        "rs55_layoutB.pomdp": rock_sample(5, 5, rocks=[(0, 0), (4, 4), (2, 1), (1, 3), (3, 2)]),
        "tag_p06_d09.pomdp": tag(move_away_probability=0.6, discount=0.9),
        "rs66_seed11.pomdpx": rock_sample(6, 6, seed=11, form="momdp"),
    }


def _start_over(model, xs: list[int]):  # type: ignore[no-untyped-def]
    """``model`` started at one of ``xs`` (uniform) with its own ``b0`` there."""
    joint = torch.zeros(model.num_observed, model.num_hidden, dtype=model.b0.dtype)
    joint[xs] = model.b0 / len(xs)
    return model.with_initial(joint)


def _random_start(model, seed: int):  # type: ignore[no-untyped-def]
    """``model`` started from a random joint ``P(x, y)`` (a Dirichlet(1) draw)."""
    g = torch.Generator().manual_seed(seed)
    joint = -torch.rand(
        model.num_observed, model.num_hidden, generator=g, dtype=torch.float64
    ).log()
    return model.with_initial(joint / joint.sum())


def _tag_any_cell(move_away_probability: float):  # type: ignore[no-untyped-def]
    """Tag as a MOMDP whose robot starts in any cell and the opponent in any other (as
    APPL's ``TagAvoid.pomdpx``)."""
    model = tag(form="momdp", robot_start=0, move_away_probability=move_away_probability)
    cells = model.num_observed
    joint = torch.zeros(cells, model.num_hidden, dtype=torch.float64)
    joint[:, :cells] = 1.0
    joint[torch.arange(cells), torch.arange(cells)] = 0.0
    return model.with_initial(joint / joint.sum())


def more_check_sets() -> dict[str, dict[str, object]]:
    """The later check sets, by name, then file name (rebuilt from seeds)."""
    return {
        "mixed": {
            "h_S15_A3_O2_d99.pomdp": random_pomdp(15, 3, 2, seed=201, discount=0.99),
            "h_S60_A4_O3_c05.pomdp": random_pomdp(60, 4, 3, concentration=0.5, seed=202),
            "h_S120_A3_O12_sp.pomdp": random_pomdp(120, 3, 12, sparsity=0.9, seed=203),
            "h_S300_A4_O5_sp.pomdp": random_pomdp(300, 4, 5, sparsity=0.97, seed=204, discount=0.9),
            "h_S25_A10_O8_peaky.pomdp": random_pomdp(25, 10, 8, concentration=0.2, seed=205),
            "h_rs44_alt.pomdp": rock_sample(4, 4, rocks=[(3, 0), (0, 3), (2, 2), (1, 1)]),
            "h_tag_p08.pomdp": tag(move_away_probability=0.8, discount=0.95),
            "h_rs75_momdp.pomdpx": rock_sample(7, 5, seed=21, form="momdp"),
        },
        "momdp": {
            "m_tag_p06.pomdpx": tag(form="momdp", move_away_probability=0.6, robot_start=5),
            "m_rs57.pomdpx": rock_sample(5, 7, seed=5, form="momdp"),
            "m_rs84.pomdpx": rock_sample(8, 4, seed=8, form="momdp"),
            "m_rnd_X12_Y8_static.pomdpx": random_momdp(12, 8, 4, 5, seed=301),
            "m_rnd_X20_Y6_dyn.pomdpx": random_momdp(
                20, 6, 3, 4, static=False, sparsity=0.7, seed=302
            ),
            "m_rnd_X6_Y20_d98.pomdpx": random_momdp(6, 20, 5, 6, seed=303, discount=0.98),
        },
        "starts": {  # MOMDPs whose first observed value is random (MOMDP.initial)
            "s_tag_any_cell.pomdpx": _tag_any_cell(move_away_probability=0.7),
            "s_rs55_first_column.pomdpx": _start_over(
                rock_sample(5, 5, seed=55, form="momdp"), [row * 5 for row in range(5)]
            ),
            "s_rnd_X10_Y6.pomdpx": _random_start(random_momdp(10, 6, 3, 4, seed=501), 502),
            "s_rnd_X15_Y5_dyn.pomdpx": _start_over(
                random_momdp(15, 5, 4, 3, static=False, sparsity=0.6, seed=503), [2, 7, 11]
            ),
        },
        "shapes": {
            "r_S200_A10_O10_dense.pomdp": random_pomdp(200, 10, 10, seed=401),
            "r_S40_A30_O4.pomdp": random_pomdp(40, 30, 4, seed=402),
            "r_S30_A4_O60.pomdp": random_pomdp(30, 4, 60, seed=403, concentration=0.3),
            "r_S100_A5_O5_d99.pomdp": random_pomdp(
                100, 5, 5, sparsity=0.9, seed=404, discount=0.99
            ),
            "r_S600_A6_O8_sp.pomdp": random_pomdp(600, 6, 8, sparsity=0.98, seed=405),
            "r_S8_A3_O3_d999.pomdp": random_pomdp(8, 3, 3, seed=406, discount=0.999),
        },
        "structured": {  # benchmarks/problems/structured.py, added in the ninth session
            "g_maze7_s1.pomdp": _STRUCTURED.maze(7, seed=1),
            "g_maze10_s2.pomdp": _STRUCTURED.maze(10, seed=2, wall_fraction=0.3),
            "g_doors3.pomdp": _STRUCTURED.doors(3),
            "g_doors5_a07.pomdp": _STRUCTURED.doors(5, accuracy=0.7),
            "g_maint6_d99.pomdp": _STRUCTURED.maintenance(6),
            "g_rs64_s77.pomdp": rock_sample(6, 4, seed=77),
        },
        "edges": {  # the tenth session: shapes at the edges of what the solver meets
            "e_blind_S20_A4_O1.pomdp": random_pomdp(20, 4, 1, seed=601),
            "e_neardet_S60_A4_O6.pomdp": random_pomdp(60, 4, 6, concentration=0.02, seed=602),
            "e_corridor40.pomdp": _STRUCTURED.corridor(40, landmarks=(0, 13, 27)),
            "e_rs10_1.pomdpx": rock_sample(10, 1, seed=604, form="momdp"),
            "e_S6_A3_O3_d9999.pomdp": random_pomdp(6, 3, 3, seed=605, discount=0.9999),
            "e_S30_A5_O5_neg.pomdp": _shifted(random_pomdp(30, 5, 5, seed=606), -20.0),
            "e_mom_X40_Y2.pomdpx": random_momdp(40, 2, 4, 3, seed=607),
        },
    }


def task_check_set() -> dict[str, object]:
    """The ``tasks`` check set (twelfth session): torchhrc's own tasks as SARSOP problems,
    built here rather than in :func:`more_check_sets` (the kinematic checks take seconds).

    * the hand-finishing MOMDP at the study's size (975 observed values: box configurations
      times progress, 2 person types, 7 actions, 48 hand observations; the kinematic
      feasibility by pytorch-kinematics, seed 0) with the hand model that generates the
      study's tracks (offset ``TRUE_HAND_LOC``) at noise 0.1, 0.2 and 0.4 m per axis;
    * the place-and-drill expert MOMDP from a uniform type belief (27 observed values).
    """
    from torchhrc.experiments.place_and_drill import build_expert_momdp, load_expert_model
    from torchhrc.tasks.hand_finishing.geometry import feasible_box_configurations
    from torchhrc.tasks.hand_finishing.model import HandFinishingTask
    from torchhrc.tasks.hand_finishing.sensing import true_observation
    from torchhrc.tasks.hand_finishing.settings import HandFinishingSettings

    study = HandFinishingSettings.create()
    feasible = feasible_box_configurations(study.geometry, seed=0)
    task = HandFinishingTask.build(feasible=feasible.comfortable, reachable=feasible.reachable,
                                   geometry=study.geometry, work_units=study.work_units,
                                   rewards=study.rewards)  # fmt: skip
    out: dict[str, object] = {}
    for noise in (0.1, 0.2, 0.4):  # the study's generating hand model at each noise
        hand = true_observation(task, noise)
        out[f"t_handfinish_n{round(noise * 100):02d}.pomdpx"] = task.momdp(hand)
    expert = load_expert_model()
    Y = len(expert.type_names)
    out["t_place_drill.pomdpx"] = build_expert_momdp(
        expert, torch.full((Y,), 1.0 / Y, dtype=torch.float64)
    )
    return out


def scale_check_set() -> dict[str, object]:
    """The ``scale`` check set (twelfth session): large random POMDPs with a sparse structure,
    as a model of thousands of states usually has (a few successors a state, a few possible
    observations after each), written sparse and read by ``sparse="auto"`` as sparse models.
    Built on demand (seconds), as :func:`task_check_set`."""
    return {
        "x_sp_S5000_A6_O16.pomdp": _sparse_random(5000, 6, 16, 4, 3, seed=702),
        "x_sp_S20000_A4_O8.pomdp": _sparse_random(20000, 4, 8, 3, 2, seed=701),
        "x_sp_S2000_A5_O10_d99.pomdp": _sparse_random(2000, 5, 10, 5, 3, seed=703, discount=0.99),
        # issue 33 goal 4: the 20,000-state model's shape at 100,000 states (94 MB written)
        "x_sp_S100000_A4_O8.pomdp": _sparse_random(100000, 4, 8, 3, 2, seed=704),
    }


def _sparse_random(S: int, A: int, O: int, successors: int, outcomes: int, *, seed: int,
                   discount: float = 0.95, starts: int = 10) -> SparsePOMDP:  # fmt: skip
    """A random sparse POMDP: each ``(a, s)`` moves to itself and ``successors - 1`` random
    other states (Dirichlet(1) probabilities; a repeated successor is summed), each
    ``(a, s2)`` emits one of ``outcomes`` consecutive observations (from a random first one,
    Dirichlet(1)), rewards standard normal, ``b0`` uniform over ``starts`` random states."""
    g = torch.Generator().manual_seed(seed)
    rows = A * S

    def dirichlet(n: int) -> torch.Tensor:
        w = -torch.rand(rows, n, generator=g, dtype=torch.float64).log()
        return (w / w.sum(1, keepdim=True)).reshape(-1)

    act = torch.arange(A).repeat_interleave(S)  # (A S,) the row (a, s) in order
    src = torch.arange(S).repeat(A)
    step = torch.randint(1, S, (rows, successors), generator=g)
    step[:, 0] = 0
    nxt = (src[:, None] + step).remainder(S)
    first = torch.randint(0, O, (rows, 1), generator=g)
    obs = (first + torch.arange(outcomes)).remainder(O)
    b0 = torch.zeros(S, dtype=torch.float64)
    b0[torch.randperm(S, generator=g)[:starts]] = 1.0 / starts

    def coo(k: int, cols: torch.Tensor) -> torch.Tensor:
        rows_k = (act.repeat_interleave(k), src.repeat_interleave(k), cols.reshape(-1))
        return torch.stack(rows_k, 1)

    return SparsePOMDP(
        transitions=(coo(successors, nxt), dirichlet(successors)),
        observations_=(coo(outcomes, obs), dirichlet(outcomes)),
        R=torch.randn(A, S, generator=g, dtype=torch.float64), b0=b0, discount=discount,
        states=tuple(f"s{i}" for i in range(S)), actions=tuple(f"a{i}" for i in range(A)),
        observations=tuple(f"o{i}" for i in range(O)),
    )  # fmt: skip


def _shifted(model, by: float):  # type: ignore[no-untyped-def]
    """``model`` with every reward moved by ``by`` (all negative: values in the hundreds)."""
    return dataclasses.replace(model, R=model.R + by)


def _stem(path: Path) -> str:
    name = path.name
    for ext in (".pomdpx", ".POMDP", ".pomdp"):
        if name.endswith(ext):
            name = name[: -len(ext)]
    return name.replace(".", "_").replace("-", "_").lower()


def _same(a, b) -> bool:  # type: ignore[no-untyped-def]
    if type(a) is not type(b):
        return False
    if not isinstance(a, POMDP):  # sparse (too large to hold densely): coordinate lists
        pairs = (*zip(a.transitions, b.transitions), *zip(a.observations_, b.observations_))
        return bool(
            float(a.discount) == float(b.discount)
            and all(x.shape == y.shape for x, y in pairs)
            and all(
                torch.equal(x, y) if x.dtype == torch.int64 else torch.allclose(x, y)
                for x, y in pairs
            )
            and torch.allclose(a.R, b.R)
            and torch.allclose(a.b0, b.b0)
        )
    if (a.num_states, a.num_actions, a.num_observations) != (
        b.num_states,
        b.num_actions,
        b.num_observations,
    ):
        return False
    return bool(
        float(a.discount) == float(b.discount)
        and torch.allclose(a.T, b.T)
        and torch.allclose(a.Z, b.Z)
        and torch.allclose(a.R, b.R)
        and torch.allclose(a.b0, b.b0)
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True, help="the suite folder")
    parser.add_argument(
        "--from", dest="sources", type=Path, nargs="*", default=[], help="folders of fetched files"
    )
    parser.add_argument("--no-random", action="store_true", help="skip the generated problems")
    parser.add_argument(
        "--check-set", nargs="?", const="check",
        choices=["check", "edges", "mixed", "momdp", "scale", "shapes", "starts", "structured",
                 "tasks"],
        help="write a check set (never tuned on) instead: the first (no name) or a later one",
    )  # fmt: skip
    args = parser.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    if args.check_set:
        note = "check set generated by benchmarks/problems/make_suite.py from its seed (torchhrc)"
        built = {"check": check_problems, "tasks": task_check_set, "scale": scale_check_set}
        if args.check_set in built:  # (built on demand: they take seconds)
            problems = built[args.check_set]()
        else:
            problems = more_check_sets()[args.check_set]
        for name, model in problems.items():
            if name.endswith(".pomdpx"):
                write_pomdpx(model, args.out / name, description=note)  # type: ignore[arg-type]
            else:
                # numbers, not names, past 50,000 states: APPL's Cassandra parser looks names
                # up in a hash table of 255 chained buckets (parse_hash.c). The file is also
                # smaller (94 MB against 101), but APPL still had not read the numbered
                # 100,000-state file after 11.5 CPU-min (named: 6 CPU-min, stopped)
                names = model.num_states <= 50_000  # type: ignore[attr-defined]
                write_pomdp(model, args.out / name, comment=note, names=names)  # type: ignore[arg-type]
            print(f"{name} (generated)")
        return 0
    kept: dict[str, object] = {}
    for src in args.sources:
        files = sorted(p for p in src.iterdir() if p.suffix.lower() in (".pomdp", ".pomdpx"))
        for path in files:
            stem = _stem(path)
            if path.suffix.lower() == ".pomdpx":
                shutil.copyfile(path, args.out / f"{stem}.pomdpx")
                print(f"{path.name}: copied as {stem}.pomdpx")
                continue
            try:
                model = read_pomdp(path, sparse="auto")  # sparse where dense would not fit
            except ParseError as err:
                print(f"{path.name}: skipped (does not parse: {err})")
                continue
            if float(model.discount) >= 1.0:
                print(f"{path.name}: skipped (discount {float(model.discount)}: SARSOP needs < 1)")
                continue
            dup = next((k for k, m in kept.items() if _same(m, model)), None)
            if dup is not None:
                print(f"{path.name}: skipped (same problem as {dup})")
                continue
            kept[stem] = model
            write_pomdp(
                model,
                args.out / f"{stem}.pomdp",
                comment=f"{path.name}, re-written by benchmarks/problems/make_suite.py (torchhrc)",
            )
            print(f"{path.name}: {stem}.pomdp (S={model.num_states}, A={model.num_actions}, "
                  f"O={model.num_observations}, discount {float(model.discount)})")  # fmt: skip
    if not args.no_random:
        for stem, model in random_problems().items():
            write_pomdp(
                model,  # type: ignore[arg-type]
                args.out / f"{stem}.pomdp",
                comment="generated by benchmarks/problems/make_suite.py from its seed (torchhrc)",
            )
            print(f"{stem}.pomdp (generated)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
