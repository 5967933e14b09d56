"""Tests for torchhrc.data.formats: the CSV and JSON round trips and their errors."""

from __future__ import annotations

import json
import os

import pytest
from _demos_fixtures import H, R, _demos

from torchhrc.data import Demonstrations
from torchhrc.errors import ParseError

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
