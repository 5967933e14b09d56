"""The state human model (CollaborativeTask.human_policy, human_model='state'): "no action"
counted, hierarchical back-off to the type's habit and the population, values worked by
hand."""

from __future__ import annotations

import torch

from torchhrc.data import Demonstrations
from torchhrc.tasks.interface import CollaborativeTask, TypeEvidence


class Chores(CollaborativeTask):
    """Two chores a, b; the robot's "go" changes nothing; a done chore cannot be redone."""

    state_names = ("none", "a", "b", "ab")
    robot_actions = ("go",)
    human_actions = ("do_a", "do_b")
    robot_effect = torch.tensor([[0, 1, 2, 3]])
    human_effect = torch.tensor([[1, 2], [1, 3], [3, 2], [3, 3]])
    human_model = "state"


VOCAB = (("human", "do_a"), ("human", "do_b"), ("robot", "go"))


def _evidence(noise: float = 0.0, pause: float = 0.0, model: str | None = None):
    task = Chores()
    # type 0: go, do_a | go, (no action) | go, do_b; type 1: go, do_b | go (recording ends)
    demos = Demonstrations.from_lists(
        [
            [("robot", "go"), ("human", "do_a"), ("robot", "go"), ("robot", "go"),
             ("human", "do_b")],
            [("robot", "go"), ("human", "do_b"), ("robot", "go")],
        ],
        vocabulary=list(VOCAB),
    )  # fmt: skip
    steps = task.read_steps(demos)
    chains = torch.zeros(3, 3, 3, dtype=torch.float64)
    chains[:, :2] = 1.0 / 3.0  # rows after a human symbol (unused)
    chains[0, 2] = torch.tensor([0.6, 0.2, 0.2])  # P(. | robot:go), type 0
    chains[1, 2] = torch.tensor([0.1, 0.5, 0.4])
    chains[2, 2] = torch.tensor([0.3, 0.1, 0.6])  # type 2 has no demonstrations
    evidence = TypeEvidence(chains, demos.vocabulary, torch.tensor([0, 1]), steps,
                            noise=noise, pause=pause, human_model=model)  # fmt: skip
    return task, evidence


