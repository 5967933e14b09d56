"""The policy graph of an alpha-vector policy, as APPL's ``polgraph`` draws it.

Starting from the initial belief, the policy's action is taken at every belief, and each
possible next observed value ``x2`` and observation ``o`` leads to the updated belief (paper
Eq. 3, Ong et al. 2010)::

    node  = (x, b)  with its action a = pi(x, b) and winning alpha vector
    edge  = (x, b) --(x2, o), P(x2, o | x, b, a)--> (x2, tau(b, a, x2, o))

Beliefs equal within ``merge_tol`` are one node (``polgraph`` merges identical beliefs too),
so the graph of a policy whose reachable beliefs are finitely many closes into a
finite-state controller (Kaelbling, Littman and Cassandra 1998: Tiger at discount 0.95
listens until the belief is two net observations to one side, then opens the other door).
``depth`` bounds the number of edges from the root, ``min_prob`` drops the edges of smaller
probability (``polgraph --graph-max-depth`` and ``--graph-min-prob``).

:meth:`PolicyGraph.to_dot` writes Graphviz DOT; :func:`draw_policy_graph` renders PNG or SVG
with matplotlib (no Graphviz needed); :func:`controller_value` is the exact value of a closed
graph of a flat POMDP, by one linear solve over (node, state) pairs.

Example:
    >>> from torchhrc.tasks.classic import tiger
    >>> from torchhrc.solvers.qmdp import qmdp_policy
    >>> g = policy_graph(tiger(), qmdp_policy(tiger()), depth=1)
    >>> [tiger().actions[n.action] for n in g.nodes][:1], len(g.edges)
    (['listen'], 2)
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from torchhrc._atomic import atomic_write_bytes
from torchhrc.errors import ModelError
from torchhrc.solvers.evaluate import PolicyLike, _form_and_chooser
from torchhrc.solvers.forms import as_solver_model

__all__ = [
    "PolicyGraph",
    "PolicyGraphEdge",
    "PolicyGraphNode",
    "controller_value",
    "draw_policy_graph",
    "policy_graph",
]


@dataclass(frozen=True)
class PolicyGraphNode:
    """One belief of the graph.

    Attributes:
        x: the observed value (0 for a flat model).
        belief: ``(Y,)`` the belief over the hidden value (the state of a flat model).
        action: the policy's action there.
        vector: index of the winning alpha vector (-1 for a callable policy).
        depth: the number of edges from the root on the shortest path.
        expanded: False for a leaf cut by ``depth`` or ``max_nodes``.
    """

    x: int
    belief: torch.Tensor
    action: int
    vector: int
    depth: int
    expanded: bool


@dataclass(frozen=True)
class PolicyGraphEdge:
    """An observation edge: ``source --(x, observation), probability--> target``."""

    source: int
    target: int
    x: int
    observation: int
    probability: float


@dataclass(frozen=True)
class PolicyGraph:
    """Nodes (beliefs with their action) and observation edges; node 0 is the root.

    Attributes:
        nodes, edges: the graph.
        closed: every node expanded and no edge dropped by ``min_prob`` or ``max_branch``: the
            graph is a finite-state controller that runs forever (see :func:`controller_value`).
        factored: a MOMDP graph (nodes show their observed value and the type belief).
        actions, observations, observed_states, hidden_states: names, or None.
    """

    nodes: tuple[PolicyGraphNode, ...]
    edges: tuple[PolicyGraphEdge, ...]
    closed: bool
    factored: bool
    actions: tuple[str, ...] | None = None
    observations: tuple[str, ...] | None = None
    observed_states: tuple[str, ...] | None = None
    hidden_states: tuple[str, ...] | None = None

    def _name(self, names: tuple[str, ...] | None, i: int) -> str:
        return names[i] if names is not None and i < len(names) else str(i)

    def action_name(self, node: int) -> str:
        """The name of node ``node``'s action."""
        return self._name(self.actions, self.nodes[node].action)

    def belief_text(self, node: int, *, top: int = 4) -> str:
        """The belief's largest entries, ``"name p, ..."`` (at most ``top``; the rest as
        ``+k more``)."""
        b = self.nodes[node].belief
        k = min(top, int((b > 0).sum()))
        p, i = b.topk(k) if k else (b[:0], torch.zeros(0, dtype=torch.long))
        words = [f"{self._name(self.hidden_states, int(j))} {float(q):.3g}" for q, j in zip(p, i)]
        rest = int((b > 0).sum()) - k
        return ", ".join(words) + (f", +{rest} more" if rest > 0 else "")

    def node_label(self, node: int) -> str:
        """The text of a node: its action, the observed state (MOMDP) and the belief."""
        n = self.nodes[node]
        lines = [f"A: {self.action_name(node)}"]
        if self.factored:
            lines.append(f"X: {self._name(self.observed_states, n.x)}")
            lines.append(f"Y: {self.belief_text(node)}")
        else:
            lines.append(f"b: {self.belief_text(node)}")
        return "\n".join(lines)

    def edge_label(self, edge: int) -> str:
        """The text of an edge: the observation, the next observed state (MOMDP) and P."""
        e = self.edges[edge]
        head = f"o: {self._name(self.observations, e.observation)}"
        if self.factored:
            head = f"X: {self._name(self.observed_states, e.x)}\n" + head
        return f"{head}\np={e.probability:.3g}"

    def to_dot(self) -> str:
        """The graph in Graphviz DOT (as ``polgraph --policy-graph`` writes it).

        Example:
            >>> from torchhrc.tasks.classic import tiger
            >>> from torchhrc.solvers.qmdp import qmdp_policy
            >>> policy_graph(tiger(), qmdp_policy(tiger()), depth=0).to_dot().splitlines()[0]
            'digraph policy {'
        """

        def quote(text: str) -> str:
            return (
                '"' + text.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\l") + '\\l"'
            )

        out = ["digraph policy {", "  node [shape=box, fontname=Helvetica];"]
        for i, n in enumerate(self.nodes):
            style = "" if n.expanded else ", style=dashed"
            out.append(f"  n{i} [label={quote(self.node_label(i))}{style}];")
        for j, e in enumerate(self.edges):
            out.append(f"  n{e.source} -> n{e.target} [label={quote(self.edge_label(j))}];")
        out.append("}")
        return "\n".join(out) + "\n"

    def write_dot(self, path: str | os.PathLike[str]) -> Path:
        """Write :meth:`to_dot` to ``path`` atomically."""
        return atomic_write_bytes(path, self.to_dot().encode())


