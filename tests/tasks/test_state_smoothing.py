"""The state model's smoothing chosen on held-out subjects (compare_human_models,
build_model(state_smoothing="auto")): it trusts a type's habit after moves its partners
rarely made exactly where the people keep their habit there."""

from __future__ import annotations

import pytest
import torch
from _fetch_phases import FetchPhases, fetch_demonstrations

from torchhrc.tasks.human_model_choice import STATE_SMOOTHING_GRID, compare_human_models
from torchhrc.tasks.interface import TypeEvidence
from torchhrc.tasks.pipeline import build_model, learn


def _demos(reactive: bool, subjects: int = 16, per_subject: int = 3, seed: int = 0):
    """Type 0 works left, type 1 right. Every partner waits, and one move in 10 fetches a
    part (left or right, even odds), whatever the type (so no state is confounded: the
    partners' moves do not carry the type). ``reactive``: after a fetch the person works the
    side fetched; otherwise they keep their own side whatever was fetched."""
    return fetch_demonstrations(lambda y, t, a: a - 1 if reactive and a > 0 else y,
                                subjects, per_subject, seed)  # fmt: skip


def _rare_turn(task, demos, types, smoothing) -> float:
    """P(own side | the other part fetched) for type 0 under ``smoothing``: after
    ``fetch_right`` at phase 0 (nothing fetched), which type 0's partners made once in 20."""
    V = len(demos.vocabulary)
    evidence = TypeEvidence(torch.full((2, V, V), 1.0 / V, dtype=torch.float64),
                            tuple(tuple(v) for v in demos.vocabulary), types,
                            task.read_steps(demos), noise=0.05, pause=0.01,
                            human_model="state", habit_weight=smoothing[0],
                            prior_strength=smoothing[1])  # fmt: skip
    b = task.human_policy(evidence)  # (Y, A, X, H + 1)
    return float(b[0, 2, 0, 0])  # type 0, fetch_right at phase 0 (nothing fetched)


@pytest.mark.numeric
@pytest.mark.parametrize("reactive", [False, True])
def test_the_chosen_smoothing_predicts_rare_turns_as_the_people_make_them(reactive):
    task = FetchPhases()
    demos, types = _demos(reactive)
    record = compare_human_models(task, demos, types, noise=0.05, pause=0.01, seed=0,
                                  models=("state",))  # fmt: skip
    chosen = record["state_smoothing"]
    w, c = chosen["habit_weight"], chosen["prior_strength"]
    scores = {(g["habit_weight"], g["prior_strength"]): g["heldout"] for g in record["state_grid"]}
    assert set(scores) == set(STATE_SMOOTHING_GRID)
    assert scores[(w, c)] == max(scores.values()) == record["heldout"]["state"]
    default = STATE_SMOOTHING_GRID[0]
    own = _rare_turn(task, demos, types, (w, c))
    own_default = _rare_turn(task, demos, types, default)
    assert record["confounded"] == 0.0
    if reactive:
        # the person works the side fetched: her own habit (own side) misleads after a
        # fetch, and her reaction to the fetch, seen after her partners' rare fetches in the
        # other phases, predicts it (test_reaction.py): the side fetched, under the chosen
        # smoothing and the default alike (before the reaction joined the back-off, only
        # the smallest habit weight of the grid, 0.5, lowered the own side)
        assert own < 0.2 and own_default < 0.2
    else:
        # the person keeps their side: the habit carries (the largest weight of the grid),
        # and the chosen smoothing predicts the own side after the rare move more surely,
        # close to the most the learner's noise and pause allow, 0.99 * (0.95 + 0.025)
        assert w == 0.98
        assert own > own_default + 0.02
        assert own > 0.95


def _own_side_partner(y: int, u: float) -> int:
    """Each type's partners fetch the type's own side's part (type 0 left, 1 right), and one
    move in 10 the other side's: every state's partner move carries the type."""
    return 1 + y if u >= 0.1 else 2 - y


@pytest.mark.numeric
@pytest.mark.parametrize("seed", [0, 1])
def test_where_partners_carry_the_type_the_smoothing_is_judged_on_the_moves_made(seed):
    # Every state is confounded (the partners of the two types fetch different parts), so
    # the choice of human model scores a held-out person without the move, under the pooled
    # partners' moves. The smoothing is the carry of a type's turns to moves its partners
    # rarely made; judged that way, each move's prediction would be scored by the turn that
    # followed another move (type 0 works left after the left part, her partners' usual
    # move: a model that predicts "left" after the right part too scores well). These
    # people work the side fetched, and the held-out turns after the partners' rare moves,
    # scored with the moves made, say so.
    task = FetchPhases()
    demos, types = fetch_demonstrations(lambda y, t, a: a - 1, seed=seed,
                                        partner=_own_side_partner)  # fmt: skip
    record = compare_human_models(task, demos, types, noise=0.05, pause=0.01, seed=0,
                                  models=("state",))  # fmt: skip
    assert record["confounded"] == 1.0
    grid = record["state_grid"]
    by_moves = max(grid, key=lambda g: g["heldout_demonstrated"])
    without = max(grid, key=lambda g: g["heldout"])
    chosen = record["state_smoothing"]
    pair = (chosen["habit_weight"], chosen["prior_strength"])
    assert pair == (by_moves["habit_weight"], by_moves["prior_strength"])
    blind = (without["habit_weight"], without["prior_strength"])
    assert blind != pair  # the two scores disagree here (a habit weight of 0.98 without)
    # type 0 after the right part, which her partners fetched one move in 20: she works
    # right, so "left" is the learner's noise and pause, about 0.03; the smoothing the
    # score without the move prefers predicts "left" 3 to 4 times as often
    own, other = _rare_turn(task, demos, types, pair), _rare_turn(task, demos, types, blind)
    assert own < 0.05
    assert other > 2 * own


