"""A policy solved from a multi-variable ``.pomdpx`` file, written as ``.policyx``, is right.

The file is RockSample(4, 4) written the way APPL's ``examples/POMDPX/RockSample_*.pomdpx``
are: one observed ``robot`` variable and one hidden variable per rock, so the hidden index
joins four variables. The model it is built from (:func:`~torchhrc.tasks.classic.
rock_sample` with ``form="momdp"``) numbers the rock states the other way (bit ``i`` of ``y``
is rock ``i``), so every check below goes through the variables' names, independently of
``read_pomdpx``'s index:

* ``read_pomdpx`` joins the hidden variables as APPL's ``FactoredPomdp`` does (the first
  declared varies slowest, ``mapFactoredStatesToValue``): the tensors read equal the source
  model's, permuted by the names;
* the ``.policyx`` written from a SARSOP solve of the file, read back and re-indexed by the
  names onto the source model, realises the solver's lower bound: its vectors are uniformly
  improvable at every belief the greedy policy reaches (``V_low(b) <= max_a Q_low(b, a)``,
  exact arithmetic, no sampling error), and a Monte Carlo run of the greedy policy does not
  fall below the lower bound. Before the fix of ``sarsop`` (a MOMDP's vectors pruned at tree
  beliefs) both failed: a kept vector's child vectors were pruned, the greedy policy looped on
  a ``check``, and APPL's ``pomdpeval`` simulated the written RockSample_7_8 policy at 19.0
  against a lower bound of 20.3;
* with APPL installed (``TORCHHRC_APPL_BIN``), APPL's ``pomdpeval`` reads the same file and
  policy and simulates a value within the bounds.
"""

from __future__ import annotations

import math
import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest
import torch

from torchhrc.io import read_policyx, read_pomdpx, read_pomdpx_variables, write_policyx
from torchhrc.pomdp import MOMDP
from torchhrc.pomdp.sparse_momdp import SparseMOMDP
from torchhrc.solvers.evaluate import evaluate_policy
from torchhrc.solvers.policy import AlphaVectorPolicy
from torchhrc.solvers.sampling import momdp_step, sample_categorical
from torchhrc.solvers.sarsop import SARSOPConfig, sarsop
from torchhrc.tasks.classic import rock_sample

K = 4  # rocks
ITERATIONS = 60  # the old pruning had broken the policy by then (V_low - max Q_low = 0.5)


def _values(t: torch.Tensor) -> str:
    return " ".join(repr(float(v)) for v in t.reshape(-1))


def _cond(var: str, parents: str, table: torch.Tensor) -> str:
    dashes = " ".join("-" for _ in range(len(table.shape)))
    return (
        f'<CondProb><Var>{var}</Var><Parent>{parents}</Parent><Parameter type="TBL">'
        f"<Entry><Instance>{dashes}</Instance><ProbTable>{_values(table)}</ProbTable></Entry>"
        "</Parameter></CondProb>"
    )


def _file_order(m: MOMDP) -> torch.Tensor:
    """``(Y,)``: the source model's hidden index of each joint index of the file's rocks
    (``rock0`` declared first, varying slowest), built from the hidden states' names."""
    out = []
    for j in range(m.num_hidden):
        good = [(j >> (K - 1 - i)) & 1 for i in range(K)]  # rock i's value in the file
        name = "".join("G" if g else "B" for g in good)  # source names: letter i = rock i
        out.append(m.hidden_states.index(name))
    return torch.tensor(out)


