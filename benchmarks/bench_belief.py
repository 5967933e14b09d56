"""Benchmark the belief updates (torchhrc.pomdp.belief) against pomdp-py's histogram update.

Three ratios, each measured in the same run:

1. torchhrc vs pomdp-py: seconds per belief update of ``torchhrc.pomdp.belief.update`` on a batch
   of ``M`` beliefs (one call, per-belief actions and observations) against
   ``pomdp_py.update_histogram_belief`` (one belief at a time, a Python double loop over
   states calling the model's ``probability``; its models here read the same tables), on
   Tiger, RockSample(4, 4) and Tag. Both give the same beliefs (checked).
2. batched vs one belief at a time: ``update`` of ``M`` beliefs in one call against a Python
   loop of ``M`` single-belief calls (same function, same results).
3. MOMDP vs flat: ``momdp_update_all`` (every ``(a, x2, o)``) against ``update_all`` on
   ``to_pomdp()`` for the same beliefs, on RockSample(4, 4) and Tag (robot position observed).

    python benchmarks/bench_belief.py [--repeats 3] [--beliefs 256] [--threads 1]

Prints a Markdown table (times are medians over the repeats).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch
from _timing import median_time

from torchhrc.pomdp import POMDP
from torchhrc.pomdp.belief import momdp_update_all, update, update_all
from torchhrc.tasks.classic import rock_sample, tag, tiger


def _pomdp_py_update(model: POMDP, belief: np.ndarray, action: int, observation: int):
    """One pomdp-py histogram update over ``model``'s tables; returns the new belief."""
    import pomdp_py

    T = model.T.numpy()
    Z = model.Z.numpy()

    class Transition(pomdp_py.TransitionModel):
        def probability(self, next_state, state, action):
            return T[action, state, next_state]

    class Observation(pomdp_py.ObservationModel):
        def probability(self, observation, next_state, action):
            return Z[action, next_state, observation]

    hist = pomdp_py.Histogram({s: float(p) for s, p in enumerate(belief)})
    new = pomdp_py.update_histogram_belief(hist, action, observation, Observation(), Transition())
    return np.array([new[s] for s in range(len(belief))])


def _sample_steps(model: POMDP, beliefs: torch.Tensor, seed: int):
    """Actions and observations of positive probability for each belief."""
    g = torch.Generator().manual_seed(seed)
    M = beliefs.shape[0]
    actions = torch.randint(model.num_actions, (M,), generator=g)
    states = torch.multinomial(beliefs, 1, generator=g).squeeze(-1)
    next_states = torch.multinomial(model.T[actions, states], 1, generator=g).squeeze(-1)
    observations = torch.multinomial(model.Z[actions, next_states], 1, generator=g).squeeze(-1)
    return actions, observations


def _beliefs(model: POMDP, M: int, seed: int) -> torch.Tensor:
    """``M`` reachable-looking beliefs: the initial belief after a few random updates."""
    beliefs = model.b0.expand(M, -1).contiguous()
    for k in range(3):
        a, o = _sample_steps(model, beliefs, seed + k)
        beliefs = update(model, beliefs, a, o).belief
    return beliefs


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--beliefs", type=int, default=256)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--pomdp-py-updates", type=int, default=3)
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    M = args.beliefs
    print(f"torch {torch.__version__}, {args.threads} thread(s), M = {M} beliefs\n")
    print("| problem | S | torchhrc s/update (batched) | pomdp-py s/update | ratio |")
    print("|---|---|---|---|---|")
    problems = {"Tiger": tiger(), "RockSample(4,4)": rock_sample(4, 4), "Tag": tag()}
    for name, model in problems.items():
        beliefs = _beliefs(model, M, seed=0)
        a, o = _sample_steps(model, beliefs, seed=10)
        ours = (
            median_time(lambda m=model, b=beliefs, a=a, o=o: update(m, b, a, o), args.repeats) / M
        )
        n = min(args.pomdp_py_updates, M)
        _pomdp_py_update(model, beliefs[0].numpy(), int(a[0]), int(o[0]))  # warm up (import)
        start = time.perf_counter()
        for i in range(n):
            ref = _pomdp_py_update(model, beliefs[i].numpy(), int(a[i]), int(o[i]))
            mine = update(model, beliefs[i], int(a[i]), int(o[i])).belief.numpy()
            assert np.allclose(ref, mine, atol=1e-9), "pomdp-py and torchhrc disagree"
        theirs = (time.perf_counter() - start) / n
        print(f"| {name} | {model.num_states} | {ours:.2e} | {theirs:.2e} | {theirs / ours:.0f}x |")

    print("\n| problem | batched s (M beliefs) | loop s (M calls) | ratio |")
    print("|---|---|---|---|")
    for name, model in problems.items():
        beliefs = _beliefs(model, M, seed=1)
        a, o = _sample_steps(model, beliefs, seed=11)
        batched = median_time(lambda m=model, b=beliefs, a=a, o=o: update(m, b, a, o), args.repeats)
        pairs = list(zip(beliefs, a.tolist(), o.tolist()))
        loop = median_time(lambda m=model, p=pairs: [update(m, b, ai, oi) for b, ai, oi in p], 1)
        print(f"| {name} | {batched:.3e} | {loop:.3e} | {loop / batched:.0f}x |")

    print("\n| problem | momdp_update_all s | update_all on to_pomdp() s | ratio |")
    print("|---|---|---|---|")
    for name, mm in {
        "RockSample(4,4)": rock_sample(4, 4, form="momdp"),
        "Tag": tag(form="momdp", robot_start=0),
    }.items():
        flat = mm.to_pomdp()
        m = min(M, 64)
        g = torch.Generator().manual_seed(2)
        x = torch.randint(mm.num_observed, (m,), generator=g)
        by = torch.distributions.Dirichlet(torch.ones(mm.num_hidden, dtype=torch.float64)).sample(
            (m,)
        )
        onehot = torch.nn.functional.one_hot(x, mm.num_observed).double()
        b_flat = (onehot[:, :, None] * by[:, None]).reshape(m, -1)
        fact = median_time(lambda mm=mm, x=x, by=by: momdp_update_all(mm, x, by), args.repeats)
        flat_t = median_time(lambda f=flat, b=b_flat: update_all(f, b), args.repeats)
        print(f"| {name} ({m} beliefs) | {fact:.3e} | {flat_t:.3e} | {flat_t / fact:.1f}x |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