def _key(x: int, belief: torch.Tensor, tol: float) -> tuple[Any, ...]:
    nz = (belief > tol).nonzero().squeeze(-1)
    rounded = torch.round(belief[nz] / tol).long()
    return (x, tuple(nz.tolist()), tuple(rounded.tolist()))


def policy_graph(
    model: Any,
    policy: PolicyLike,
    *,
    depth: int | None = None,
    min_prob: float = 0.0,
    max_branch: int | None = None,
    merge_tol: float = 1e-9,
    max_nodes: int = 1000,
) -> PolicyGraph:
    """The graph of beliefs the policy reaches from the initial belief (``polgraph``).

    Args:
        model: an unbatched POMDP, MOMDP, SparsePOMDP or SparseMOMDP.
        policy: an :class:`~torchhrc.solvers.policy.AlphaVectorPolicy` (flat or MOMDP), or
            a callable as :func:`~torchhrc.solvers.evaluate.evaluate_policy` takes.
        depth: the most edges from the root (None: until the graph closes or ``max_nodes``).
        min_prob: the least probability ``P(x2, o | x, b, a)`` of an edge that is drawn.
        max_branch: the most edges out of a node (``polgraph --graph-max-branch``): the most
            probable are kept, the first ``(x2, o)`` among equal probabilities (None: all).
        merge_tol: beliefs equal to within this (entrywise, after rounding) are one node.
        max_nodes: the most nodes; beyond, nodes are left unexpanded.

    Returns:
        :class:`PolicyGraph`, root first.

    Raises:
        ValueError: a negative ``depth``, ``min_prob`` outside ``[0, 1]``, ``max_branch < 1``,
            ``max_nodes < 1``.
        ModelError: the policy does not fit the model.

    Example:
        >>> from torchhrc.tasks.classic import tiger
        >>> from torchhrc.solvers.qmdp import qmdp_policy
        >>> policy_graph(tiger(), qmdp_policy(tiger()), depth=2).nodes[1].belief.tolist()
        [0.85, 0.15]
    """
    if depth is not None and depth < 0:
        raise ValueError(f"expected depth >= 0 or None, got {depth}")
    if not 0.0 <= min_prob <= 1.0:
        raise ValueError(f"expected min_prob in [0, 1], got {min_prob}")
    if max_nodes < 1:
        raise ValueError(f"expected max_nodes >= 1, got {max_nodes}")
    if max_branch is not None and max_branch < 1:
        raise ValueError(f"expected max_branch >= 1 or None, got {max_branch}")
    if not merge_tol > 0:
        raise ValueError(f"expected merge_tol > 0, got {merge_tol}")
    form, choose = _form_and_chooser(model, policy)
    vector_of = None
    if hasattr(policy, "best_vector"):
        vector_of = policy.best_vector  # type: ignore[union-attr]
    xs, beliefs, _ = form.roots
    if len(xs) > 1:
        raise ModelError(
            "policy_graph needs one initial observed value (the model starts at random)"
        )
    nodes: list[dict[str, Any]] = []
    index: dict[tuple[Any, ...], int] = {}
    edges: list[PolicyGraphEdge] = []
    closed = True

    def add(x: int, b: torch.Tensor, d: int) -> int:
        key = _key(x, b, merge_tol)
        if key in index:
            return index[key]
        xt = torch.tensor([x])
        a = int(choose(xt, b.unsqueeze(0))[0])
        v = -1
        if vector_of is not None:
            v = int(
                vector_of(xt, b.unsqueeze(0))[0] if form.factored else vector_of(b.unsqueeze(0))[0]
            )
        index[key] = len(nodes)
        nodes.append({"x": x, "belief": b, "action": a, "vector": v, "depth": d, "expanded": False})
        return len(nodes) - 1

    add(int(xs[0]), beliefs[0], 0)
    frontier = 0
    while frontier < len(nodes):
        node = nodes[frontier]
        if (depth is not None and node["depth"] >= depth) or len(nodes) >= max_nodes:
            closed = False
            frontier += 1
            continue
        node["expanded"] = True
        kx, J = form.expand(node["x"], node["belief"].unsqueeze(0).to(form.b0.dtype))
        Ja = J[0, node["action"]]  # (K, O, Y)
        prob = Ja.sum(-1)  # (K, O)
        outcomes = [(k, o, float(prob[k, o])) for k, o in (prob > 0).nonzero().tolist()]
        drawn = [(k, o, p) for k, o, p in outcomes if p >= min_prob]
        if max_branch is not None and len(drawn) > max_branch:  # the most probable, stably
            kept = sorted(range(len(drawn)), key=lambda i: -drawn[i][2])[:max_branch]
            drawn = [drawn[i] for i in sorted(kept)]
        closed = closed and len(drawn) == len(outcomes)
        for k, o, p in drawn:
            target = add(int(kx[k]), Ja[k, o] / prob[k, o], node["depth"] + 1)
            edges.append(PolicyGraphEdge(frontier, target, int(kx[k]), o, p))
        frontier += 1
    source = getattr(form, "source", model)

    def names(field: str) -> tuple[str, ...] | None:
        value = getattr(source, field, None)
        return tuple(value) if value is not None else None

    factored = bool(form.factored)
    return PolicyGraph(
        nodes=tuple(PolicyGraphNode(**n) for n in nodes),
        edges=tuple(edges),
        closed=closed,
        factored=factored,
        actions=names("actions"),
        observations=names("observations"),
        observed_states=names("observed_states") if factored else None,
        hidden_states=names("hidden_states") if factored else names("states"),
    )


