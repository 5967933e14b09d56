"""Tests for torchhrc.data.demonstrations: construction, validation, selection, counts,
relabelling."""

from __future__ import annotations

import itertools

import pytest
import torch
from _demos_fixtures import EFFICIENT, SAFE, H, R, _demos

from torchhrc.data import Demonstrations
from torchhrc.errors import ModelError

# ---------------------------------------------------------------- construction


def test_from_lists_vocabulary_padding_and_mask():
    d = _demos()
    assert d.vocabulary == (
        (H, "place_A"),
        (H, "place_B"),
        (H, "wait"),
        (R, "drill_A"),
        (R, "drill_B"),
    )
    assert d.symbol_names[2] == "human:wait"
    assert d.num_symbols == 5 and d.num_sequences == 4 and d.max_length == 5
    assert d.lengths.tolist() == [4, 5, 2, 4]
    assert d.sequences.dtype == torch.int64
    assert d.sequences[0].tolist() == [0, 1, 3, 4, 0]  # padded with 0
    assert d.mask[2].tolist() == [True, True, False, False, False]
    assert d.sequence_ids == ("0", "1", "0", "1")
    assert d.keys == ("s1/0", "s1/1", "s2/0", "s2/1")
    assert d.unique_subjects == ("s1", "s2")
    assert d.subject_index.tolist() == [0, 0, 1, 1]
    assert d.to_lists() == [SAFE, EFFICIENT, SAFE[:2], EFFICIENT[1:]]


def test_human_and_robot_wait_are_different_symbols():
    d = Demonstrations.from_lists([[(H, "wait"), (R, "wait"), (H, "wait")]])
    assert d.num_symbols == 2
    assert d.sequences.tolist() == [[0, 1, 0]]


def test_fixed_vocabulary_is_kept_and_enforced():
    vocab = [(R, "drill_A"), (H, "place_A"), (H, "unused")]
    d = Demonstrations.from_lists([[(H, "place_A"), (R, "drill_A")]], vocabulary=vocab)
    assert d.vocabulary == tuple(vocab) and d.sequences.tolist() == [[1, 0]]
    with pytest.raises(ModelError, match="not in the vocabulary"):
        Demonstrations.from_lists([[(H, "place_B"), (R, "drill_A")]], vocabulary=vocab)


@pytest.mark.parametrize(
    ("kwargs", "error", "match"),
    [
        ({"sequences": torch.zeros(2, 3)}, TypeError, "int64"),
        ({"sequences": torch.zeros(3, dtype=torch.long)}, ModelError, r"\(N, L\)"),
        ({"lengths": torch.tensor([3])}, ModelError, "lengths"),
        ({"lengths": torch.tensor([3, 1])}, ModelError, r"lengths\[1\] = 1"),
        ({"lengths": torch.tensor([3, 4])}, ModelError, r"lengths\[1\] = 4"),
        ({"sequences": torch.tensor([[0, 1, 2], [1, 0, 0]])}, ModelError, r"sequences\[0, 2\]"),
        ({"sequences": torch.tensor([[0, 1, 0], [1, 0, 1]])}, ModelError, "padding"),
        ({"subjects": ("a",)}, ModelError, "subjects"),
        ({"sequence_ids": ("0", "0"), "subjects": ("a", "a")}, ModelError, "a/0 appears twice"),
        ({"types": ("t",)}, ModelError, "types"),
        ({"vocabulary": ((H, "a"), ("robto", "b"))}, ModelError, "actor 'robto'"),
        ({"vocabulary": ((H, "a"), (H, "a"))}, ModelError, "distinct"),
    ],
)
def test_invalid_fields_are_reported(kwargs, error, match):
    fields = {
        "vocabulary": ((H, "a"), (R, "b")),
        "sequences": torch.tensor([[0, 1, 0], [1, 0, 0]]),
        "lengths": torch.tensor([3, 2]),
        "subjects": ("a", "b"),
        "sequence_ids": ("0", "0"),
        "types": None,
    }
    fields.update(kwargs)
    with pytest.raises(error, match=match):
        Demonstrations(**fields)


def test_from_lists_rejects_short_sequences_and_unknown_actors():
    with pytest.raises(ModelError, match=r"sequences\[1\] has 1 step"):
        Demonstrations.from_lists([SAFE, SAFE[:1]])
    with pytest.raises(ModelError, match="actor 'robbot'"):
        Demonstrations.from_lists([[(H, "a"), ("robbot", "b")]])
    with pytest.raises(TypeError, match=r"sequences\[0\]\[1\]"):
        Demonstrations.from_lists([[(H, "a"), "robot:b"]])


