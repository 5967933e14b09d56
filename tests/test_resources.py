"""Shipped files: top-level assets/ and models/ are the single source, and one lookup finds
them in a checkout and in a built wheel installed elsewhere."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

import torchhrc
from torchhrc.resources import shipped_path, shipped_root

ROOT = Path(__file__).resolve().parents[1]


def test_top_level_folders_are_the_single_source():
    assert (ROOT / "assets" / "panda" / "panda.urdf").is_file()
    assert (ROOT / "models" / "place_and_drill_expert.json").is_file()
    package = Path(torchhrc.__file__).parent
    if package.parent == ROOT:  # imported from this checkout: nothing copied into the package
        assert not (package / "assets").exists() and not (package / "models").exists()
        assert shipped_root("assets") == ROOT / "assets"
        assert shipped_path("models", "place_and_drill_expert.json") == (
            ROOT / "models" / "place_and_drill_expert.json"
        )


def test_lookup_errors():
    with pytest.raises(ValueError, match="expected kind in"):
        shipped_root("meshes")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="relative name"):
        shipped_path("assets", "../pyproject.toml")
    with pytest.raises(FileNotFoundError, match=r"no shipped file 'nothing\.urdf'"):
        shipped_path("assets", "nothing.urdf")


_CHECK = """
import json, sys
import torchhrc
from torchhrc.resources import shipped_path
from torchhrc.kinematics import asset_path
from torchhrc.tasks.place_and_drill.hand_coded import DEFAULT_EXPERT_PATH, load_expert_model
expert = load_expert_model()
print(json.dumps({
    "package": torchhrc.__file__,
    "urdf": str(asset_path("panda/panda.urdf")),
    "arm": str(shipped_path("assets", "human_arm/human_arm.urdf")),
    "expert": str(DEFAULT_EXPERT_PATH),
    "types": list(expert.type_names),
}))
"""


def _copy_source(source: Path) -> Path:
    """A copy of what a build reads (the package, the shipped files, the build config), without
    this checkout's build leftovers; returns ``source``."""
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", "*.egg-info", "build")
    for name in ("torchhrc", "assets", "models"):
        shutil.copytree(ROOT / name, source / name, ignore=ignore)
    for name in ("pyproject.toml", "setup.py", "MANIFEST.in", "README.md"):
        shutil.copy2(ROOT / name, source / name)
    return source


@pytest.mark.slow
def test_a_built_wheel_ships_and_finds_the_files(tmp_path: Path):
    source = _copy_source(tmp_path / "src")
    wheels = tmp_path / "wheels"
    pip = [sys.executable, "-m", "pip", "--disable-pip-version-check", "--no-input"]
    subprocess.run([*pip, "wheel", str(source), "--no-deps", "--no-build-isolation",
                    "-w", str(wheels)], check=True, capture_output=True)  # fmt: skip
    (wheel,) = wheels.glob("torchhrc-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    assert {"torchhrc/assets/panda/panda.urdf", "torchhrc/assets/human_arm/human_arm.urdf",
            "torchhrc/models/place_and_drill_expert.json",
            "torchhrc/models/place_and_drill_learned/model.safetensors"} <= names  # fmt: skip
    site = tmp_path / "site"
    subprocess.run([*pip, "install", "--no-deps", "--target", str(site), str(wheel)],
                   check=True, capture_output=True)  # fmt: skip
    env = dict(os.environ, PYTHONPATH=str(site))
    out = subprocess.run([sys.executable, "-c", _CHECK], cwd=tmp_path, env=env, check=True,
                         capture_output=True, text=True)  # fmt: skip
    found = json.loads(out.stdout.strip().splitlines()[-1])
    installed = site / "torchhrc"
    assert Path(found["package"]).parent == installed
    assert Path(found["urdf"]) == installed / "assets" / "panda" / "panda.urdf"
    assert Path(found["arm"]) == installed / "assets" / "human_arm" / "human_arm.urdf"
    assert Path(found["expert"]) == installed / "models" / "place_and_drill_expert.json"
    assert found["types"] == ["safe", "efficient"]