def controller_value(model: Any, graph: PolicyGraph) -> float:
    """The exact discounted value at the root of a closed graph of a flat POMDP.

    The graph run as a finite-state controller (Hansen 1998): node ``n`` takes its action
    ``a_n`` and moves along the edge of the observation received::

        V[n, s] = R[a_n, s] + discount sum_{s2, o} T[a_n, s, s2] Z[a_n, s2, o] V[m(n, o), s2]

    one linear system over ``(node, state)`` pairs; the value is ``b0 . V[root]``. A
    transition to an observation without an edge (impossible at the node's belief) counts
    0; it never happens from the states the belief holds.

    Args:
        model: the flat model the graph was made of (a :class:`~torchhrc.pomdp.POMDP`, or
            any flat model :func:`~torchhrc.solvers.forms.as_solver_model` takes).
        graph: a :class:`PolicyGraph` with ``closed`` True.

    Returns:
        The value at the root belief.

    Raises:
        ModelError: the graph is not closed, or not of a flat model.

    Example:
        >>> from torchhrc.tasks.classic import tiger
        >>> from torchhrc.solvers.blind import blind_policy
        >>> round(controller_value(tiger(), policy_graph(tiger(), blind_policy(tiger()))), 6)
        -20.0
    """
    form = as_solver_model(model)
    if form.factored or graph.factored:
        raise ModelError("controller_value needs a flat POMDP and its graph")
    if not graph.closed:
        raise ModelError("controller_value needs a closed graph (no depth or min_prob cut)")
    N, S, O = len(graph.nodes), form.num_hidden, form.num_observations
    succ = torch.full((N, O), -1, dtype=torch.long)
    for e in graph.edges:
        succ[e.source, e.observation] = e.target
    acts = torch.tensor([n.action for n in graph.nodes])
    # T[a, s] is the prediction of the corner belief s (exact: products with 1 and 0), and
    # the observation slice of the one next observed value is Z[a, s2, o] transposed
    corners = torch.eye(S, dtype=form.b0.dtype, device=form.b0.device)
    T = form.predict(0, corners)[:, :, 0, :].transpose(0, 1).double().cpu()  # (A, S, S2)
    Z = form.observation(0)[:, 0].transpose(1, 2).double().cpu()  # (A, S2, O)
    R = form.R[:, 0, :].double().cpu()  # (A, S)
    M = torch.zeros(N, S, N, S, dtype=torch.float64)
    for n in range(N):
        a = int(acts[n])
        for o in range(O):
            m = int(succ[n, o])
            if m >= 0:
                M[n, :, m, :] += T[a] * Z[a, :, o].unsqueeze(0)  # (S, S2)
    system = torch.eye(N * S, dtype=torch.float64) - form.discount * M.reshape(N * S, N * S)
    V = torch.linalg.solve(system, R[acts].reshape(N * S)).reshape(N, S)
    return float(graph.nodes[0].belief.double() @ V[0])