# ---------------------------------------------------------------- selection and counts


def test_subset_and_select_subjects():
    d = _demos()
    s = d.subset([2, 0])
    assert s.keys == ("s2/0", "s1/0") and s.types == ("safe", "safe")
    assert s.max_length == 4  # trimmed to the longest selected sequence
    assert s.to_lists() == [SAFE[:2], SAFE]
    assert d.subset(torch.tensor([False, True, False, True])).keys == ("s1/1", "s2/1")
    assert d.select_subjects(["s2"]) == d.subset([2, 3])
    assert d.select_subjects("s2", exclude=True) == d.subset([0, 1])
    assert d.subset([]).num_sequences == 0
    with pytest.raises(ModelError, match="nobody"):
        d.select_subjects(["nobody"])
    with pytest.raises(IndexError):
        d.subset([4])


def test_transition_counts_match_a_python_count():
    d = _demos()
    per = d.transition_counts(per_sequence=True)
    assert per.shape == (4, 5, 5)
    for n, seq in enumerate(d.to_lists()):
        expected = torch.zeros(5, 5, dtype=torch.float64)
        for a, b in itertools.pairwise(seq):
            expected[d.vocabulary.index(a), d.vocabulary.index(b)] += 1
        assert torch.equal(per[n], expected)
    assert torch.equal(d.transition_counts(), per.sum(0))
    assert d.transition_counts().sum() == (d.lengths - 1).sum()


def test_map_actions_merges_symbols_and_keeps_every_step():
    d = Demonstrations.from_lists(
        [
            [("human", "place_A"), ("robot", "drill_A"), ("human", "place_B")],
            [("human", "place_B"), ("robot", "wait")],
        ]
    )
    merged = d.map_actions(lambda actor, action: action.split("_")[0])
    assert merged.symbol_names == ("human:place", "robot:drill", "robot:wait")
    assert merged.to_lists() == [
        [("human", "place"), ("robot", "drill"), ("human", "place")],
        [("human", "place"), ("robot", "wait")],
    ]
    assert torch.equal(merged.lengths, d.lengths)
    # a dict renames only the names it has; the padding stays 0
    renamed = d.map_actions({"wait": "idle"})
    assert ("robot", "idle") in renamed.vocabulary and renamed.num_symbols == d.num_symbols
    assert int(renamed.sequences[1, 2]) == 0
    with pytest.raises(ModelError, match="expected an action name"):
        d.map_actions(lambda actor, action: "")
    with pytest.raises(TypeError, match="callable or a dict"):
        d.map_actions(3)


def _relabel_reference(steps, separator="_"):
    """Per-step loop: objects renamed 1, 2, ... in order of first appearance."""
    seen: dict[str, int] = {}
    out = []
    for actor, action in steps:
        verb, sep, obj = action.rpartition(separator)
        if sep and verb and obj:
            seen.setdefault(obj, len(seen) + 1)
            out.append((actor, f"{verb}{separator}{seen[obj]}"))
        else:
            out.append((actor, action))
    return out


def test_relabel_objects_matches_a_per_step_loop_on_random_sequences():
    g = torch.Generator().manual_seed(0)
    actions = [(H, f"place_{p}") for p in "ABCD"] + [(R, f"drill_{p}") for p in "ABCD"]
    actions += [(H, "wait"), (R, "wait"), (R, "drill_all")]
    seqs = []
    for _ in range(40):
        length = int(torch.randint(2, 12, (1,), generator=g))
        idx = torch.randint(len(actions), (length,), generator=g).tolist()
        seqs.append([actions[i] for i in idx])
    d = Demonstrations.from_lists(seqs, types=["t"] * len(seqs))
    r = d.relabel_objects()
    assert r.to_lists() == [_relabel_reference(s) for s in seqs]
    assert torch.equal(r.lengths, d.lengths) and r.types == d.types
    assert not r.sequences[~r.mask].any()  # padding stays 0


def test_relabel_objects_is_invariant_to_renaming_the_objects():
    rename = {"A": "C", "B": "A", "C": "B"}
    seqs = [[(H, "place_A"), (R, "drill_A"), (H, "place_C"), (H, "wait"), (R, "drill_C")]]
    renamed = [[(a, n[:-1] + rename[n[-1]]) if "_" in n else (a, n) for a, n in s] for s in seqs]
    one = Demonstrations.from_lists(seqs).relabel_objects()
    two = Demonstrations.from_lists(renamed).relabel_objects()
    assert one.to_lists() == two.to_lists()
    assert one.to_lists()[0] == [
        (H, "place_1"),
        (R, "drill_1"),
        (H, "place_2"),
        (H, "wait"),
        (R, "drill_2"),
    ]
    # another separator; a name that is only a separator part stays as it is
    d = Demonstrations.from_lists([[(H, "pick:x"), (H, "_"), (R, "pick:y")]])
    assert d.relabel_objects(separator=":").to_lists() == [[(H, "pick:1"), (H, "_"), (R, "pick:2")]]
    with pytest.raises(TypeError, match="separator"):
        d.relabel_objects(separator="")