def factored_rocksample() -> tuple[str, MOMDP]:
    """RockSample(4, 4) as an APPL-style ``.pomdpx`` text with one variable per rock."""
    m = rock_sample(4, K, form="momdp")
    A, X, Y, O = m.num_actions, m.num_observed, m.num_hidden, m.num_observations
    perm = _file_order(m)
    robot = " ".join(m.observed_states)
    # the robot moves independently of the rocks; a rock is spoiled only by sampling it
    Tx = m.Tx[:, :, 0, :]  # (A, X, X2)
    x2 = Tx.argmax(-1)  # deterministic moves
    rock_t = []
    for i in range(K):
        t = torch.zeros(A, X, 2, 2, dtype=torch.float64)
        for r in (0, 1):
            y = r << i
            ty = m.Ty[torch.arange(A)[:, None], torch.arange(X)[None], y, x2]  # (A, X, Y2)
            good = ty[..., [y2 for y2 in range(Y) if (y2 >> i) & 1]].sum(-1)
            t[:, :, r, 1], t[:, :, r, 0] = good, 1 - good
        rock_t.append(t)
    rocks_prev = " ".join(f"rock{i}_0" for i in range(K))
    rocks_curr = " ".join(f"rock{i}_1" for i in range(K))
    Z = m.Z[:, :, perm, :].reshape(A, X, *[2] * K, O)  # rocks in file order, rock0 slowest
    R = m.R[:, :, perm]
    b0 = torch.zeros(X, dtype=torch.float64)
    b0[m.x0] = 1.0
    lines = [
        '<?xml version="1.0" encoding="ISO-8859-1"?>',
        '<pomdpx version="1.0" id="rs44">',
        "<Description>RockSample(4, 4), one variable per rock</Description>",
        f"<Discount>{m.discount!r}</Discount>",
        "<Variable>",
        '<StateVar vnamePrev="robot_0" vnameCurr="robot_1" fullyObs="true">'
        f"<ValueEnum>{robot}</ValueEnum></StateVar>",
        *(
            f'<StateVar vnamePrev="rock{i}_0" vnameCurr="rock{i}_1" fullyObs="false">'
            "<ValueEnum>bad good</ValueEnum></StateVar>"
            for i in range(K)
        ),
        f'<ObsVar vname="sensor"><ValueEnum>{" ".join(m.observations)}</ValueEnum></ObsVar>',
        f'<ActionVar vname="act"><ValueEnum>{" ".join(m.actions)}</ValueEnum></ActionVar>',
        '<RewardVar vname="reward"/>',
        "</Variable>",
        "<InitialStateBelief>",
        _cond("robot_0", "null", b0),
        *(
            _cond(f"rock{i}_0", "null", torch.full((2,), 0.5, dtype=torch.float64))
            for i in range(K)
        ),
        "</InitialStateBelief>",
        "<StateTransitionFunction>",
        _cond("robot_1", "act robot_0", Tx),
        *(_cond(f"rock{i}_1", f"act robot_0 rock{i}_0", rock_t[i]) for i in range(K)),
        "</StateTransitionFunction>",
        "<ObsFunction>",
        _cond("sensor", f"act robot_1 {rocks_curr}", Z),
        "</ObsFunction>",
        "<RewardFunction>",
        f'<Func><Var>reward</Var><Parent>act robot_0 {rocks_prev}</Parent><Parameter type="TBL">'
        f"<Entry><Instance>{' '.join('-' for _ in range(2 + K))}</Instance>"
        f"<ValueTable>{_values(R)}</ValueTable></Entry></Parameter></Func>",
        "</RewardFunction>",
        "</pomdpx>",
    ]
    return "\n".join(lines) + "\n", m


@pytest.fixture(scope="module")
def factored() -> tuple[str, MOMDP, torch.Tensor]:
    text, source = factored_rocksample()
    # the file's hidden index -> the source model's, by the variables' value names
    v = read_pomdpx_variables(text)
    to_source = []
    for j in range(v.size("hidden")):
        values = v.decode("hidden", j)
        name = "".join("G" if values[f"rock{i}_1"] == "good" else "B" for i in range(K))
        to_source.append(source.hidden_states.index(name))
    return text, source, torch.tensor(to_source)


def test_hidden_variables_join_in_appls_order(factored) -> None:
    text, source, to_source = factored
    # APPL: the last declared variable varies fastest; rock0 = good is the upper half
    assert to_source.tolist() == _file_order(source).tolist()
    m = read_pomdpx(text)
    assert isinstance(m, MOMDP) and (m.num_observed, m.num_hidden) == (17, 16)
    p = to_source
    torch.testing.assert_close(m.Tx, source.Tx[:, :, p, :], rtol=0, atol=1e-12)
    torch.testing.assert_close(m.Ty, source.Ty[:, :, p][..., p], rtol=0, atol=1e-12)
    torch.testing.assert_close(m.Z, source.Z[:, :, p, :], rtol=0, atol=1e-12)
    torch.testing.assert_close(m.R, source.R[:, :, p], rtol=0, atol=1e-12)
    torch.testing.assert_close(m.b0, source.b0[p], rtol=0, atol=1e-12)
    assert m.x0 == source.x0


