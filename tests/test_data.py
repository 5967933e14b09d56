"""Tests for torchhrc.data: construction, validation, selection, counts, CSV/JSON IO."""

from __future__ import annotations

import itertools
import json
import os

import pytest
import torch

from torchhrc.data import Demonstrations
from torchhrc.errors import ModelError, ParseError

H, R = "human", "robot"
SAFE = [(H, "place_A"), (H, "place_B"), (R, "drill_A"), (R, "drill_B")]
EFFICIENT = [(H, "place_B"), (R, "drill_B"), (H, "place_A"), (R, "drill_A"), (H, "wait")]


def _demos(types: bool = True) -> Demonstrations:
    return Demonstrations.from_lists(
        [SAFE, EFFICIENT, SAFE[:2], EFFICIENT[1:]],
        subjects=["s1", "s1", "s2", "s2"],
        types=["safe", "efficient", "safe", "efficient"] if types else None,
    )


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


# ---------------------------------------------------------------- IO round trips


@pytest.mark.parametrize("types", [True, False])
def test_csv_round_trip(tmp_path, types):
    d = _demos(types)
    path = tmp_path / "demos.csv"
    d.write_csv(path)
    text = path.read_text()
    header = "subject,sequence,step,actor,action" + (",type" if types else "")
    assert text.splitlines()[0] == header
    assert text.splitlines()[1] == "s1,0,0,human,place_A" + (",safe" if types else "")
    assert len(text.splitlines()) == 1 + int(d.lengths.sum())
    assert Demonstrations.read_csv(path) == d
    assert [p.name for p in tmp_path.iterdir()] == ["demos.csv"]  # no temp file left


def test_csv_with_quoted_fields_columns_in_any_order_and_blank_lines(tmp_path):
    path = tmp_path / "d.csv"
    path.write_text(
        "action,actor,step,sequence,subject\n"
        '"place, A",human,0,x,"Ann B"\n'
        "\n"
        "drill_A,robot,1,x,Ann B\n"
    )
    d = Demonstrations.read_csv(path)
    assert d.to_lists() == [[(H, "place, A"), (R, "drill_A")]]
    assert d.keys == ("Ann B/x",)
    d.write_csv(tmp_path / "e.csv")
    assert Demonstrations.read_csv(tmp_path / "e.csv") == d


@pytest.mark.parametrize("types", [True, False])
def test_json_round_trip(tmp_path, types):
    d = _demos(types)
    path = tmp_path / "demos.json"
    d.write_json(path)
    data = json.loads(path.read_text())
    assert data["format"] == "torchhrc.demonstrations"
    assert data["sequences"][0]["steps"][0] == ["human", "place_A"]
    assert Demonstrations.read_json(path) == d


def test_read_csv_with_fixed_vocabulary(tmp_path):
    d = _demos()
    path = tmp_path / "d.csv"
    d.write_csv(path)
    vocab = (*tuple(reversed(d.vocabulary)), (R, "wait"))
    e = Demonstrations.read_csv(path, vocabulary=vocab)
    assert e.vocabulary == vocab and e.to_lists() == d.to_lists()
    with pytest.raises(ParseError, match=r"d.csv:2:5: symbol human:place_A is not in"):
        Demonstrations.read_csv(path, vocabulary=[(R, "drill_A")])


# ---------------------------------------------------------------- malformed CSV

HEADER = "subject,sequence,step,actor,action\n"
OK_ROWS = "s,0,0,human,place_A\ns,0,1,robot,drill_A\n"


