"""Tests of torchhrc.io.policyx: APPL .policyx and safetensors round trips, malformed files."""

from __future__ import annotations

import pytest
import torch

from torchhrc.errors import ParseError
from torchhrc.io.policyx import (
    format_policyx,
    load_policy,
    read_policy_safetensors,
    read_policyx,
    save_policy,
    write_policy_safetensors,
    write_policyx,
)
from torchhrc.solvers.policy import AlphaVectorPolicy

# Written by APPL SARSOP's pomdpsol (5 s) for benchmarks/problems/tiger.pomdp.
APPL_STYLE = """<?xml version="1.0" encoding="ISO-8859-1"?>
<Policy version="0.1" type="value" model="tiger.pomdp" \
xmlns:xsi="http://www.w3.org/2001/XMLSchema-instance" xsi:noNamespaceSchemaLocation="policyx.xsd">
<AlphaVector vectorLength="2" numObsValue="1" numVectors="5">
<Vector action="1" obsValue="0">-81.5975 28.4025 </Vector>
<Vector action="0" obsValue="0">3.01448 24.6954 </Vector>
<Vector action="0" obsValue="0">24.6954 3.01452 </Vector>
<Vector action="2" obsValue="0">28.4025 -81.5975 </Vector>
<Vector action="0" obsValue="0">19.3711 19.3711 </Vector>
</AlphaVector> </Policy>
"""


def _flat() -> AlphaVectorPolicy:
    g = torch.Generator().manual_seed(0)
    return AlphaVectorPolicy(
        torch.randn(4, 3, generator=g, dtype=torch.float64) * 1e3, torch.tensor([0, 2, 1, 2])
    )


def _momdp() -> AlphaVectorPolicy:
    g = torch.Generator().manual_seed(1)
    return AlphaVectorPolicy(
        torch.randn(5, 2, generator=g, dtype=torch.float64),
        torch.tensor([1, 0, 0, 3, 2]),
        observed=torch.tensor([0, 0, 2, 2, 1]),
    )


def _same(a: AlphaVectorPolicy, b: AlphaVectorPolicy) -> None:
    assert torch.equal(a.alphas, b.alphas) and torch.equal(a.actions, b.actions)
    assert (a.observed is None) == (b.observed is None)
    if a.observed is not None:
        assert torch.equal(a.observed, b.observed)


@pytest.mark.parametrize("make", [_flat, _momdp])
@pytest.mark.parametrize("suffix", [".policyx", ".safetensors"])
def test_round_trip_is_exact(make, suffix, tmp_path):
    p = make()
    path = save_policy(p, tmp_path / f"p{suffix}")
    back = load_policy(path)
    _same(back, p)
    beliefs = torch.tensor([[0.2, 0.8], [0.5, 0.5]], dtype=torch.float64)
    if p.observed is None:
        b = torch.tensor([[0.2, 0.3, 0.5]], dtype=torch.float64)
        assert torch.equal(back.action(b), p.action(b))
        assert torch.equal(back.value(b), p.value(b))
    else:
        x = torch.tensor([0, 2])
        assert torch.equal(back.action(x, beliefs), p.action(x, beliefs))


def test_momdp_header_counts_observed_values(tmp_path):
    text = format_policyx(_momdp(), model="task.pomdpx", num_observed=4)
    assert '<AlphaVector vectorLength="2" numObsValue="4" numVectors="5">' in text
    assert 'model="task.pomdpx"' in text
    assert '<Vector action="3" obsValue="2">' in text
    with pytest.raises(ValueError, match="num_observed = 2"):
        format_policyx(_momdp(), num_observed=2)
    path = tmp_path / "p.policyx"
    path.write_text(text)
    assert read_policyx(path).observed.tolist() == [0, 0, 2, 2, 1]
    assert read_policyx(path, momdp=False).observed is None