def test_counts_no_action_and_backs_off_to_the_type_habit_and_the_population():
    task, evidence = _evidence()
    p = task.human_policy(evidence)[:, 0]  # (Y, X, H + 1), the one robot action
    # pooled waiting rates: type 0 waited 1 of 3 choices -> (1 + .5) / (3 + 1) = 3/8;
    # type 1 0 of 1 (its last step has no human turn: not counted) -> .5 / 2 = 1/4;
    # type 2 no steps -> 1/2. Chain prior: chain preference over legal actions x (1 - rate),
    # rate. "go" changes nothing, so the state before the robot's move is the state after:
    # the habit is (counts + chain prior) / (n + 1) (one pseudo-step). The population: all
    # counts + the habits weighted by the types' shares (1/2, 1/2, 0), normalised. The prior:
    # 3/4 habit + 1/4 population (TypeEvidence.habit_weight, default 0.75);
    # p = (counts + prior) / (n + 1).
    # Where a type's partners never went (x_before unvisited: the move is unusual, u = 1),
    # the habit's "no action" is raised by the type's off-script lift d (its other actions
    # rescaled to the rest): d = (sum of u (pass - habit's pass share, the turn left out)
    # over its turns + 2 D) / (sum of u + 2), D the same over every type's turns toward 0;
    # u = 1 for a turn in a state the type visited once, 0 here for one of two "go"s.
    # Type 0: its turn at "none" (u = 1, do_a), whose left-out habit is the chain prior
    # (pass 3/8): -3/8; its turns at "a": u = 0. Type 1: its turn at "none" (u = 1, do_b),
    # chain prior pass 1/4: -1/4. D = (-3/8 - 1/4) / (2 + 2) = -5/32; d = (-3/8 - 5/16) / 3
    # = -11/48, (-1/4 - 5/16) / 3 = -3/16, and D for type 2 (no turns).
    habit = {
        (0, 0): [47 / 64, 5 / 64, 12 / 64],  # (1, 0, 0) + (5/8 * (.75, .25), 3/8), over 2
        (0, 1): [0.0, 13 / 24, 11 / 24],  # "a", only do_b legal: (0, 1, 1) + (0, 5/8, 3/8)
        (1, 0): [1 / 16, 13 / 16, 1 / 8],  # (0, 1, 0) + (3/4 * (1/6, 5/6), 1/4), over 2
        (1, 1): [0.0, 15 / 16, 1 / 16],  # "a" never seen: the chain prior (0, .75, .25)
        (1, 2): [15 / 16, 0.0, 1 / 16],  # "b" never seen with a turn: (.75, 0, .25)
        (0, 2): [41 / 48, 0.0, 7 / 48],  # the chain prior (5/8, 0, 3/8)
        # no data: its chain preference x 1/2 and rate 1/2, less 5/32
        (2, 0): [63 / 128, 21 / 128, 44 / 128],
    }
    population = {
        # counts (1, 1, 0) + (habit00 + habit10) / 2 = (51, 57, 20) / 128, over 3
        0: [179 / 384, 185 / 384, 20 / 384],
        # counts (0, 1, 1) + (habit01 + habit11) / 2 = (0, 71, 25) / 96, over 3
        1: [0.0, 167 / 288, 121 / 288],
        # no counts: (habit02 + habit12) / 2
        2: [43 / 48, 0.0, 5 / 48],
    }
    counts = {(0, 0): [1.0, 0.0, 0.0], (0, 1): [0.0, 1.0, 1.0], (1, 0): [0.0, 1.0, 0.0],
              (1, 2): [0.0, 0.0, 0.0], (2, 0): [0.0, 0.0, 0.0]}  # fmt: skip
    for (y, x), n in counts.items():
        n_ = torch.tensor(n, dtype=p.dtype)
        h, q = torch.tensor(habit[y, x], dtype=p.dtype), torch.tensor(population[x], dtype=p.dtype)
        want = (n_ + 0.75 * h + 0.25 * q) / (n_.sum() + 1)
        assert torch.allclose(p[y, x], want, atol=1e-12), (y, x)
    # type 2 has no data: 3/4 its own chain preference, not the others' behaviour
    assert torch.allclose(p[2, 0], torch.tensor([746, 374, 416], dtype=p.dtype) / 1536,
                          atol=1e-12)  # fmt: skip
    # "ab": nothing legal, "no action" is certain for every type
    assert torch.allclose(p[:, 3], torch.tensor([0.0, 0.0, 1.0], dtype=p.dtype))


def test_noise_and_pause_mix_as_documented_and_rows_sum_to_one():
    task, plain = _evidence()
    q = task.human_policy(plain)[:, 0]
    e, s = 0.1, 0.02
    _, mixed = _evidence(noise=e, pause=s)
    p = task.human_policy(mixed)
    assert torch.allclose(p.sum(-1), torch.ones_like(p[..., 0]), atol=1e-12)
    assert (p >= 0).all()
    u = torch.tensor([[0.5, 0.5], [0.0, 1.0], [1.0, 0.0], [0.0, 0.0]], dtype=q.dtype)  # (X, H)
    want_h = (1 - s) * ((1 - e) * q[..., :2] + e * u)
    want_none = (1 - s) * (1 - e) * q[..., 2] + s
    want_none[:, 3] = 1.0  # nothing legal: all "no action"
    assert torch.allclose(p[:, 0, :, :2], want_h, atol=1e-12)
    assert torch.allclose(p[:, 0, :, 2], want_none, atol=1e-12)


def test_chain_model_gives_no_action_only_the_pause():
    task, evidence = _evidence(noise=0.05, pause=0.03, model="chain")
    p = task.human_policy(evidence)[:, 0]  # (Y, X, H + 1)
    assert torch.allclose(p[:, :3, 2], torch.full((3, 3), 0.03, dtype=p.dtype), atol=1e-12)
    # type 0 in "none": (1 - .03) * (.95 * (.75, .25) + .05 * (.5, .5))
    want = 0.97 * (0.95 * torch.tensor([0.75, 0.25]) + 0.05 * torch.tensor([0.5, 0.5]))
    assert torch.allclose(p[0, 0, :2], want.to(p.dtype), atol=1e-12)