def _load_make_script():
    import importlib.util

    spec = importlib.util.spec_from_file_location(
        "make_learned_models", ROOT / "models" / "make_learned_models.py"
    )
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_shipped_learned_model_loads_and_finishes_the_task():
    import torch

    from torchhrc.tasks import Controller, LearnedModel
    from torchhrc.tasks.place_and_drill import PlaceAndDrillTask

    path = shipped_path("models", "place_and_drill_learned/model.json").parent
    model = LearnedModel.load(path)
    assert sorted(model.type_names) == ["efficient", "safe"]
    assert model.policy is not None and model.lower <= model.upper + 1e-9
    task = PlaceAndDrillTask(3)
    for order in ((0, 1, 2), (2, 0, 1)):  # the human places in this order
        controller = Controller.from_model(model)
        controller.reset()
        x, placed = task.initial_state, 0
        for _ in range(4 * 3):
            a = controller.act(x)
            h = order[placed] if placed < 3 else -1
            x = int(task.step(torch.tensor(x), torch.tensor(h), torch.tensor(a)))
            placed += h >= 0
            if x == task.terminal_state:
                break
        assert x == task.terminal_state  # every screw placed and drilled


#: relative tolerance of the learned tensors (IRL weights and rewards, the chains, behaviour,
#: transitions and type prior). Last-bit differences of a BLAS kernel move them by about
#: 1e-15: the counts are exact, the soft EM and IRL iterate a fixed number of steps or to a
#: tolerance (an extra step moves a result by at most that tolerance, 1e-8 for the EM) and
#: IRL picks one of its iterates. A change of the learning moves them by far more: another
#: clustering seed 0.14 in the weights, another simulated study 0.028 (measured).
LEARNED_RTOL = 1e-6

#: a decision is checked only where the best action's value beats every other action's by
#: more than this (the policy's values are 2-element dot products: round-off ~1e-16)
DECISION_MARGIN = 1e-6


def _shipped_learned():
    from torchhrc.tasks import LearnedModel

    return LearnedModel.load(shipped_path("models", "place_and_drill_learned/model.json").parent)


@pytest.mark.slow
@pytest.mark.numeric
def test_the_shipped_learned_model_is_what_the_script_learns():
    """A fresh run of ``models/make_learned_models.py`` learns the shipped model: the same
    types and clustering, the same tensors within ``LEARNED_RTOL``, and solver bounds that
    bracket the same value (SARSOP stops at its precision on whatever path round-off gives)."""
    import torch

    shipped = _shipped_learned()
    again = _load_make_script().place_and_drill_learned()
    assert shipped.type_names == again.type_names and shipped.info["k"] == again.info["k"]
    assert torch.equal(shipped.assignments, again.assignments)
    tensors = {name: (getattr(shipped.momdp, name), getattr(again.momdp, name))
               for name in ("Tx", "R", "b0", "Z")}  # fmt: skip
    tensors |= {name: (getattr(shipped, name), getattr(again, name))
                for name in ("weights", "chains", "behaviour")}  # fmt: skip
    for name, (a, b) in tensors.items():
        torch.testing.assert_close(b, a, rtol=LEARNED_RTOL, atol=LEARNED_RTOL, msg=name)
    tol = 1e-9
    assert again.lower <= shipped.upper + tol and shipped.lower <= again.upper + tol
    precision = again.info["solver"]["precision"]
    assert again.upper - again.lower <= precision + tol
    assert shipped.upper - shipped.lower <= precision + tol


#: the shipped policy's action at each observed state (rows, ``model.json``'s
#: ``observed_states``) for P(efficient) = 0, 0.05, ..., 1 (columns): w = wait, A/B/C =
#: drill_A/B/C. Every decision has a value margin of at least 7.4e-4 over the next action.
SHIPPED_DECISIONS = {
    "EEE": "wwwwwwwwwwwwwwwwwwwww", "EEP": "wwwwwwwwwwwCCCCCCCCCC",
    "EED": "wwwwwwwwwwwwwwwwwwwww", "EPE": "wwwwwwwwwwwwBBBBBBBBB",
    "EPP": "wwwwwwwwwwwBBBBBBBBBB", "EPD": "wwwwwwwwwwwBBBBBBBBBB",
    "EDE": "wwwwwwwwwwwwwwwwwwwww", "EDP": "wwwwwwwwwwwCCCCCCCCCC",
    "EDD": "wwwwwwwwwwwwwwwwwwwww", "PEE": "wwwwwwwwwwwAAAAAAAAAA",
    "PEP": "wwwwwwwwwwwAAAAAAAAAA", "PED": "wwwwwwwwwwwAAAAAAAAAA",
    "PPE": "wwwwwwwwwwwAAAAAAAAAA", "PPP": "AAAAAAAAAAAAAAAAAAAAA",
    "PPD": "AAAAAAAAAAAAAAAAAAAAA", "PDE": "wwwwwwwwwwwAAAAAAAAAA",
    "PDP": "AAAAAAAAAAAAAAAAAAAAA", "PDD": "AAAAAAAAAAAAAAAAAAAAA",
    "DEE": "wwwwwwwwwwwwwwwwwwwww", "DEP": "wwwwwwwwwwwCCCCCCCCCC",
    "DED": "wwwwwwwwwwwwwwwwwwwww", "DPE": "wwwwwwwwwwwBBBBBBBBBB",
    "DPP": "BBBBBBBBBBBBBBBBBBBBB", "DPD": "BBBBBBBBBBBBBBBBBBBBB",
    "DDE": "wwwwwwwwwwwwwwwwwwwww", "DDP": "CCCCCCCCCCCCCCCCCCCCC",
    "DDD": "wwwwwwwwwwwwwwwwwwwww",
}  # fmt: skip


