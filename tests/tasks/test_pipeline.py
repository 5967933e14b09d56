"""The task pipeline: the place-and-drill model against one worked in plain Python, consistency
checks on type-dependent pieces, save / load, and one code path for every task."""

from __future__ import annotations

import inspect
import json
import math
import random
from dataclasses import dataclass

import pytest
import torch

from torchhrc.data import Demonstrations
from torchhrc.errors import ModelError
from torchhrc.mixture import fit_mixture
from torchhrc.tasks import pipeline
from torchhrc.tasks.controller import Controller
from torchhrc.tasks.interface import CollaborativeTask, TypeEvidence
from torchhrc.tasks.pipeline import (
    IRLConfig,
    LearnedModel,
    build_model,
    compare_human_models,
    learn,
)
from torchhrc.tasks.place_and_drill.demos import simulate_study
from torchhrc.tasks.place_and_drill.model import FEATURE_NAMES, PlaceAndDrillTask


@pytest.fixture(scope="module")
def study():
    demos = simulate_study(n_subjects=6, n_demos=3, seed=0)
    fit = fit_mixture(demos, k_min=2, k_max=3, restarts=4, seed=0)
    return demos, fit


def _place_and_drill_tx(chains, vocabulary, n, noise, pause):
    """The paper's place-and-drill ``Tx[a][x][y][x2]`` in plain Python (module docstring of
    torchhrc.tasks.place_and_drill.model): the robot acts, then the human places an empty
    position ``i`` with ``(1 - pause) ((1 - noise) q_i + noise / #empty)``, ``q`` the type's
    chain ``P(human:place_i | robot:a)`` over the empty positions, or lets the turn pass."""
    lookup = {tuple(v): i for i, v in enumerate(vocabulary)}
    actions = ["wait"] + [f"drill_{chr(65 + i)}" for i in range(n)]
    X, K = 3**n, len(chains)
    Tx = [[[[0.0] * X for _ in range(K)] for _ in range(X)] for _ in actions]
    for a, name in enumerate(actions):
        for x in range(X):
            status = [(x // 3 ** (n - 1 - i)) % 3 for i in range(n)]
            if a > 0 and status[a - 1] == 1:  # drilling a placed screw
                status[a - 1] = 2
            m = sum(s * 3 ** (n - 1 - i) for i, s in enumerate(status))
            empty = [i for i in range(n) if status[i] == 0]
            for y in range(K):
                if not empty:
                    Tx[a][x][y][m] = 1.0
                    continue
                row = chains[y][lookup[("robot", name)]]
                pref = [row[lookup[("human", f"place_{chr(65 + i)}")]] for i in empty]
                total = sum(pref)
                q = [p / total if total > 0 else 1.0 / len(empty) for p in pref]
                for i, qi in zip(empty, q):
                    p_i = (1 - pause) * ((1 - noise) * qi + noise / len(empty))
                    Tx[a][x][y][m + 3 ** (n - 1 - i)] += p_i
                Tx[a][x][y][m] += pause
    return torch.tensor(Tx, dtype=torch.float64)


def test_build_model_equals_the_place_and_drill_model_worked_in_plain_python(study):
    demos, fit = study
    task = PlaceAndDrillTask(3)
    chains = fit.transition_over(demos).detach().double()  # over the recorded symbols
    model = build_model(task, demos, chains, fit.assignments, irl_iterations=5, seed=0)
    Tx = _place_and_drill_tx(chains.tolist(), demos.vocabulary, 3, noise=0.05, pause=0.01)
    m = model.momdp
    # 1e-9: the library rounds the pause through float32 (0.01 -> 0.0099999998)
    assert torch.allclose(m.Tx, Tx, rtol=0, atol=1e-9)
    # R = sum_f w[y, f] phi_f(x, a), zero in the all-drilled state (26), uniform start at 0
    phi, w = task.features(), model.weights
    R = [[[sum(w[y, f].item() * phi[a, x, f].item() for f in range(6)) if x != 26 else 0.0
           for y in range(fit.k)] for x in range(27)] for a in range(4)]  # fmt: skip
    assert torch.allclose(m.R, torch.tensor(R, dtype=torch.float64), rtol=0, atol=1e-12)
    assert m.Ty is None and m.x0 == 0 and torch.equal(m.b0, torch.full((2,), 0.5).double())
    assert m.Z.shape == (4, 27, 2, 1) and bool((m.Z == 1).all())
    assert sorted(model.type_names) == ["efficient", "safe"]
    # the IRL rewards say what each type's demonstrations do (module docstring): a safe
    # partner's robot waits while a position is empty, an efficient one's drills at once
    early, wait = FEATURE_NAMES.index("drill_early"), FEATURE_NAMES.index("wait_early")
    for y, name in enumerate(model.type_names):
        sign = 1.0 if name == "efficient" else -1.0
        assert sign * (w[y, early] - w[y, wait]) > 0


@dataclass(frozen=True)
class _WrongReward(PlaceAndDrillTask):
    def known_reward(self, evidence: TypeEvidence) -> torch.Tensor:
        return torch.zeros(self.num_actions, self.num_states, evidence.num_types + 1,
                           dtype=torch.float64)  # fmt: skip


@dataclass(frozen=True)
class _WrongBehaviour(PlaceAndDrillTask):
    def human_policy(self, evidence: TypeEvidence) -> torch.Tensor:
        return super().human_policy(evidence)[:1]


@dataclass(frozen=True)
class _WrongObservation(PlaceAndDrillTask):
    def observation(self, model):
        return torch.ones(self.num_actions, self.num_states, 1, 1, dtype=torch.float64)


@pytest.mark.parametrize(
    "task, piece",
    [
        (_WrongReward(3), "known_reward"),
        (_WrongBehaviour(3), "human_policy"),
        (_WrongObservation(3), "observation"),
    ],
)
def test_a_type_dependent_piece_with_the_wrong_number_of_types_is_rejected(study, task, piece):
    demos, fit = study
    with pytest.raises(ModelError, match=rf"the task's {piece}\(\) has \d+ types .*Y=2"):
        build_model(task, demos, fit.model.transition, fit.assignments, irl_iterations=2)


def test_inconsistent_inputs_are_rejected(study):
    demos, fit = study
    task = PlaceAndDrillTask(3)
    with pytest.raises(ModelError, match="expected assignments of shape"):
        build_model(task, demos, fit.model.transition, fit.assignments[:-1])
    with pytest.raises(ModelError, match=r"expected assignments in \[0, 2\)"):
        build_model(task, demos, fit.model.transition, fit.assignments + 5)
    with pytest.raises(ModelError, match="not an action of the task"):
        build_model(PlaceAndDrillTask(2), demos, fit.model.transition, fit.assignments)


def test_learn_save_load_roundtrip_and_controller(tmp_path):
    demos = simulate_study(n_subjects=4, n_demos=2, seed=1)
    model = learn(PlaceAndDrillTask(3), demos, k_min=2, k_max=2, restarts=2,
                  irl_iterations=3, solver_time=2.0, seed=0)  # fmt: skip
    assert model.policy is not None and model.lower <= model.upper + 1e-9
    path = model.save(tmp_path / "pd")
    again = LearnedModel.load(path)
    for name in ("Tx", "R", "Z", "b0"):
        assert torch.equal(getattr(model.momdp, name), getattr(again.momdp, name))
    assert torch.equal(model.policy.alphas, again.policy.alphas)
    assert again.type_names == model.type_names and again.info == model.info
    assert again.vocabulary == model.vocabulary and again.lower == model.lower
    a, b = Controller.from_model(model), Controller.from_model(again)
    a.reset(), b.reset()
    x = 0
    for h in (0, 1, 2):  # the human places A, B, C
        act = a.act(x)
        assert act == b.act(x)
        x = int(PlaceAndDrillTask(3).step(torch.tensor(x), torch.tensor(h), torch.tensor(act)))
    assert torch.allclose(a.belief, b.belief)
    # saving again replaces the directory atomically
    model.save(path)
    assert sorted(p.name for p in path.iterdir()) == ["model.json", "model.safetensors"]
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_the_prior_is_the_types_share_of_the_demonstrations():
    """learn()'s ``b0``: each learned type's share of the demonstrations (a new person is a
    draw from the population the demonstrators came from); ``prior="uniform"``: 1 / k."""
    demos = simulate_study(n_subjects=8, n_demos=3, seed=2)
    types = list(demos.types)
    first = types[0]
    # every demonstration of the first type, a third of the other's: about 3 to 1
    keep = [i for i, t in enumerate(types) if t == first]
    keep += [i for i, t in enumerate(types) if t != first][::3]
    demos = demos.subset(keep)
    settings = dict(k=2, restarts=2, irl_iterations=2, solve=False, seed=0)
    shares = learn(PlaceAndDrillTask(3), demos, **settings)
    counts = torch.bincount(shares.assignments, minlength=2).double()
    torch.testing.assert_close(shares.momdp.b0, counts / counts.sum())
    assert float(shares.momdp.b0.max()) >= 0.7  # the majority type, about 3/4
    assert shares.info["prior"] == {"rule": "shares", "b0": shares.momdp.b0.tolist()}
    uniform = learn(PlaceAndDrillTask(3), demos, prior="uniform", **settings)
    assert torch.equal(uniform.assignments, shares.assignments)
    torch.testing.assert_close(uniform.momdp.b0, torch.full((2,), 0.5, dtype=torch.float64))
    assert uniform.info["prior"] == {"rule": "uniform", "b0": [0.5, 0.5]}
    with pytest.raises(ValueError, match="expected prior 'shares' or 'uniform', got 'even'"):
        learn(PlaceAndDrillTask(3), demos, prior="even", **settings)


def test_load_reports_the_bad_file(tmp_path):
    with pytest.raises(ModelError, match=r"model\.json: no such file"):
        LearnedModel.load(tmp_path)
    (tmp_path / "model.json").write_text('{"format": "torchhrc.learned_task_model",\n oops}')
    (tmp_path / "model.safetensors").write_bytes(b"")
    with pytest.raises(ModelError, match=r"model.json: line 2"):
        LearnedModel.load(tmp_path)
    (tmp_path / "model.json").write_text(json.dumps({"format": "other"}))
    with pytest.raises(ModelError, match="field 'format'"):
        LearnedModel.load(tmp_path)


class _Sides(CollaborativeTask):
    """The robot holds a part left or right (or waits); the person takes from a side."""

    state_names = ("none", "took_left", "took_right")
    robot_actions = ("wait", "hold_left", "hold_right")
    human_actions = ("take_left", "take_right")
    robot_effect = torch.tensor([[0, 1, 2]] * 3)
    human_effect = torch.tensor([[1, 2]] * 3)
    human_model = "state"

    @property
    def human_legal(self) -> torch.Tensor:
        return torch.ones(3, 2, dtype=torch.bool)


def test_learn_records_both_readings_of_the_objects_and_raw_keeps_sides_apart():
    # docs/your_own_task.md section 2, "Action names carry objects": left- and right-handed
    # people who otherwise act alike, 10 subjects x 3; the exchangeable reading (the sides as
    # interchangeable objects) makes them one type, and objects="raw" keeps them apart; the
    # split of divided types reads the partners' holds as the clustering read the objects
    # (one move, "hold"), so it does not part them again
    seqs, who = [], []
    for s in range(10):
        side = ("left", "right")[s % 2]
        seqs += [[("robot", f"hold_{side}"), ("human", f"take_{side}")] * 4] * 3
        who += [f"s{s}"] * 3
    demos = Demonstrations.from_lists(seqs, subjects=who)
    auto = learn(_Sides(), demos, solve=False, irl_iterations=1)
    readings = auto.info["object_comparison"]
    assert set(readings) == {"raw", "exchangeable"}
    kept = max(readings, key=lambda r: readings[r]["exact_icl"])
    assert auto.info["objects"] == kept and auto.info["k_clustered"] == int(readings[kept]["k"])
    assert readings["raw"]["k"] == 2 and readings["exchangeable"]["k"] == 1
    assert auto.num_types == 1 and auto.info["split"] == []
    assert auto.info["divided"]["states"] == 0  # left and right holds: one move, "hold"
    raw = learn(_Sides(), demos, solve=False, irl_iterations=1, objects="raw")
    assert raw.info["objects"] == "raw" and raw.num_types == 2 and raw.info["split"] == []


def test_learn_names_the_demonstrations_container():
    task = _Turns()
    with pytest.raises(TypeError, match=r"got list; build one .*Demonstrations.from_lists"):
        learn(task, [[("robot", "a"), ("human", "left")]] * 4, k=1, solve=False)


def test_controller_needs_a_solved_model(study):
    demos, fit = study
    model = build_model(PlaceAndDrillTask(3), demos, fit.model.transition, fit.assignments,
                        irl_iterations=2)  # fmt: skip
    with pytest.raises(ModelError, match="solve it first"):
        Controller.from_model(model)


def test_a_momdp_given_by_hand_is_solved_as_the_learned_one(study):
    """The study's baselines (solve_momdp) and its learned model (solve_model) are solved with
    the same settings: the same bounds on the same MOMDP."""
    demos, fit = study
    model = build_model(PlaceAndDrillTask(3), demos, fit.model.transition, fit.assignments,
                        irl_iterations=2)  # fmt: skip
    settings = dict(time_limit=60.0, precision=1e-2, max_iterations=3, seed=0)
    solved = pipeline.solve_model(model, **settings)
    by_hand = pipeline.solve_momdp(model.momdp, **settings)
    assert (by_hand.lower, by_hand.upper) == (solved.lower, solved.upper)
    assert solved.info["solver"]["precision"] == pytest.approx(1e-2 * float(
        model.momdp.R.max() - model.momdp.R.min()))  # fmt: skip


def test_the_pipeline_does_not_dispatch_on_task_classes():
    source = inspect.getsource(pipeline)
    assert "isinstance(task" not in source and "type(task)" not in source
    for name in ("PlaceAndDrill", "HandFinishing", "Kitchen"):
        assert name not in source.split('"""', 2)[2]  # beyond the module docstring


# ---------------------------------------------------------------------------- issue 31 goal 4
class _Turns(CollaborativeTask):
    """Four phases in a cycle; the robot's "a"/"b" change nothing, the human's "left" and
    "right" both advance the phase (both always legal)."""

    state_names = ("p0", "p1", "p2", "p3")
    robot_actions = ("a", "b")
    human_actions = ("left", "right")
    robot_effect = torch.tensor([[0, 1, 2, 3], [0, 1, 2, 3]])
    human_effect = torch.tensor([[1, 1], [2, 2], [3, 3], [0, 0]])


def _turn_demos(respond, subjects=8, per_subject=3, steps=8, seed=0):
    """The robot picks a or b at random; the human answers ``respond(x, robot)`` (0 = left)."""
    rng = random.Random(seed)
    seqs, who = [], []
    for s in range(subjects):
        for _ in range(per_subject):
            x, seq = 0, []
            for _ in range(steps):
                r = rng.randrange(2)
                h = respond(x, r)
                seq += [("robot", "ab"[r]), ("human", ("left", "right")[h])]
                x = (x + 1) % 4
            seqs.append(seq)
            who.append(f"s{s}")
    return Demonstrations.from_lists(seqs, subjects=who)


@pytest.mark.parametrize(
    "respond, expected",
    [
        (lambda x, r: x % 2, "state"),  # left in even phases: P(h | x), the robot irrelevant
        (lambda x, r: r, "chain"),  # mirrors the robot's last action: P(h | a_r), any phase
    ],
)
def test_auto_human_model_picks_the_model_the_human_follows(respond, expected):
    task = _Turns()
    demos = _turn_demos(respond)
    types = torch.zeros(demos.num_sequences, dtype=torch.long)
    record = compare_human_models(task, demos, types, noise=0.05, pause=0.01, seed=0,
                                  state_smoothing=(0.75, 1.0))  # fmt: skip
    assert record["used"] == expected and record["folds"] == 5 and record["subjects"] == 8
    other = "chain" if expected == "state" else "state"
    # the followed model predicts each held-out turn almost surely: (1 - pause) *
    # ((1 - noise) * q + noise / 2), half the noise landing on the right action, with q = 1
    # for the chain (log 0.965 = -0.036 nats a turn); the state model (smoothing given:
    # habit weight 0.75, strength 1) backs off by one pseudo-step from ~38.4 training turns
    # per phase, all
    # the same answer, toward 3/4 the type's habit before the robot's move (the same
    # phase: h = 38.9 / 39.4 of the chain's even split smoothed in) and 1/4 the
    # population's (one type: (38.4 + h) / 39.4): q = (38.4 + prior) / 39.4 = 0.9997
    # (log 0.965); the other one cannot tell the two actions apart: log(0.99 / 2) = -0.703
    habit = 38.9 / 39.4
    prior = 0.75 * habit + 0.25 * (38.4 + habit) / 39.4
    q = 1.0 if expected == "chain" else (38.4 + prior) / 39.4
    want = math.log(0.99 * (0.95 * q + 0.025))
    assert record["per_step"][expected] == pytest.approx(want, abs=0.01)
    assert record["per_step"][other] == pytest.approx(math.log(0.495), abs=0.05)
    model = learn(task, demos, k=1, solve=False, irl_iterations=2)
    assert model.info["human_model"]["used"] == expected
    assert model.info["human_model"]["requested"] == "auto"
    # the behaviour built is the chosen model's: the chain model's does not depend on x
    b = model.behaviour[0, :, :, :2]  # (A, X, H)
    depends_on_x = not torch.allclose(b[:, 0], b[:, 1])
    assert depends_on_x == (expected == "state")
    forced = learn(task, demos, k=1, solve=False, irl_iterations=2, human_model=other)
    record = forced.info["human_model"]
    assert record["requested"] == other and record["used"] == other
    assert set(record["state_smoothing"]) == {"habit_weight", "prior_strength"}


def test_auto_human_model_scores_without_a_move_that_carries_the_type():
    # two types; each type's partner always makes its own move (type 0 "a", type 1 "b") and
    # each person does their own thing (type 0 "left", type 1 "right") whatever the move.
    # With the demonstrated moves the chain "left after a" predicts as well as the state
    # model (better: it pools the four phases), but online the robot picks the move itself
    # and the chain cannot tell the types apart. Every phase is confounded (the partners'
    # moves differ by total variation 1), so the person is scored under the pooled partner
    # (a or b, 1/2 each): the chain's type 0 answers "left" after "a" with
    # (1 - pause) * (0.95 * 1 + 0.025) = 0.965 and after "b" (never seen) with
    # 0.99 * (0.95 / 2 + 0.025) = 0.495, so each turn costs log(0.73 / 0.965) = -0.279
    # against the demonstrated moves (the log w_y terms cancel); the state model predicts
    # the person from the phase, the same after either move.
    seqs, who, types = [], [], []
    for s in range(8):
        y = s % 2
        for _ in range(3):
            seqs.append([("robot", "ab"[y]), ("human", ("left", "right")[y])] * 8)
            who.append(f"s{s}")
            types.append(y)
    demos = Demonstrations.from_lists(seqs, subjects=who)
    # (the default smoothing: the property is the scoring's, not the smoothing's choice)
    record = compare_human_models(_Turns(), demos, torch.tensor(types), noise=0.05,
                                  pause=0.01, seed=0, state_smoothing=(0.75, 1.0))  # fmt: skip
    assert record["confounded"] == 1.0
    demonstrated = record["per_step_demonstrated"]
    assert demonstrated["chain"] > demonstrated["state"]  # the old rule would pick chain
    assert record["used"] == "state"
    cost = math.log((0.965 + 0.495) / 2 / 0.965)
    assert record["per_step"]["chain"] - demonstrated["chain"] == pytest.approx(cost, abs=0.02)
    assert record["per_step"]["state"] == pytest.approx(demonstrated["state"], abs=0.01)


def test_recorded_scores_pick_the_recorded_k(tmp_path):
    demos = simulate_study(n_subjects=8, n_demos=3, seed=2)
    model = learn(PlaceAndDrillTask(3), demos, k_max=4, restarts=3, solve=False,
                  irl_iterations=2)  # fmt: skip
    info = model.info
    scores = {int(k): row for k, row in info["scores"].items()}
    assert sorted(scores) == [1, 2, 3, 4] and info["criterion"] == "icl_or_gain"
    settings = info["cluster"]
    assert settings["initial"] is True and settings["k_min"] == 1 and settings["k_max"] == 4
    assert settings["object_separator"] == "_"  # the fit's, recorded for info["divided"]
    # the exact ICL's k, cut to the smallest k whose next k gains less than min_gain ...
    top = max(scores, key=lambda k: scores[k]["exact_icl"])
    gain = settings["min_gain"]
    k_icl = next((k for k in range(1, top) if not scores[k + 1]["gain"] >= gain), top)
    # ... raised only by steps that gain strong_gain in the fit and enough held out
    T = float((demos.lengths - 1).sum())
    expected = k_icl
    while expected < 4 and scores[expected + 1]["gain"] >= settings["strong_gain"]:
        step = scores[expected + 1]["heldout"] - scores[expected]["heldout"]
        if step < settings["heldout_gain"] * T:
            break
        expected += 1
    if "heldout" not in scores[1]:  # no strong step was tried
        assert expected == k_icl
    assert info["k"] in (expected, k_icl) and info["k"] >= k_icl
    assert info["k"] == model.num_types == 2
    assert info["human_model"]["used"] == "chain"  # the task's own setting (the paper's)
    again = LearnedModel.load(model.save(tmp_path / "m"))
    assert again.info == json.loads(json.dumps(info))


def test_learn_passes_its_settings_through(monkeypatch):
    from torchhrc.mixture import ClusterConfig
    from torchhrc.mixture.selection import DEFAULT_HELDOUT_GAIN, DEFAULT_MIN_GAIN
    from torchhrc.solvers.sarsop import SARSOPConfig
    from torchhrc.tasks.pipeline import LEARN_MIN_GAIN

    demos = simulate_study(n_subjects=6, n_demos=3, seed=0)
    task = PlaceAndDrillTask(3)
    seen = {}
    original = pipeline.learn_type_weights

    def spy(*args, **kwargs):
        seen.update(kwargs)
        return original(*args, **kwargs)

    monkeypatch.setattr(pipeline, "learn_type_weights", spy)
    model = learn(task, demos, cluster=ClusterConfig(criterion="bic", k_min=2, k_max=3,
                  restarts=2, objects="raw"), irl=IRLConfig(rule="last", epsilon=0.2,
                  iterations=3, l2=0.5, pooling=0.3), solver=SARSOPConfig(time_limit=5.0,
                  max_iterations=2))  # fmt: skip
    info = model.info
    scores = {int(k): row for k, row in info["scores"].items()}
    assert info["criterion"] == "bic" and sorted(scores) == [2, 3]
    assert info["k"] <= max(scores, key=lambda k: scores[k]["bic"])
    assert info["cluster"]["restarts"] == 2 and info["objects"] == "raw"
    # learn()'s gain for the soft method, not fit_mixture's (0.015): one effect size
    assert info["cluster"]["min_gain"] == info["cluster"]["strong_gain"] == LEARN_MIN_GAIN
    assert LEARN_MIN_GAIN == 0.01 and DEFAULT_MIN_GAIN == 0.015
    # ... and half of it held out, not fit_mixture's 0.01
    assert info["cluster"]["heldout_gain"] == pytest.approx(0.005)
    assert DEFAULT_HELDOUT_GAIN == 0.01
    # learn()'s default order: each order selects a k, the fit with the most types is kept
    assert info["cluster"]["order"] == "auto" and info["order"] in (1, 2, 3)
    kept = info["order_comparison"][str(info["order"])]
    assert set(info["order_comparison"]) == {"1", "2", "3"} and kept["k"] == info["k"]
    assert kept["k"] == max(row["k"] for row in info["order_comparison"].values())
    assert seen == {"rule": "last", "epsilon": 0.2, "max_iterations": 3, "seed": 0, "l2": 0.5,
                    "pooling": 0.3}  # fmt: skip
    assert info["irl"] == {"rule": "last", "epsilon": 0.2, "iterations": 3, "l2": 0.5,
                           "pooling": 0.3, "wrong_moves": "symmetric"}  # fmt: skip
    assert info["solver"]["max_iterations"] == 2 and info["solver"]["time_limit"] == 5.0
    assert info["solver"]["lower_bound_init"] == "type_policy_lower_bound"
    # the keywords reach the same settings
    again = learn(task, demos, criterion="bic", k_min=2, k_max=3, restarts=2, objects="raw",
                  irl_epsilon=0.2, irl_iterations=3, irl_l2=0.5, irl_pooling=0.3,
                  irl_wrong_moves="learned", solve=False)  # fmt: skip
    assert again.info["scores"] == info["scores"] and again.info["k"] == info["k"]
    assert again.info["irl"]["l2"] == 0.5 and again.info["irl"]["pooling"] == 0.3
    assert again.info["irl"]["wrong_moves"] == again.info["wrong_moves"]["rule"] == "learned"
    paper = learn(task, demos, cluster=ClusterConfig(method="paper", k_min=2, k_max=3,
                  restarts=2), solve=False)  # fmt: skip
    assert paper.info["order"] == 1 and paper.info["order_comparison"] is None
    assert paper.info["cluster"]["min_gain"] == 0.0  # the paper's hard EM: BIC alone
    given = learn(task, demos, k_min=2, k_max=3, restarts=2, min_gain=0.03, solve=False)
    assert given.info["cluster"]["min_gain"] == given.info["cluster"]["strong_gain"] == 0.03
    assert given.info["cluster"]["heldout_gain"] == pytest.approx(0.015)
    # why the clustering stopped where it did, against the thresholds it used
    step = given.info["next_step"]
    assert info["next_step"] is None  # (criterion="bic": only icl_or_gain's steps are named)
    assert (step is None) == (given.info["k_clustered"] == 3)
    if step is not None:
        assert step["k"] == given.info["k_clustered"] + 1
        assert step["thresholds"]["min_gain"] == 0.03
        assert step["thresholds"]["heldout_gain"] == pytest.approx(0.015)
    second = learn(task, demos, k_min=2, k_max=3, restarts=2, order=2, solve=False)
    assert second.info["order"] == 2 and second.info["cluster"]["order"] == 2
    with pytest.raises(ValueError, match="either in cluster= or as keywords"):
        learn(task, demos, cluster=ClusterConfig(k_max=3), k_min=2, solve=False)
    with pytest.raises(ValueError, match="either in irl="):
        learn(task, demos, irl=IRLConfig(), irl_epsilon=0.1, solve=False)
    with pytest.raises(ValueError, match="either in irl="):
        learn(task, demos, irl=IRLConfig(), irl_l2=0.1, solve=False)
    with pytest.raises(ValueError, match=r"expected l2 to be a number >= 0, got -1"):
        IRLConfig(l2=-1)
    with pytest.raises(ValueError, match=r"expected pooling to be a number in \[0, 1\), got 1"):
        IRLConfig(pooling=1)
    with pytest.raises(ValueError, match=r"pooling > 0 needs a ridge"):
        IRLConfig(l2=0, pooling=0.5)
    with pytest.raises(ValueError, match=r"expected wrong_moves 'symmetric' or 'learned'"):
        IRLConfig(wrong_moves="free")
    with pytest.raises(TypeError):
        ClusterConfig(k_maks=3)  # a typo is an error, not a silently ignored setting
    # more types than demonstrations: refused before any fit (it gave 43 empty types in silence)
    with pytest.raises(ValueError, match=r"expected k <= the number of demonstrations \(18\)"):
        learn(task, demos, k=19, solve=False)
    with pytest.raises(ValueError, match=r"expected k_min <= .*\(18\), got k_min = 20"):
        learn(task, demos, k_min=20, k_max=25, solve=False)
