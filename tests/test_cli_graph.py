"""Tests of ``torchhrc graph`` (APPL's polgraph): Tiger's optimal controller as DOT, the
drawing, the cuts, a MOMDP's labels, and exit 2 with nothing written on bad input."""

from __future__ import annotations

import json
import re
import sys

import pytest

from torchhrc.cli import main
from torchhrc.io.cassandra import write_pomdp
from torchhrc.io.policyx import save_policy
from torchhrc.io.pomdpx import write_pomdpx
from torchhrc.solvers import SARSOPConfig, solve
from torchhrc.solvers.qmdp import qmdp_policy
from torchhrc.tasks.classic import rock_sample, tiger


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    folder = tmp_path_factory.mktemp("graph")
    sol = solve(tiger(), SARSOPConfig(time_limit=600.0, precision=1e-5, seed=0))
    return {
        "model": write_pomdp(tiger(), folder / "tiger.pomdp"),
        "policy": save_policy(sol.policy, folder / "tiger.policyx"),
    }


def _run(capsys, *argv):
    try:
        code = main(list(map(str, argv)))
    except SystemExit as exit_:
        code = exit_.code
    out, err = capsys.readouterr()
    return code, out, err


def _dot(path):
    text = path.read_text()
    nodes = dict(re.findall(r'^\s*n(\d+) \[label="([^"]*)"', text, re.M))
    edges = re.findall(r'^\s*n(\d+) -> n(\d+) \[label="([^"]*)"', text, re.M)
    return text, nodes, edges


def test_tiger_graph_is_klc98s_controller(capsys, files, tmp_path):
    out_dot, image = tmp_path / "g.dot", tmp_path / "g.png"
    code, out, err = _run(
        capsys, "graph", files["model"], "--policy", files["policy"], "--out", out_dot,
        "--image", image, "--json",
    )  # fmt: skip
    assert code == 0, err
    summary = json.loads(out)
    assert summary == {"nodes": 5, "edges": 10, "closed": True, "dot": str(out_dot),
                       "image": str(image)}  # fmt: skip
    text, nodes, edges = _dot(out_dot)
    assert text.startswith("digraph policy {")
    actions = {i: label.split("\\l")[0] for i, label in nodes.items()}
    assert sorted(actions.values()) == ["A: listen"] * 3 + ["A: open-left", "A: open-right"]
    assert actions["0"] == "A: listen" and "tiger-left 0.5, tiger-right 0.5" in nodes["0"]
    # each open node returns to the root on both observations; each listen node has 2 edges
    for i, action in actions.items():
        out_edges = [e for e in edges if e[0] == i]
        assert len(out_edges) == 2
        if action.startswith("A: open"):
            assert {e[1] for e in out_edges} == {"0"}
    # opening follows two net observations: the open-right node holds tiger-left 0.97
    right = next(i for i, a in actions.items() if a == "A: open-right")
    assert "b: tiger-left 0.97" in nodes[right]
    assert image.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_depth_min_prob_and_svg(capsys, files, tmp_path):
    out_dot, image = tmp_path / "g.dot", tmp_path / "g.svg"
    code, out, err = _run(
        capsys, "graph", files["model"], "--policy", files["policy"], "--out", out_dot,
        "--image", image, "--depth", "1",
    )  # fmt: skip
    assert code == 0, err
    text, nodes, edges = _dot(out_dot)
    assert len(nodes) == 3 and len(edges) == 2 and text.count("style=dashed") == 2
    assert "closed     false (cut by --depth, --min-prob, --max-branch or --max-nodes)" in out
    assert b"<svg" in image.read_bytes()[:2000]
    code, _, err = _run(
        capsys, "graph", files["model"], "--policy", files["policy"], "--out", out_dot,
        "--min-prob", "0.3", "--force",
    )  # fmt: skip
    assert code == 0, err
    _, _, edges = _dot(out_dot)
    probs = [float(re.search(r"p=([0-9.]+)", e[2]).group(1)) for e in edges]
    assert len(edges) == 8 and min(probs) >= 0.3


def test_a_polgraph_command_line_runs(capsys, files, tmp_path):
    """polgraph's own options, with ``polgraph`` replaced by ``torchhrc graph``."""
    out_dot = tmp_path / "g.dot"
    code, out, err = _run(
        capsys, "graph", files["model"], "--fast", "--policy-file", files["policy"],
        "--policy-graph", out_dot, "--graph-max-depth", "3", "--graph-min-prob", "0.01",
        "--graph-max-branch", "1",
    )  # fmt: skip
    assert code == 0, err
    _, nodes, edges = _dot(out_dot)
    sources = [e[0] for e in edges]
    assert len(sources) == len(set(sources)) == 3  # one edge out of each node, 3 deep
    assert len(nodes) <= 4
    assert "closed     false" in out


