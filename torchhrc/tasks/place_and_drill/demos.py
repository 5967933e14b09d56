"""Simulated demonstrations of the place-and-drill task (the paper's user study).

Paper (Nikolaidis et al., section "Evaluation"): the human places screws in ``n`` positions,
the robot drills each placed screw; 18 subjects gave 3 demonstrations each; the subjects
fell into a "safe" type (every screw placed before drilling began) and an "efficient" type
(each screw drilled right after its placement), and "the order of screw placement did not
affect the clustering". This module generates such a study, with ground-truth types.

A demonstration is a sequence of *turns*; in each turn the human acts, then the robot::

    human: place_<p> for an empty position p, or wait
    robot: drill_<p> for a placed, undrilled position p, or wait

It ends after the turn in which the last screw is drilled, so a sequence alternates
human and robot symbols and has even length. The vocabulary is the task's full action set,
``A = 2 n + 2`` symbols, in the canonical order of :class:`~torchhrc.data.Demonstrations`::

    index:  0 .. n-1       n            n+1 .. 2n      2n+1
    symbol: human:place_p  human:wait   robot:drill_p  robot:wait

Strategies are *chunk sizes* ``g`` (one rule covers all three types):

* ``"safe"`` (``g = n``): place all, then drill;
* ``"efficient"`` (``g = 1``): place one, drill it, repeat;
* ``"pairs"`` (``g = 2``): place two, drill those two, repeat.

and a *lag* ``l`` (0 for the three above): the robot keeps ``l`` placed screws undrilled
while the human goes on placing:

* ``"lagging"`` (``g = 1``, ``l = 1``): the robot drills the previous screw while the next
  one is placed (``place_1; place_2 drill_1; place_3 drill_2; wait drill_3``).

Placements are numbered ``0, 1, ...`` as they happen; chunk ``c`` is placements
``c g .. c g + g - 1``. With ``P`` screws placed and ``Q`` placed but undrilled, the
noiseless rules are: the human places the next screw of its placement order if
``P mod g != 0`` or ``Q <= l`` (finish the current chunk; start a new one only when at most
``l`` placed screws are undrilled), else waits; the robot drills the earliest placed
undrilled screw once its chunk is complete (``P`` reaches the chunk's end) and ``Q > l``, or
once ``P = n``, else waits.

Deviations (``deviation="other"``, the default): with probability ``noise`` (the subject's
own rate) a human step is replaced by a uniformly drawn *other legal* action of the human
(another empty position, a wait, or a placement where the rule waits); with probability
``robot_noise`` the same for a robot step (another placed undrilled screw, a wait, or a
drill where the rule waits). Every sequence therefore stays task-valid: no screw is placed
twice, no empty or drilled position is drilled, every screw ends drilled; after a deviation
the rules go on from the state it left. With ``deviation="uniform"`` a deviating step is
replaced by a uniformly random action of the same actor (any of its ``n + 1`` actions, the
rule's own included); an action that is not legal in the state (placing a placed screw,
drilling one that is not placed or already drilled) is recorded and changes nothing.
Each subject has a preferred placement order (a random permutation) which each
demonstration keeps with probability ``1 - order_change`` (``order_change=1``: a fresh
random order in every demonstration).

Why ``robot_noise`` defaults to 0 in :func:`simulate_study`: in the paper's study the
subjects demonstrated the *robot's* actions themselves (human and robot switched roles), so
the robot-role steps are the subject's own statement of preference, while the human-role
placements were replayed by the robot and matched the subject's order only 88% of the time.
Deviations are therefore modelled on the human-role steps by default; a non-zero
``robot_noise`` (e.g. for robustness studies) makes preference steps deviate too, and at the
paper's noise levels then makes some sequences indistinguishable between types (a safe
sequence whose robot drilled early twice *is* an efficient one).

Every sequence of a study is simulated at once: the state is a batch of tensors and only
the turns are a Python loop.

Example:
    >>> from torchhrc.tasks.place_and_drill.demos import simulate_study
    >>> demos = simulate_study(n_subjects=4, n_demos=2, noise=0.0, seed=0)
    >>> demos.num_sequences, demos.num_symbols, sorted(set(demos.types))
    (8, 8, ['efficient', 'safe'])
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
import torch.nn.functional as F

from torchhrc.data import Demonstrations, Step
from torchhrc.errors import ModelError

__all__ = [
    "DEVIATIONS",
    "LAGS",
    "STRATEGIES",
    "demonstration",
    "placement_orders",
    "position_names",
    "scaling_study",
    "simulate_demonstrations",
    "simulate_study",
    "task_vocabulary",
]

#: Strategy name -> chunk size ``g`` (``None``: all positions, i.e. ``g = n``).
STRATEGIES: dict[str, int | None] = {"safe": None, "efficient": 1, "pairs": 2, "lagging": 1}

#: Strategy name -> lag ``l`` (screws the robot leaves undrilled while the human places).
LAGS: dict[str, int] = {"lagging": 1}

#: How a deviating step is drawn (see the module docstring).
DEVIATIONS = ("other", "uniform")

#: Demonstrations simulated per batch by :func:`simulate_study` (bounds the turn buffers).
_BATCH = 1 << 17

_MAX_POSITIONS = 26


def position_names(n_positions: int) -> tuple[str, ...]:
    """Position names ``("A", "B", ...)`` for ``n_positions`` in ``[1, 26]``.

    Example:
        >>> position_names(3)
        ('A', 'B', 'C')
    """
    _check_positions(n_positions)
    return tuple(chr(ord("A") + i) for i in range(n_positions))


def task_vocabulary(n_positions: int) -> tuple[Step, ...]:
    """The task's ``A = 2 n + 2`` symbols: places, human wait, drills, robot wait.

    Example:
        >>> [f"{a}:{b}" for a, b in task_vocabulary(1)]
        ['human:place_A', 'human:wait', 'robot:drill_A', 'robot:wait']
    """
    names = position_names(n_positions)
    return (
        *(("human", f"place_{p}") for p in names),
        ("human", "wait"),
        *(("robot", f"drill_{p}") for p in names),
        ("robot", "wait"),
    )


def _check_positions(n_positions: object) -> int:
    if not isinstance(n_positions, int) or isinstance(n_positions, bool):
        raise TypeError(f"expected n_positions to be an int, got {type(n_positions).__name__}")
    if not 1 <= n_positions <= _MAX_POSITIONS:
        raise ModelError(f"expected n_positions in [1, {_MAX_POSITIONS}], got {n_positions}")
    return n_positions


def _chunk_size(strategy: str, n_positions: int) -> int:
    if strategy not in STRATEGIES:
        raise ModelError(f"unknown strategy {strategy!r}, expected one of {', '.join(STRATEGIES)}")
    g = STRATEGIES[strategy]
    return n_positions if g is None else min(g, n_positions)


def _sample_other(
    legal: torch.Tensor,
    chosen: torch.Tensor,
    flip: torch.Tensor,
    generator: torch.Generator,
    uniform: bool = False,
) -> torch.Tensor:
    """Replace ``chosen`` by a uniform other legal option where ``flip`` (and one exists).

    Args:
        legal: ``(B, C)`` bool, the legal options.
        chosen: ``(B,)`` int64, the rule's option (legal).
        flip: ``(B,)`` bool, where noise strikes.
        uniform: draw among all ``C`` options instead (legal or not, ``chosen`` included).
    """
    if uniform:
        keys = torch.rand(legal.shape, generator=generator, dtype=torch.float64)
        return torch.where(flip, keys.to(legal.device).argmax(-1), chosen)
    others = legal.clone()
    others[torch.arange(legal.shape[0]), chosen] = False
    has_other = others.any(-1)
    # Uniform draw among the other legal options: argmax of random keys on them.
    keys = torch.rand(others.shape, generator=generator, dtype=torch.float64).to(legal.device)
    keys = torch.where(others, keys, torch.full_like(keys, -1.0))
    return torch.where(flip & has_other, keys.argmax(-1), chosen)


def simulate_demonstrations(
    orders: torch.Tensor,
    chunk_sizes: torch.Tensor,
    noise: torch.Tensor,
    robot_noise: torch.Tensor,
    *,
    generator: torch.Generator | None = None,
    max_noisy_turns: int | None = None,
    lags: torch.Tensor | None = None,
    deviation: str = "other",
) -> tuple[torch.Tensor, torch.Tensor]:
    """Simulate ``B`` demonstrations at once (the batched kernel of :func:`simulate_study`).

    Args:
        orders: ``(B, n)`` int64, ``orders[b]`` a permutation of ``0..n-1``: the positions
            in the order demonstration ``b`` intends to place them.
        chunk_sizes: ``(B,)`` int64 in ``[1, n]``, the strategy of each demonstration
            (``n`` safe, ``1`` efficient, ``2`` pairs).
        noise: ``(B,)`` float in ``[0, 1]``, per-step probability that a human step is
            replaced by another legal human action.
        robot_noise: ``(B,)`` float in ``[0, 1]``, the same for the robot's steps.
        generator: the random source (a fresh unseeded one if None).
        max_noisy_turns: after this many turns the rules are followed without noise so
            every demonstration ends (default ``8 n + 8``; noiseless play needs <= ``2 n``).
        lags: ``(B,)`` int64 in ``[0, n)``, the robot's lag ``l`` of each demonstration
            (default all 0; ``"lagging"`` is chunk 1, lag 1).
        deviation: ``"other"`` (another legal action) or ``"uniform"`` (any action of the
            actor, see the module docstring).

    Returns:
        ``(sequences (B, L) int64, lengths (B,) int64)`` over :func:`task_vocabulary`
        indices, padded with 0; ``lengths`` even, in ``[2 n, 2 (max_noisy_turns + 2 n)]``.

    Example:
        >>> no_noise = torch.tensor([0.0])
        >>> seqs, lengths = simulate_demonstrations(
        ...     torch.tensor([[0, 1]]), torch.tensor([1]), no_noise, no_noise)
        >>> seqs.tolist(), lengths.tolist()  # place_A drill_A place_B drill_B
        ([[0, 3, 1, 4]], [4])
    """
    if not isinstance(orders, torch.Tensor) or orders.dim() != 2 or orders.dtype != torch.int64:
        raise ModelError(
            f"expected orders to be an int64 tensor of shape (B, n), got "
            f"{getattr(orders, 'dtype', type(orders).__name__)} "
            f"{tuple(getattr(orders, 'shape', ()))}"
        )
    b, n = orders.shape
    _check_positions(n)
    device = orders.device
    if not torch.equal(orders.sort(-1).values, torch.arange(n, device=device).expand(b, n)):
        raise ModelError("expected every row of orders (B, n) to be a permutation of 0..n-1")
    if chunk_sizes.shape != (b,) or ((chunk_sizes < 1) | (chunk_sizes > n)).any():
        raise ModelError(
            f"expected chunk_sizes of shape (B,) = ({b},) with values in [1, {n}], got "
            f"shape {tuple(chunk_sizes.shape)}"
        )
    if noise.shape != (b,) or ((noise < 0) | (noise > 1)).any():
        raise ModelError(
            f"expected noise of shape (B,) = ({b},) with values in [0, 1], got "
            f"shape {tuple(noise.shape)}"
        )
    if robot_noise.shape != (b,) or ((robot_noise < 0) | (robot_noise > 1)).any():
        raise ModelError(
            f"expected robot_noise of shape (B,) = ({b},) with values in [0, 1], got "
            f"shape {tuple(robot_noise.shape)}"
        )
    if lags is None:
        lags = torch.zeros(b, dtype=torch.int64, device=device)
    if lags.shape != (b,) or ((lags < 0) | (lags >= n)).any():
        raise ModelError(
            f"expected lags of shape (B,) = ({b},) with values in [0, {n}), got "
            f"shape {tuple(lags.shape)}"
        )
    if deviation not in DEVIATIONS:
        raise ValueError(f"expected deviation in {DEVIATIONS}, got {deviation!r}")
    uniform = deviation == "uniform"
    if generator is None:
        generator = torch.Generator()
    noisy_turns = 8 * n + 8 if max_noisy_turns is None else int(max_noisy_turns)
    max_turns = noisy_turns + 2 * n
    wait_h, wait_r = n, 2 * n + 1
    rank = torch.empty_like(orders)
    rank.scatter_(1, orders, torch.arange(n, device=device).expand(b, n))  # rank[b, p]
    placed = torch.zeros(b, n, dtype=torch.bool, device=device)
    drilled = torch.zeros_like(placed)
    place_index = torch.zeros(b, n, dtype=torch.int64, device=device)  # k-th placement
    rows = torch.arange(b, device=device)
    g = chunk_sizes.to(device=device, dtype=torch.int64)
    lag = lags.to(device=device, dtype=torch.int64)
    noise = noise.to(device=device, dtype=torch.float64)
    robot_noise = robot_noise.to(device=device, dtype=torch.float64)
    out = torch.zeros(b, 2 * max_turns, dtype=torch.int64, device=device)
    lengths = torch.zeros(b, dtype=torch.int64, device=device)
    active = torch.ones(b, dtype=torch.bool, device=device)
    big = torch.iinfo(torch.int64).max
    for turn in range(max_turns):
        if not active.any():
            break
        noisy = turn < noisy_turns
        # ---- human: option p in 0..n-1 = place p, option n = wait.
        count = placed.sum(-1)
        pending = (placed & ~drilled).sum(-1)
        place_rule = (count < n) & ((count % g != 0) | (pending <= lag))
        next_pos = torch.where(placed, torch.full_like(rank, big), rank).argmin(-1)
        human = torch.where(place_rule, next_pos, torch.full_like(next_pos, n))
        if noisy:
            legal = torch.cat([~placed, placed.new_ones(b, 1)], dim=-1)
            flip = torch.rand(b, generator=generator, dtype=torch.float64).to(device) < noise
            human = _sample_other(legal, human, flip, generator, uniform)
        does_place = active & (human < n)
        hit = torch.nn.functional.one_hot(human.clamp(max=n - 1), n).bool()
        hit &= does_place[:, None] & ~placed  # an illegal placement changes nothing
        place_index = torch.where(hit, count[:, None].expand(b, n), place_index)
        placed |= hit
        # ---- robot: option p = drill p, option n = wait.
        count = placed.sum(-1)
        pend = placed & ~drilled
        first = torch.where(pend, place_index, torch.full_like(place_index, big)).argmin(-1)
        chunk_end = (place_index[rows, first] // g + 1) * g  # placements closing its chunk
        ready = pend.any(-1) & (((count >= chunk_end) & (pend.sum(-1) > lag)) | (count == n))
        robot = torch.where(ready, first, torch.full_like(first, n))
        if noisy:
            legal = torch.cat([pend, pend.new_ones(b, 1)], dim=-1)
            flip = torch.rand(b, generator=generator, dtype=torch.float64).to(device) < robot_noise
            robot = _sample_other(legal, robot, flip, generator, uniform)
        does_drill = active & (robot < n)
        drilled |= (
            torch.nn.functional.one_hot(robot.clamp(max=n - 1), n).bool()
            & does_drill[:, None]
            & pend  # an illegal drill changes nothing
        )
        # ---- record the turn's two symbols for active demonstrations.
        human_symbol = torch.where(human < n, human, torch.full_like(human, wait_h))
        robot_symbol = torch.where(robot < n, robot + n + 1, torch.full_like(robot, wait_r))
        out[:, 2 * turn] = torch.where(active, human_symbol, 0)
        out[:, 2 * turn + 1] = torch.where(active, robot_symbol, 0)
        lengths += 2 * active
        active &= ~drilled.all(-1)
    assert not active.any(), "noiseless rules always finish within 2n turns"
    max_len = int(lengths.max()) if b else 0
    return out[:, :max_len].contiguous(), lengths


def _noise_rates(
    noise: float | tuple[float, float], n_subjects: int, generator: torch.Generator
) -> torch.Tensor:
    if isinstance(noise, (int, float)) and not isinstance(noise, bool):
        low = high = float(noise)
    elif isinstance(noise, Sequence) and len(noise) == 2:
        low, high = (float(v) for v in noise)
    else:
        raise TypeError(f"expected noise to be a float or a (low, high) pair, got {noise!r}")
    if not (0.0 <= low <= high <= 1.0) or math.isnan(low) or math.isnan(high):
        raise ModelError(f"expected noise rates with 0 <= low <= high <= 1, got {noise!r}")
    u = torch.rand(n_subjects, generator=generator, dtype=torch.float64)
    return low + (high - low) * u


def scaling_study(n_sequences: int, types: int = 2, *, seed: int = 0) -> Demonstrations:
    """The corpus of the clustering-at-scale study (issue 12, ``docs/clustering.md``).

    :func:`simulate_study` with ``n_sequences // 3`` subjects of 3 demonstrations, a fresh
    random placement order in every demonstration, every step (human and robot) replaced with
    probability 0.1 by a uniformly random action of its actor; 2 types (``"safe"``,
    ``"efficient"``) at 3 positions, or 3 (adding ``"lagging"``) at 4 positions.

    Args:
        n_sequences: about how many sequences (at least 3).
        types: 2 or 3.
        seed: the simulation's seed.

    Returns:
        :class:`~torchhrc.data.Demonstrations` with ground-truth ``types``.

    Raises:
        ModelError: ``types`` is not 2 or 3, or fewer than 3 sequences.

    Example:
        >>> d = scaling_study(54, 3, seed=0)
        >>> len(d.types), sorted(set(d.types))
        (54, ['efficient', 'lagging', 'safe'])
    """
    if types not in (2, 3):
        raise ModelError(f"expected types to be 2 or 3, got {types!r}")
    if not isinstance(n_sequences, int) or n_sequences < 3:
        raise ModelError(f"expected n_sequences to be an int >= 3, got {n_sequences!r}")
    three = types == 3
    return simulate_study(
        n_subjects=n_sequences // 3,
        n_demos=3,
        n_positions=4 if three else 3,
        strategies=("safe", "efficient", "lagging") if three else ("safe", "efficient"),
        noise=0.1,
        robot_noise=0.1,
        order_change=1.0,
        deviation="uniform",
        seed=seed,
    )


def simulate_study(
    *,
    n_subjects: int = 18,
    n_demos: int = 3,
    n_positions: int = 3,
    strategies: Sequence[str] = ("safe", "efficient"),
    noise: float | tuple[float, float] = (0.0, 0.15),
    robot_noise: float | tuple[float, float] = 0.0,
    order_change: float = 0.1,
    deviation: str = "other",
    seed: int | None = 0,
    generator: torch.Generator | None = None,
) -> Demonstrations:
    """Simulate a place-and-drill demonstration study with ground-truth types.

    Subjects are split as evenly as possible between ``strategies`` (in a seeded random
    arrangement); each draws a noise rate (uniform in ``noise`` if a pair) and a preferred
    placement order, then gives ``n_demos`` demonstrations (see the module docstring).
    The default is the paper's study: 18 subjects x 3 demonstrations, 3 positions, half
    safe and half efficient.

    Args:
        n_subjects: number of subjects (ids ``"S01"``, ``"S02"``, ...).
        n_demos: demonstrations per subject (sequence ids ``"0"``, ``"1"``, ...).
        n_positions: number of screw positions ``n`` (1 to 26).
        strategies: strategy names from :data:`STRATEGIES`, distinct.
        noise: per-step probability that a human (placement-role) step deviates: one rate
            for all subjects, or a ``(low, high)`` range each subject's rate is drawn from.
        robot_noise: the same for the robot-role steps, which carry the type's preference
            (default 0; see the module docstring for why).
        order_change: probability that a demonstration uses a fresh random placement order
            instead of the subject's preferred one (1: a fresh order in every demonstration).
        deviation: how a deviating step is drawn: ``"other"`` (another legal action of the
            actor) or ``"uniform"`` (a uniformly random action of the actor, which may be
            illegal and then changes nothing).
        seed: seed of a fresh generator (ignored when ``generator`` is given).
        generator: the random source.

    Returns:
        :class:`~torchhrc.data.Demonstrations` over :func:`task_vocabulary` with
        ``types`` = each subject's strategy name.

    Raises:
        ModelError: a count, rate or strategy is out of range.

    Example:
        >>> d = simulate_study(n_subjects=2, n_demos=1, strategies=["safe"], noise=0.0)
        >>> len(d.to_lists()[0]), d.to_lists()[0][:2]  # place, robot waits, ...
        (10, [('human', 'place_B'), ('robot', 'wait')])
    """
    for name, value, low in (("n_subjects", n_subjects, 1), ("n_demos", n_demos, 1)):
        if not isinstance(value, int) or isinstance(value, bool):
            raise TypeError(f"expected {name} to be an int, got {type(value).__name__}")
        if value < low:
            raise ModelError(f"expected {name} >= {low}, got {value}")
    _check_positions(n_positions)
    if isinstance(strategies, str):
        strategies = [s.strip() for s in strategies.split(",")]
    strategies = tuple(strategies)
    if not strategies or len(set(strategies)) != len(strategies):
        raise ModelError(f"expected distinct strategy names, got {strategies!r}")
    sizes = [_chunk_size(s, n_positions) for s in strategies]
    lag_of = [min(LAGS.get(s, 0), n_positions - 1) for s in strategies]
    if deviation not in DEVIATIONS:
        raise ValueError(f"expected deviation in {DEVIATIONS}, got {deviation!r}")
    if not 0.0 <= float(order_change) <= 1.0:
        raise ModelError(f"expected order_change in [0, 1], got {order_change}")
    if generator is None:
        generator = torch.Generator()
        generator.manual_seed(0 if seed is None else int(seed))

    # Subjects: strategy (balanced, shuffled), noise rate, preferred order.
    balanced = torch.arange(n_subjects) % len(strategies)
    strategy_of = balanced[torch.randperm(n_subjects, generator=generator)]  # (S,)
    rates = _noise_rates(noise, n_subjects, generator)  # (S,)
    robot_rates = _noise_rates(robot_noise, n_subjects, generator)  # (S,)
    keys = torch.rand(n_subjects, n_positions, generator=generator)
    preferred = keys.argsort(-1)  # (S, n) a random permutation per subject
    # Demonstrations (subject-major): keep the preferred order or draw a fresh one.
    total = n_subjects * n_demos
    subject_of = torch.arange(n_subjects).repeat_interleave(n_demos)  # (B,)
    fresh = torch.rand(total, n_positions, generator=generator).argsort(-1)
    change = torch.rand(total, generator=generator, dtype=torch.float64) < float(order_change)
    orders = torch.where(change[:, None], fresh, preferred[subject_of])  # (B, n)
    chunk = torch.tensor(sizes, dtype=torch.int64)[strategy_of[subject_of]]  # (B,)
    lags = torch.tensor(lag_of, dtype=torch.int64)[strategy_of[subject_of]]  # (B,)
    # batches bound the (B, turns) buffers of the kernel; one batch for studies up to _BATCH
    parts = [
        simulate_demonstrations(
            orders[i : i + _BATCH],
            chunk[i : i + _BATCH],
            rates[subject_of[i : i + _BATCH]],
            robot_rates[subject_of[i : i + _BATCH]],
            generator=generator,
            lags=lags[i : i + _BATCH],
            deviation=deviation,
        )
        for i in range(0, total, _BATCH)
    ]
    if len(parts) == 1:
        sequences, lengths = parts[0]
    else:
        width_l = max(p[0].shape[1] for p in parts)
        sequences = torch.cat([F.pad(p[0], (0, width_l - p[0].shape[1])) for p in parts])
        lengths = torch.cat([p[1] for p in parts])
    width = max(2, len(str(n_subjects)))
    subject_names = [f"S{i + 1:0{width}d}" for i in range(n_subjects)]
    subject_list = subject_of.tolist()
    return Demonstrations(
        vocabulary=task_vocabulary(n_positions),
        sequences=sequences,
        lengths=lengths,
        subjects=tuple(subject_names[s] for s in subject_list),
        sequence_ids=tuple(str(i % n_demos) for i in range(total)),
        types=tuple(strategies[int(strategy_of[s])] for s in subject_list),
    )


def demonstration(strategy: str, order: Sequence[str] | str) -> list[Step]:
    """The noiseless demonstration of ``strategy`` for a placement ``order``.

    Args:
        strategy: a name from :data:`STRATEGIES`.
        order: the positions in placement order, e.g. ``"BAC"`` or ``["B", "A", "C"]``; a
            permutation of ``position_names(len(order))``.

    Example:
        >>> [f"{a[0]}:{b}" for a, b in demonstration("efficient", "BA")]
        ['h:place_B', 'r:drill_B', 'h:place_A', 'r:drill_A']
        >>> [f"{a[0]}:{b}" for a, b in demonstration("lagging", "BA")]
        ['h:place_B', 'r:wait', 'h:place_A', 'r:drill_B', 'h:wait', 'r:drill_A']
    """
    order = tuple(order)
    n = len(order)
    names = position_names(n)
    if sorted(order) != list(names):
        raise ModelError(f"expected order to be a permutation of {names}, got {order!r}")
    perm = torch.tensor([[names.index(p) for p in order]], dtype=torch.int64)
    g = torch.tensor([_chunk_size(strategy, n)])
    lag = torch.tensor([min(LAGS.get(strategy, 0), n - 1)])
    zero = torch.zeros(1, dtype=torch.float64)
    seqs, lengths = simulate_demonstrations(perm, g, zero, zero, lags=lag)
    vocab = task_vocabulary(n)
    return [vocab[a] for a in seqs[0, : int(lengths[0])].tolist()]


def placement_orders(demonstrations: Demonstrations) -> dict[str, list[tuple[str, ...]]]:
    """Each subject's demonstrated placement order(s), read from its sequences.

    The order of a sequence is the positions of its ``human:place_<p>`` steps, in the order
    they occur (a real or simulated file alike; noise included).

    Returns:
        ``{subject: [order of each of its sequences, in sequence order]}``, each order a
        tuple of position names.

    Example:
        >>> d = Demonstrations.from_lists([demonstration("safe", "CAB")], subjects=["s"])
        >>> placement_orders(d)
        {'s': [('C', 'A', 'B')]}
    """
    place_of = [
        action[len("place_") :] if actor == "human" and action.startswith("place_") else None
        for actor, action in demonstrations.vocabulary
    ]
    out: dict[str, list[tuple[str, ...]]] = {s: [] for s in demonstrations.unique_subjects}
    rows = demonstrations.sequences.cpu().tolist()
    for subject, row, length in zip(
        demonstrations.subjects, rows, demonstrations.lengths.cpu().tolist()
    ):
        order = tuple(place_of[a] for a in row[:length] if place_of[a] is not None)
        out[subject].append(order)  # type: ignore[arg-type]
    return out