def _layout(graph: PolicyGraph) -> list[tuple[float, float]]:
    """Layered positions: depth down the page, nodes of a depth side by side."""
    layers: dict[int, list[int]] = {}
    for i, n in enumerate(graph.nodes):
        layers.setdefault(n.depth, []).append(i)
    pos = [(0.0, 0.0)] * len(graph.nodes)
    for d, members in layers.items():
        for j, i in enumerate(members):
            pos[i] = (j - (len(members) - 1) / 2.0, -float(d))
    return pos


def draw_policy_graph(graph: PolicyGraph, path: str | os.PathLike[str]) -> Path:
    """Render the graph to a PNG or SVG file (by its suffix) with matplotlib.

    Nodes are laid out by depth (the root on top); an edge back up the graph is drawn as an
    arc. Needs matplotlib (``pip install torchhrc[full]``); no Graphviz.

    Raises:
        ValueError: the suffix is neither ``.png`` nor ``.svg``.
        ImportError: matplotlib is missing (the message names the extra).
    """
    suffix = Path(path).suffix.lower()
    if suffix not in (".png", ".svg"):
        raise ValueError(f"expected path to end in .png or .svg, got {os.fspath(path)!r}")
    try:
        import matplotlib

        matplotlib.use("Agg", force=False)
        import matplotlib.pyplot as plt
        from matplotlib.patches import FancyArrowPatch
    except ImportError as error:  # pragma: no cover - extras installed in tests
        raise ImportError(
            "drawing a policy graph needs matplotlib: pip install 'torchhrc[full]'"
        ) from error
    import io

    pos = _layout(graph)
    width = max(
        1,
        max(
            (sum(1 for n in graph.nodes if n.depth == d) for d in {n.depth for n in graph.nodes}),
            default=1,
        ),
    )
    height = max(n.depth for n in graph.nodes) + 1
    sx, sy = 4.5, 2.2
    fig, ax = plt.subplots(figsize=(max(4.0, sx * width), max(3.0, sy * height)))
    xy = [(px * sx, py * sy) for px, py in pos]
    pairs: dict[tuple[int, int], list[str]] = {}  # parallel edges share one arrow
    for j, e in enumerate(graph.edges):
        pairs.setdefault((e.source, e.target), []).append(graph.edge_label(j).replace("\n", ", "))
    for (source, target), labels in pairs.items():
        (x1, y1), (x2, y2) = xy[source], xy[target]

        back = graph.nodes[target].depth <= graph.nodes[source].depth
        rad = 0.35 if back else 0.0
        if source == target:
            x2, y2, rad = x1 + 0.01, y1 + 0.01, 2.5
        ax.add_patch(
            FancyArrowPatch(
                (x1, y1),
                (x2, y2),
                connectionstyle=f"arc3,rad={rad}",
                arrowstyle="-|>",
                mutation_scale=12,
                color="0.4",
                shrinkA=22,
                shrinkB=22,
                lw=0.8,
            )
        )
        mx, my = (x1 + x2) / 2, (y1 + y2) / 2
        if rad:
            mx, my = mx + rad * (y2 - y1) / 2, my - rad * (x2 - x1) / 2
        ax.text(
            mx,
            my,
            "\n".join(labels),
            fontsize=6,
            ha="center",
            va="center",
            color="0.2",
            bbox={"fc": "white", "ec": "none", "pad": 0.5},
        )
    for i, (px, py) in enumerate(xy):
        style = "-" if graph.nodes[i].expanded else "--"
        ax.text(
            px,
            py,
            graph.node_label(i),
            fontsize=7,
            ha="center",
            va="center",
            bbox={"boxstyle": "round", "fc": "#e8f0fe", "ec": "0.3", "ls": style},
        )
    xs = [p[0] for p in xy]
    ys = [p[1] for p in xy]
    ax.set_xlim(min(xs) - sx, max(xs) + sx)
    ax.set_ylim(min(ys) - sy / 1.5, max(ys) + sy / 1.5)
    ax.axis("off")
    buffer = io.BytesIO()
    fig.savefig(buffer, format=suffix[1:], bbox_inches="tight")
    plt.close(fig)
    return atomic_write_bytes(path, buffer.getvalue())