def test_momdp_nodes_show_the_observed_state_and_type_belief(capsys, tmp_path):
    model = rock_sample(4, 2, form="momdp")
    path = write_pomdpx(model, tmp_path / "rs42.pomdpx")
    policy = save_policy(qmdp_policy(model), tmp_path / "rs42.safetensors")
    code, _, err = _run(
        capsys, "graph", path, "--policy", policy, "--out", tmp_path / "g.dot", "--depth", "2"
    )
    assert code == 0, err
    _, nodes, edges = _dot(tmp_path / "g.dot")
    for label in nodes.values():
        lines = label.split("\\l")
        assert lines[0].startswith("A: ") and lines[1].startswith("X: ")
        assert lines[2].startswith("Y: ")
    assert all(e[2].startswith("X: ") for e in edges)


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--min-prob", "1.5"], "probability in [0, 1]"),
        (["--depth", "-1"], "non-negative integer"),
        (["--image", "{tmp}/g.jpg"], "expected a .png or .svg path"),
        (["--policy", "{tmp}/none.policyx"], "No such file"),
        (["--policy", "{other}"], "o.policyx does not fit the model"),
    ],
)
def test_bad_input_exits_2_without_writing(capsys, files, tmp_path, extra, message):
    other = save_policy(
        qmdp_policy(rock_sample(4, 2, form="momdp").to_pomdp()), tmp_path / "o.policyx"
    )
    argv = ["graph", files["model"], "--policy", files["policy"], "--out", tmp_path / "g.dot"]
    argv += [a.format(tmp=tmp_path, other=other) for a in extra]
    code, _, err = _run(capsys, *argv)
    assert code == 2 and len(err.strip().splitlines()) == 1 and message in err, err
    assert not (tmp_path / "g.dot").exists() and not list(tmp_path.glob("g.*"))


def test_image_without_matplotlib_exits_2_without_writing(capsys, files, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # (import matplotlib fails)
    argv = ["graph", files["model"], "--policy", files["policy"], "--out", tmp_path / "g.dot"]
    code, out, err = _run(capsys, *argv, "--image", tmp_path / "g.png")
    assert code == 2 and out == "" and list(tmp_path.iterdir()) == []
    assert err == (
        "torchhrc graph: error: drawing a policy graph needs matplotlib: "
        "pip install 'torchhrc[full]'\n"
    )


def test_existing_output_is_kept(capsys, files, tmp_path):
    dot = tmp_path / "g.dot"
    dot.write_text("keep")
    code, _, err = _run(capsys, "graph", files["model"], "--policy", files["policy"], "--out", dot)
    assert code == 2 and "file exists" in err and dot.read_text() == "keep"
    code, _, err = _run(capsys, "graph", files["model"], "--policy", files["policy"], "--out",
                        tmp_path / "g.txt")  # fmt: skip
    assert code == 2 and "expected a .dot path" in err


def test_same_graph_as_appl_polgraph(files, tmp_path):
    """APPL's polgraph on the same files draws the same nodes (action, most likely state and
    its probability) and the same node-to-node edges (polgraph keeps one edge per pair)."""
    import os
    import shutil
    import subprocess
    from pathlib import Path

    from torchhrc.io.policyx import load_policy
    from torchhrc.solvers.policy_graph import policy_graph

    folder = os.environ.get("TORCHHRC_APPL_BIN")
    path = Path(folder) / "polgraph" if folder else None
    binary = str(path) if path is not None and path.is_file() else shutil.which("polgraph")
    if binary is None:
        pytest.skip("APPL's polgraph is not installed (set TORCHHRC_APPL_BIN to its folder)")
    subprocess.run(
        [binary, str(files["model"]), "--policy-file", str(files["policy"]), "--policy-graph",
         str(tmp_path / "appl.dot")],
        capture_output=True, check=True, cwd=tmp_path,
    )  # fmt: skip
    text = (tmp_path / "appl.dot").read_text()
    node = re.compile(r'^(\w+) \[label="Y \((\d+)\) ([0-9.]+)\\lA \((\d+)\)\\l"', re.M)
    appl_nodes = {m[0]: (int(m[3]), int(m[1]), round(float(m[2]), 2)) for m in node.findall(text)}
    edge = re.compile(r'^(\w+) -> (\w+) \[label="o \((\d+)\) ([0-9.]+)', re.M)
    appl_edges = {(appl_nodes[a], appl_nodes[b]) for a, b, _, _ in edge.findall(text)}
    g = policy_graph(tiger(), load_policy(files["policy"]))
    ours = [(n.action, int(n.belief.argmax()), round(float(n.belief.max()), 2)) for n in g.nodes]
    assert sorted(ours) == sorted(appl_nodes.values())
    assert {(ours[e.source], ours[e.target]) for e in g.edges} == appl_edges