def _improvability_gap(m: MOMDP, policy: AlphaVectorPolicy, episodes: int, horizon: int) -> float:
    """``max (V_low(b) - max_a Q_low(b, a))`` over the beliefs the greedy policy reaches, with
    ``Q_low(b, a) = R(b, a) + gamma sum_{x2, o} P(x2, o | b, a) V_low(tau(b, a, x2, o))``
    computed exactly from the vectors (<= 0 up to round-off for a uniformly improvable set,
    whose greedy policy then earns at least ``V_low(b0)``)."""
    g = torch.Generator().manual_seed(0)
    X, Y = m.num_observed, m.num_hidden
    alphas, actions, observed = policy.alphas, policy.actions, policy.observed
    mine = observed[None, :] == torch.arange(X)[:, None]  # (X, N) vectors of each x
    x = torch.full((episodes,), m.x0)
    b = m.b0.expand(episodes, Y).clone()
    y = sample_categorical(b, g)
    worst = -math.inf
    for _ in range(horizon):
        scores = (b @ alphas.T).masked_fill(~mine[x], -torch.inf)  # (E, N)
        v = scores.max(-1).values
        pred = torch.einsum("ey,aeyx,aeyxz->aexz", b, m.Tx[:, x], m.Ty[:, x])  # (A, E, X2, Y2)
        J = pred.unsqueeze(3) * m.Z.permute(0, 1, 3, 2).unsqueeze(1)  # (A, E, X2, O, Y2)
        child = (J @ alphas.T).masked_fill(~mine.view(1, 1, X, 1, -1), -torch.inf).amax(-1)
        child = torch.where(J.sum(-1) > 0, child, torch.zeros(()))  # impossible: weight 0
        q = torch.einsum("aey,ey->ae", m.R[:, x], b) + m.discount * child.sum((-1, -2))
        worst = max(worst, float((v - q.amax(0)).max()))
        step = momdp_step(m, x, y, b, actions[scores.argmax(-1)], g)
        x, y, b = step.x, step.y, step.belief
    return worst


@pytest.mark.parametrize("form", ["dense", "sparse"])
def test_written_policy_realises_its_lower_bound(factored, form: str, tmp_path: Path) -> None:
    text, source, to_source = factored
    model = read_pomdpx(text)
    if form == "sparse":
        model = SparseMOMDP.from_dense(model)
    sol = sarsop(model, SARSOPConfig(time_limit=1e9, max_iterations=ITERATIONS))
    path = write_policyx(sol.policy, tmp_path / "rs44.policyx", num_observed=17)
    back = read_policyx(path)
    assert back.observed is not None and back.alphas.shape[1] == 16
    # re-index the vectors by the names onto the source model: column to_source[j] = file's j
    alphas = torch.empty_like(back.alphas)
    alphas[:, to_source] = back.alphas
    policy = AlphaVectorPolicy(alphas, back.actions, observed=back.observed)
    assert float(policy.value(source.x0, source.b0)) == pytest.approx(sol.lower, abs=1e-9)
    assert _improvability_gap(source, policy, episodes=64, horizon=40) <= 1e-9
    r = evaluate_policy(source, policy, episodes=2000, seed=1)
    half = (r.mean - r.ci_low) * 3.29 / 1.96  # the 95% interval (with the tail) widened to 99.9%
    assert r.mean >= sol.lower - half, (r.mean, half, sol.lower)


def _pomdpeval() -> str:
    folder = os.environ.get("TORCHHRC_APPL_BIN")
    path = Path(folder) / "pomdpeval" if folder else None
    found = str(path) if path is not None and path.is_file() else shutil.which("pomdpeval")
    if found is None:
        pytest.skip("APPL's pomdpeval is not installed (set TORCHHRC_APPL_BIN to its folder)")
    return found


def test_pomdpeval_simulates_the_written_policy_within_bounds(factored, tmp_path: Path) -> None:
    binary = _pomdpeval()
    text, _, _ = factored
    model_path = tmp_path / "rs44.pomdpx"
    model_path.write_text(text)
    model = read_pomdpx(model_path)
    sol = sarsop(model, SARSOPConfig(time_limit=1e9, max_iterations=ITERATIONS))
    policy = write_policyx(sol.policy, tmp_path / "rs44.policyx", num_observed=17)
    length, runs = 150, 2000  # 0.95^150 * 10 / 0.05 = 0.09 left past the horizon
    proc = subprocess.run(
        [binary, str(model_path), "--policy-file", str(policy), "--simLen", str(length),
         "--simNum", str(runs), "--srand", "1"],
        capture_output=True, text=True, cwd=tmp_path,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    row = re.compile(r"^\s*(\d+)\s+([-0-9.eE+]+)\s+\(([-0-9.eE+]+),\s*([-0-9.eE+]+)\)")
    rows = [m for m in map(row.match, proc.stdout.splitlines()) if m]
    assert rows, proc.stdout[-2000:]
    mean, lo, hi = (float(rows[-1].group(i)) for i in (2, 3, 4))
    half = (hi - lo) / 2 * 3.29 / 1.96
    tail = model.discount**length * float(model.R.abs().max()) / (1 - model.discount)
    assert sol.lower - half - tail <= mean <= sol.upper + half + tail, (mean, half, sol.lower)