def test_relabel_log_multiplicity_counts_the_injections_by_enumeration():
    """Every injective renaming of a sequence's objects (with its first step kept, or not)
    relabels to the same sequence; the count is ``(M - f)! / (M - m)!``."""
    import math

    g = torch.Generator().manual_seed(1)
    objects = "ABCD"
    actions = [(H, f"place_{p}") for p in objects] + [(R, f"drill_{p}") for p in objects]
    actions += [(H, "wait"), (R, "wait")]
    seqs = []
    for _ in range(30):
        length = int(torch.randint(2, 9, (1,), generator=g))
        seqs.append([actions[i] for i in torch.randint(len(actions), (length,), generator=g)])
    d = Demonstrations.from_lists(seqs, vocabulary=actions)
    given = d.relabel_log_multiplicity().exp()
    free = d.relabel_log_multiplicity(given_first=False).exp()
    for n, seq in enumerate(seqs):
        used = sorted({a.rpartition("_")[2] for _, a in seq if "_" in a})
        image = d.subset([n]).relabel_objects().to_lists()[0]
        same = same_first = 0
        for perm in itertools.permutations(objects, len(used)):
            rename = dict(zip(used, perm))
            other = [(x, f"{a[:-1]}{rename[a[-1]]}") if "_" in a else (x, a) for x, a in seq]
            again = Demonstrations.from_lists([other], vocabulary=actions).relabel_objects()
            assert again.to_lists()[0] == image
            same += 1
            same_first += other[0] == seq[0]
        assert math.isclose(float(free[n]), same, rel_tol=1e-12)
        assert math.isclose(float(given[n]), same_first, rel_tol=1e-12)
    assert d.num_objects() == 4


def test_with_vocabulary_reindexes_and_names_a_missing_symbol():
    d = Demonstrations.from_lists([[(H, "a"), (R, "b"), (H, "a")]])
    other = d.with_vocabulary([(R, "b"), (H, "c"), (H, "a")])
    assert other.to_lists() == d.to_lists() and other.sequences.tolist() == [[2, 0, 2]]
    assert d.with_vocabulary(d.vocabulary) is d
    with pytest.raises(ModelError, match="robot:b"):
        d.with_vocabulary([(H, "a")])


def test_relabel_objects_can_keep_every_symbol_the_vocabulary_allows():
    vocab = [(H, "place_A"), (H, "place_B"), (H, "place_C"), (H, "wait"), (R, "drill_A")]
    d = Demonstrations.from_lists([[(H, "place_C"), (R, "drill_A")]], vocabulary=vocab)
    used = d.relabel_objects()
    full = d.relabel_objects(keep_unused=True)
    assert used.symbol_names == ("human:place_1", "robot:drill_2")
    assert full.symbol_names == (
        "human:place_1", "human:place_2", "human:place_3", "human:wait",
        "robot:drill_1", "robot:drill_2", "robot:drill_3",
    )  # fmt: skip
    assert full.to_lists() == used.to_lists()


def test_indexing_and_iteration_give_the_steps():
    import numpy as np

    seqs = [[("human", "a"), ("robot", "b")], [("robot", "b"), ("human", "a"), ("robot", "c")],
            [("human", "a"), ("human", "a")]]  # fmt: skip
    d = Demonstrations.from_lists(seqs, subjects=["x", "y", "y"])
    assert list(d) == seqs == d.to_lists()
    assert d[1] == seqs[1] and d[-1] == seqs[2] and d[np.int64(0)] == seqs[0]
    assert d[torch.tensor(2)] == seqs[2]
    tail = d[1:]
    assert isinstance(tail, Demonstrations) and tail.subjects == ("y", "y")
    assert tail.to_lists() == seqs[1:] and d[::2].to_lists() == [seqs[0], seqs[2]]
    with pytest.raises(IndexError, match="index 3 out of range for 3 demonstrations"):
        d[3]
    with pytest.raises(IndexError, match="index -4 out of range"):
        d[-4]
    for bad in (1.0, True, "0", [0, 1]):
        with pytest.raises(TypeError, match=r"an integer index or a slice.*use \.subset"):
            d[bad]