@pytest.mark.numeric
def test_the_shipped_learned_model_makes_the_same_decisions_everywhere():
    """Loaded on any machine, the shipped policy picks the recorded action at 27 x 21
    beliefs, each away from a tie (value margin above ``DECISION_MARGIN``); the set holds
    states where the action switches with the belief over types."""
    import torch

    model = _shipped_learned()
    meta = json.loads(shipped_path("models", "place_and_drill_learned/model.json").read_text())
    names = meta["observed_states"]
    letter = {"wait": "w", "drill_A": "A", "drill_B": "B", "drill_C": "C"}
    letters = [letter[a] for a in meta["actions"]]
    assert meta["hidden_states"] == ["efficient", "safe"] and set(SHIPPED_DECISIONS) == set(names)
    p = torch.linspace(0, 1, 21, dtype=torch.float64)
    beliefs = torch.stack([p, 1 - p], -1)
    policy = model.policy
    switches = 0
    for x, name in enumerate(names):
        mine = policy.observed == x
        scores = beliefs @ policy.alphas[mine].T  # (21, vectors at x)
        q = torch.full((21, len(letters)), -torch.inf, dtype=torch.float64)
        for a in policy.actions[mine].unique().tolist():
            q[:, a] = scores[:, policy.actions[mine] == a].amax(-1)
        top = q.topk(2, -1).values
        margin = top[:, 0] - top[:, 1]
        acts = policy.action(torch.full((21,), x), beliefs)
        assert torch.equal(acts, q.argmax(-1))
        got = "".join(letters[a] for a in acts.tolist())
        want = SHIPPED_DECISIONS[name]
        for i in range(21):
            if margin[i] > DECISION_MARGIN:
                assert got[i] == want[i], (name, float(p[i]), got, want)
        assert int((margin > DECISION_MARGIN).sum()) == 21, (name, margin)
        switches += len(set(want)) > 1
    assert switches >= 10  # the type belief matters


_SDIST_THEN_WHEEL = """
import sys, tarfile
from pathlib import Path
from setuptools import build_meta
out = Path(sys.argv[1])
sdist = out / build_meta.build_sdist(str(out))
with tarfile.open(sdist) as tar:
    tar.extractall(out / "unpacked", filter="data")
(root,) = (out / "unpacked").iterdir()
import os
os.chdir(root)
print(out / build_meta.build_wheel(str(out)))
"""


@pytest.mark.slow
def test_the_wheel_built_from_the_sdist_ships_the_files(tmp_path: Path):
    """``python -m build`` builds the sdist, then the wheel from the unpacked sdist."""
    source = _copy_source(tmp_path / "src")
    out = tmp_path / "dist"
    out.mkdir()
    done = subprocess.run([sys.executable, "-c", _SDIST_THEN_WHEEL, str(out)], cwd=source,
                          check=True, capture_output=True, text=True)  # fmt: skip
    wheel = Path(done.stdout.strip().splitlines()[-1])
    names = set(zipfile.ZipFile(wheel).namelist())
    assert {"torchhrc/assets/panda/panda.urdf", "torchhrc/models/place_and_drill_expert.json",
            "torchhrc/models/place_and_drill_learned/model.safetensors"} <= names  # fmt: skip