@pytest.mark.filterwarnings("ignore::torchhrc.irl.projection.IRLConvergenceWarning")
def test_build_model_uses_and_records_the_smoothing():
    task = FetchPhases()
    demos, types = _demos(reactive=False)
    chains = torch.full((2, 5, 5), 0.2, dtype=torch.float64)
    auto = build_model(task, demos, chains, types, irl_iterations=1)
    chosen = auto.info["human_model"]["state_smoothing"]
    assert auto.info["human_model"]["used"] == "state" and chosen["habit_weight"] == 0.98
    given = build_model(task, demos, chains, types, irl_iterations=1,
                        state_smoothing=(0.5, 16.0))  # fmt: skip
    assert given.info["human_model"]["state_smoothing"] == {"habit_weight": 0.5,
                                                             "prior_strength": 16.0}  # fmt: skip
    # the behaviour built is the recorded smoothing's
    want = _rare_turn(task, demos, types, (chosen["habit_weight"], chosen["prior_strength"]))
    got = float(auto.behaviour[0, 2, 0, 0])
    assert got == pytest.approx(want, abs=1e-9)
    # both numbers of the pair reach the behaviour (a strength of 1 would give another)
    assert float(given.behaviour[0, 2, 0, 0]) == pytest.approx(
        _rare_turn(task, demos, types, (0.5, 16.0)), abs=1e-9
    )
    assert abs(_rare_turn(task, demos, types, (0.5, 16.0))
               - _rare_turn(task, demos, types, (0.5, 1.0))) > 0.01  # fmt: skip
    # the reaction weights are recorded, one per type: these people keep their side
    assert auto.info["human_model"]["reaction"] == [0.0, 0.0]
    answer, answer_types = _demos(reactive=True)
    reactive = build_model(task, answer, chains, answer_types, irl_iterations=1)
    assert min(reactive.info["human_model"]["reaction"]) >= 0.5


@pytest.mark.parametrize(
    "value, error, match",
    [
        ((1.5, 1.0), ValueError, "habit_weight in \\[0, 1\\], got 1.5"),
        ((0.5, 0.0), ValueError, "prior_strength a finite number above 0, got 0.0"),
        ("best", ValueError, "state_smoothing 'auto' or a pair"),
        ((0.5,), TypeError, "state_smoothing 'auto' or a pair"),
    ],
)
def test_bad_smoothing_is_refused_before_any_work(value, error, match):
    task = FetchPhases()
    demos, _ = _demos(reactive=False, subjects=2, per_subject=1)
    with pytest.raises(error, match=match):
        learn(task, demos, k=1, solve=False, state_smoothing=value)
    with pytest.raises(ValueError, match="habit_weight"):
        TypeEvidence(torch.zeros(1, 1, 1), (("robot", "wait"),), torch.zeros(1), None,
                     habit_weight=-0.1)  # fmt: skip


@pytest.mark.numeric
def test_few_subjects_keep_the_best_pair_of_the_held_out_turns():
    # 6 subjects, 2 demonstrations each, people who answer the rare fetch: another pair
    # than the default scores best by about 0.5 nats. The pair with the best held-out
    # score is kept however small its gain (a guard of one standard error of the subjects'
    # differences kept the default here; on the 480 runs of the held-out tasks it kept the
    # default where the best pair won: docs/evaluation_history.md, "The smoothing judged on
    # the moves made")
    task = FetchPhases()
    demos, types = _demos(reactive=True, subjects=6, per_subject=2, seed=4)
    record = compare_human_models(task, demos, types, noise=0.05, pause=0.01, seed=0,
                                  models=("state",))  # fmt: skip
    grid = record["state_grid"]
    top = max(grid, key=lambda g: g["heldout_demonstrated"])
    assert (top["habit_weight"], top["prior_strength"]) != STATE_SMOOTHING_GRID[0]
    assert 0.0 < top["heldout_demonstrated"] - grid[0]["heldout_demonstrated"] < 1.0
    chosen = record["state_smoothing"]
    assert (chosen["habit_weight"], chosen["prior_strength"]) == (
        top["habit_weight"],
        top["prior_strength"],
    )
    assert record["heldout"]["state"] == top["heldout"]