@pytest.mark.parametrize(
    ("text", "line", "match"),
    [
        ("", 1, "empty file"),
        ("\n\n", 1, "empty file"),
        (HEADER, 2, "no data rows"),
        ("subject,sequence,step,actor\n" + "s,0,0,human\n", 1, "missing column.*action"),
        ("subject,sequence,step,actor,action,extra\n", 1, "unknown column 'extra'"),
        ("subject,sequence,step,actor,action,step\n", 1, "'step' appears twice"),
        (HEADER + "s,0,0,human,place_A,x\n", 2, "expected 5 fields"),
        (HEADER + "s,0,0,human\n", 2, "expected 5 fields"),
        (HEADER + "s,0,zero,human,place_A\n", 2, "step 'zero' is not a non-negative integer"),
        (HEADER + "s,0,1.5,human,place_A\n", 2, "not a non-negative integer"),
        (HEADER + "s,0,-1,human,place_A\n", 2, "not a non-negative integer"),
        (HEADER + "s,0,0,human,place_A\ns,0,0,robot,drill_A\n", 3, "duplicate step 0"),
        (HEADER + "s,0,0,human,place_A\ns,0,2,robot,drill_A\n", 3, "missing step.* 1 "),
        (HEADER + "s,0,1,human,place_A\ns,0,2,robot,drill_A\n", 2, "starts at step 1"),
        (HEADER + "s,0,0,Human,place_A\n", 2, "unknown actor 'Human'"),
        (HEADER + "s,0,0,human,place_A\n", 2, "has 1 step, expected at least 2"),
        (HEADER + "s,0,0,human,place_A\nt,1,0,human,a\nt,1,1,robot,b\n", 2, "has 1 step"),
        (HEADER + "s,0,0,human,place_A\nt,0,1,robot,drill_A\n", 3, "changes subject"),
        (HEADER + OK_ROWS + "t,0,0,human,a\nt,0,1,human,a\ns,0,2,human,a\n", 6, "not contig"),
        (HEADER + "s,,0,human,place_A\n", 2, "empty 'sequence' field"),
        (HEADER + "s,0,0,human,\n", 2, "empty 'action' field"),
        (HEADER.strip() + ",type\n" + "s,0,0,human,a,safe\ns,0,1,robot,b,efficient\n", 3, "type"),
        (HEADER.strip() + ",type\n" + "s,0,0,human,a,\ns,0,1,robot,b,\n", 2, "empty 'type'"),
    ],
)
def test_malformed_csv_names_file_line_and_reason(tmp_path, text, line, match):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(ParseError, match=match) as info:
        Demonstrations.read_csv(path)
    error = info.value
    assert error.path == os.fspath(path)
    assert error.line == line
    assert str(error).startswith(f"{path}:{line}")
    assert isinstance(error, ValueError)


def test_missing_csv_file_raises_file_not_found(tmp_path):
    with pytest.raises(FileNotFoundError):
        Demonstrations.read_csv(tmp_path / "none.csv")


# ---------------------------------------------------------------- malformed JSON


def _json_text(**changes) -> str:
    data = _demos().to_json_dict()
    data.update(changes)
    return json.dumps(data)


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("", "empty file"),
        ('{"format": ', "invalid JSON"),
        ("[]", "expected a JSON object"),
        (_json_text(format="other"), r"\$.format"),
        (_json_text(version=2), r"\$.version"),
        (_json_text(extra=1), "unknown keys"),
        (_json_text(vocabulary=[["human", "a"], ["bot", "b"]]), r"\$.vocabulary.*actor 'bot'"),
        (_json_text(sequences={}), r"\$.sequences: expected a list"),
        (
            _json_text(sequences=[{"subject": "s", "sequence": "0", "steps": [["human", "x"]]}]),
            r"\$.sequences\[0\].steps\[0\]: symbol",
        ),
        (
            _json_text(
                sequences=[{"subject": "s", "sequence": "0", "steps": [["human", "place_A"]]}]
            ),
            r"\$.sequences\[0\].steps: 1 step",
        ),
        (
            _json_text(sequences=[{"subject": "s", "steps": []}]),
            r"\$.sequences\[0\]: missing key 'sequence'",
        ),
        (
            _json_text(
                sequences=[
                    {"subject": "s", "sequence": "0", "steps": [["human", "place_A"]] * 2},
                    {"subject": "s", "sequence": "0", "steps": [["human", "place_A"]] * 2},
                ]
            ),
            "appears twice",
        ),
    ],
)
def test_malformed_json_is_a_parse_error(tmp_path, text, match):
    path = tmp_path / "bad.json"
    path.write_text(text)
    with pytest.raises(ParseError, match=match) as info:
        Demonstrations.read_json(path)
    assert info.value.path == os.fspath(path)


def test_invalid_json_reports_line_and_column(tmp_path):
    path = tmp_path / "bad.json"
    path.write_text('{\n "format": "torchhrc.demonstrations",\n "version": 1,,\n}')
    with pytest.raises(ParseError) as info:
        Demonstrations.read_json(path)
    assert info.value.line == 3 and info.value.column is not None


def test_undecodable_bytes_and_csv_errors_are_parse_errors(tmp_path):
    path = tmp_path / "latin1.csv"
    path.write_bytes(HEADER.encode() + b"s,0,0,human,caf\xe9\n")
    with pytest.raises(ParseError, match="not UTF-8") as info:
        Demonstrations.read_csv(path)
    assert info.value.line == 2
    path = tmp_path / "huge_field.csv"
    path.write_text(HEADER + 's,0,0,human,"' + "a" * 200_000 + '"\n')
    with pytest.raises(ParseError, match="malformed CSV: field larger than field limit"):
        Demonstrations.read_csv(path)
    path = tmp_path / "latin1.json"
    path.write_bytes(b'{"format": "caf\xe9"}')
    with pytest.raises(ParseError, match="not UTF-8"):
        Demonstrations.read_json(path)


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