def test_reads_appl_written_tiger_policy(tmp_path):
    path = tmp_path / "tiger.policyx"
    path.write_text(APPL_STYLE)
    p = read_policyx(path)
    assert p.observed is None and p.num_vectors == 5
    assert p.actions.tolist() == [1, 0, 0, 2, 0]
    torch.testing.assert_close(p.alphas[0], torch.tensor([-81.5975, 28.4025], dtype=torch.float64))
    b0 = torch.tensor([0.5, 0.5], dtype=torch.float64)
    # Tiger's optimal value at the uniform belief, 19.37 (Kaelbling et al. 1998): listen there
    assert p.value(b0).item() == pytest.approx(19.3711) and p.action(b0).item() == 0
    sure_left = torch.tensor([0.99, 0.01], dtype=torch.float64)
    assert p.action(sure_left).item() == 2  # open the right door
    _same(read_policyx(write_policyx(p, tmp_path / "again.policyx")), p)


def test_reads_sparse_vectors(tmp_path):
    path = tmp_path / "s.policyx"
    path.write_text(
        '<?xml version="1.0"?>\n<Policy version="0.1" type="value">\n'
        '<AlphaVector vectorLength="3" numObsValue="2" numVectors="1">\n'
        '<SparseVector action="1" obsValue="1"><Entry>2 -4.5</Entry><Entry>0 1</Entry>'
        "</SparseVector>\n</AlphaVector></Policy>\n"
    )
    p = read_policyx(path)
    assert p.alphas.tolist() == [[1.0, 0.0, -4.5]] and p.observed.tolist() == [1]


@pytest.mark.parametrize(
    ("text", "line", "reason"),
    [
        (APPL_STYLE.replace("</AlphaVector>", "</AlphaVectr>"), 9, "malformed XML"),
        (
            APPL_STYLE.replace('</Vector>\n<Vector action="2"', '\n<Vector action="2"'),
            7,
            "<Vector> inside <Vector>",
        ),
        (APPL_STYLE.replace("3.01448 24.6954 ", "3.01448 "), 5, "expected 2 values"),
        (APPL_STYLE.replace('numVectors="5"', 'numVectors="6"'), 3, "numVectors = 6"),
        (APPL_STYLE.replace('action="2"', 'action="open"'), 7, "action='open'"),
        (APPL_STYLE.replace("19.3711 19.3711", "19.3711 abc"), 8, "bad number"),
        (APPL_STYLE.replace('<Vector action="1"', '<Row action="1"'), 4, "unexpected element"),
        (APPL_STYLE.replace('obsValue="0">3.01448', 'obsValue="1">3.01448'), 5, "obsValue 1 out"),
        (APPL_STYLE.replace("-81.5975 28.4025", "nan 28.4025"), 4, "non-finite"),
    ],
)
def test_malformed_policyx_reports_file_and_line(text, line, reason, tmp_path):
    path = tmp_path / "bad.policyx"
    path.write_text(text)
    with pytest.raises(ParseError) as info:
        read_policyx(path)
    assert reason in info.value.reason, info.value.reason
    assert info.value.path == str(path) and info.value.line == line, str(info.value)


def test_entity_declarations_are_refused(tmp_path):
    path = tmp_path / "e.policyx"
    path.write_text('<?xml version="1.0"?>\n<!DOCTYPE p [<!ENTITY a "aaaa">]>\n<Policy/>\n')
    with pytest.raises(ParseError, match="entity"):
        read_policyx(path)


def test_bad_safetensors_and_missing_files(tmp_path):
    junk = tmp_path / "junk.safetensors"
    junk.write_bytes(b"\x00\x01not a safetensors file")
    with pytest.raises(ParseError, match="not a safetensors file"):
        read_policy_safetensors(junk)
    from safetensors.torch import save_file

    other = tmp_path / "other.safetensors"
    save_file({"weights": torch.zeros(2)}, str(other))
    with pytest.raises(ParseError, match="missing"):
        read_policy_safetensors(other)
    with pytest.raises(ParseError, match="cannot read file"):
        read_policyx(tmp_path / "absent.policyx")
    with pytest.raises(ValueError, match=r"\.policyx or \.safetensors"):
        save_policy(_flat(), tmp_path / "p.bin")
    with pytest.raises(TypeError, match="AlphaVectorPolicy"):
        write_policyx(torch.zeros(2), tmp_path / "x.policyx")


def test_writes_are_atomic(tmp_path):
    write_policyx(_flat(), tmp_path / "a.policyx")
    write_policy_safetensors(_flat(), tmp_path / "a.safetensors")
    write_policyx(_momdp(), tmp_path / "a.policyx")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.policyx", "a.safetensors"]
    _same(read_policyx(tmp_path / "a.policyx"), _momdp())
