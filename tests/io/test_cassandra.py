"""Tests of torchhrc.io.cassandra: every feature by hand, round trips, corruptions."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import pytest
import torch
from _fuzz import corrupt
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from torchhrc.errors import ParseError
from torchhrc.io.cassandra import format_pomdp, parse_pomdp, read_pomdp, write_pomdp
from torchhrc.pomdp import POMDP
from torchhrc.pomdp.sparse import SparsePOMDP
from torchhrc.tasks.classic import rock_sample, tag, tiger
from torchhrc.testing import random_pomdp

ROOT = Path(__file__).resolve().parents[2]

# The Tiger problem in the layout of Cassandra's tiger.aaai.pomdp (matrix forms, keywords).
TIGER_TEXT = """\
# Tiger (Kaelbling, Littman, Cassandra 1998)
discount: 0.95
values: reward
states: tiger-left tiger-right
actions: listen open-left open-right
observations: tiger-left tiger-right

T: listen
identity

T: open-left
uniform

T: open-right
uniform

O: listen
0.85 0.15
0.15 0.85

O: open-left
uniform

O: open-right
uniform

R: listen : * : * : * -1
R: open-left : tiger-left : * : * -100
R: open-left : tiger-right : * : * 10
R: open-right : tiger-left : * : * 10
R: open-right : tiger-right : * : * -100
"""

# Every feature: comments, cost, names and counts, start include, wildcards, the three forms,
# uniform, identity, overrides, and rewards depending on s2 and o.
EVERYTHING = """\
# a comment line
discount: 0.9   # a trailing comment
values: cost
states: s0 s1 s2
actions: 2
observations: left right
start include: s0 s2

T: * uniform
T: 0 identity
T: 1 : s0
0.0 0.5 0.5
T: 1 : s1 uniform
T: 1 : s2 : * 0.0
T: 1 : s2 : s2 1.0

O: * uniform
O: 1
1 0
0 1
0.2 0.8
O: 0 : s2
0.9 0.1
O: 0 : s1 : left 0.3
O: 0:s1:right 0.7

R: * : * : * : * 1.0
R: 1 : s0 : * : * 5
R: 0 : s2 : s2 : left 10
R: 0 : s1 : s1
2 4
R: 1 : s1
1 1
2 2
3 3
"""


def _assert_same(a: POMDP, b: POMDP) -> None:
    assert torch.equal(a.T, b.T)
    assert torch.equal(a.Z, b.Z)
    assert torch.equal(a.R, b.R)
    assert torch.equal(a.b0, b.b0)
    assert a.discount == b.discount


def test_every_feature_parses_to_the_values_worked_by_hand():
    m = read_pomdp(EVERYTHING)
    d = torch.float64
    assert m.discount == 0.9
    assert m.states == ("s0", "s1", "s2") and m.actions is None
    assert m.observations == ("left", "right")
    torch.testing.assert_close(m.b0, torch.tensor([0.5, 0.0, 0.5], dtype=d))
    torch.testing.assert_close(m.T[0], torch.eye(3, dtype=d))
    third = 1.0 / 3.0
    T1 = torch.tensor([[0.0, 0.5, 0.5], [third, third, third], [0.0, 0.0, 1.0]], dtype=d)
    torch.testing.assert_close(m.T[1], T1)
    Z0 = torch.tensor([[0.5, 0.5], [0.3, 0.7], [0.9, 0.1]], dtype=d)
    Z1 = torch.tensor([[1.0, 0.0], [0.0, 1.0], [0.2, 0.8]], dtype=d)
    torch.testing.assert_close(m.Z, torch.stack([Z0, Z1]))
    # expected costs: (0, s1) = 0.3 * 2 + 0.7 * 4; (0, s2) = 0.9 * 10 + 0.1 * 1;
    # (1, s1) = mean over s2 of the matrix rows = 2; (1, s0) = 5; the rest 1. Cost = -reward.
    cost = torch.tensor([[1.0, 3.4, 9.1], [5.0, 2.0, 1.0]], dtype=d)
    torch.testing.assert_close(m.R, -cost)


@pytest.mark.parametrize(
    ("start", "expected"),
    [
        ("start: uniform", [1 / 3, 1 / 3, 1 / 3]),
        ("start: b", [0.0, 1.0, 0.0]),
        ("start: 2", [0.0, 0.0, 1.0]),
        ("start: 0.2 0.3 0.5", [0.2, 0.3, 0.5]),
        ("start exclude: a", [0.0, 0.5, 0.5]),
        ("start include: a 2", [0.5, 0.0, 0.5]),
        ("", [1 / 3, 1 / 3, 1 / 3]),
    ],
)
def test_start_forms(start, expected):
    text = f"""discount: 1
states: a b c
{start}
actions: 1
observations: 1
T: * identity
O: * uniform
"""
    m = read_pomdp(text)
    torch.testing.assert_close(m.b0, torch.tensor(expected, dtype=torch.float64))
    assert m.R.abs().sum() == 0


@pytest.mark.parametrize("sparse", [False, True])
def test_wildcard_action_entries_in_runs_override_in_file_order(sparse):
    """Runs of ``O: * : s2 : o p`` (Hallway's form, read by the vectorised path) set every
    action; a later specific entry overrides its action only, an even later wildcard all
    again, exactly as the entries one by one (worked by hand)."""
    text = """discount: 0.9
values: reward
states: 2
actions: 3
observations: 2
T: * : 0 : 0 1.0
T: * : 1 : 1 1.0
T: 2 : 1 : 0 0.5
T: 2 : 1 : 1 0.5
O: * : 0 : 0 0.25
O: * : 0 : 1 0.75
O: * : 1 : 0 1.0
O: 1 : 0 : 0 0.5
O: 1 : 0 : 1 0.5
O: * : 1 : 0 0.0
O: * : 1 : 1 1.0
R: * : 0 : * : * 1.0
R: 1 : 0 : * : * 2.0
"""
    m = parse_pomdp(text, sparse=sparse)
    if sparse:
        m = m.to_dense()
    T, Z = m.T, m.Z
    eye = torch.eye(2, dtype=torch.float64)
    assert torch.equal(T[0], eye) and torch.equal(T[1], eye)
    assert torch.equal(T[2], torch.tensor([[1.0, 0.0], [0.5, 0.5]], dtype=torch.float64))
    z = torch.tensor([[0.25, 0.75], [0.0, 1.0]], dtype=torch.float64)
    assert torch.equal(Z[0], z) and torch.equal(Z[2], z)
    assert torch.equal(Z[1], torch.tensor([[0.5, 0.5], [0.0, 1.0]], dtype=torch.float64))
    assert m.R[:, 0].tolist() == [1.0, 2.0, 1.0] and m.R[:, 1].tolist() == [0.0, 0.0, 0.0]


@pytest.mark.parametrize("sparse", [False, True])
def test_identity_overrides_earlier_entries_of_its_action_and_later_ones_override_it(sparse):
    """``T: a identity`` sets the action's whole matrix: entries of that action before it are
    gone (the sparse reader drops them at the end instead of writing S x S zeros), other
    actions keep theirs, and entries after it override it (worked by hand)."""
    text = """discount: 0.9
values: reward
states: 3
actions: 2
observations: 1
T: * : 0 : 2 1.0
T: * : 1 : 2 1.0
T: * : 2 : 0 1.0
T: 0 identity
T: 0 : 2 : 2 0.0
T: 0 : 2 : 1 1.0
O: * uniform
"""
    m = parse_pomdp(text, sparse=sparse)
    if sparse:
        m = m.to_dense()
    f = torch.float64
    assert torch.equal(m.T[0], torch.tensor([[1, 0, 0], [0, 1, 0], [0, 1, 0]], dtype=f))
    assert torch.equal(m.T[1], torch.tensor([[0, 0, 1], [0, 0, 1], [1, 0, 0]], dtype=f))


@pytest.mark.parametrize("sparse", [False, True])
def test_a_matrix_of_zeros_overrides_earlier_entries_of_its_actions(sparse):
    """``T: * : * : * 0.0`` (the first line of APPL's TagAvoid) and ``T: a : * : * 0.0`` set
    whole matrices to zero: earlier entries of those actions are gone, later ones count (the
    sparse reader appends no cells for them, as for ``identity``), and a row left at zero is
    reported as summing to 0, not as never set, by both readers (worked by hand)."""
    head = "discount: 0.9\nvalues: reward\nstates: 3\nactions: 2\nobservations: 1\n"
    text = (
        head
        + """T: * : 0 : 1 1.0
T: * : * : * 0.0
T: * : 0 : 0 1.0
T: * : 1 : 2 1.0
T: * : 2 : 2 1.0
T: 1 : 2 : 0 1.0
T: 1 : * : * 0
T: 1 : 0 : 2 1.0
T: 1 : 1 : 1 1.0
T: 1 : 2 : 1 1.0
O: * uniform
"""
    )
    m = parse_pomdp(text, sparse=sparse)
    if sparse:
        m = m.to_dense()
    f = torch.float64
    assert torch.equal(m.T[0], torch.tensor([[1, 0, 0], [0, 0, 1], [0, 0, 1]], dtype=f))
    assert torch.equal(m.T[1], torch.tensor([[0, 0, 1], [0, 1, 0], [0, 1, 0]], dtype=f))
    missing = text.replace("T: 1 : 1 : 1 1.0\n", "")
    with pytest.raises(ParseError, match="action 1, state 1 sums to 0, expected 1") as info:
        parse_pomdp(missing, sparse=sparse)
    assert info.value.line == 12  # the zero matrix was the row's last assignment


def test_sparse_reader_keeps_no_cells_for_a_matrix_of_zeros():
    """A tag-sized ``T: * : * : * 0.0`` (5 x 870 x 870 cells) costs the sparse table nothing:
    the cells kept at the end are the entries after it."""
    from torchhrc.io.cassandra.tables import _SparseTable

    table = _SparseTable("T", 5, 870, 870)
    table.fill(None, slice(None), slice(None), slice(None), 0.0, 7)  # type: ignore[arg-type]
    assert table.length == 0 and table.cells == 0 and not table.keys
    assert table.zeroed == dict.fromkeys(range(5), 7)
    assert table.cleared == dict.fromkeys(range(5), 0)


def test_sparse_reader_takes_an_identity_at_rocksample_7_8_size_and_a_long_name_list():
    # before: the identity wrote 13 x 12545^2 zeros (refused: too many cells), and the
    # duplicate check of 12,545 state names was quadratic
    names = " ".join(f"s{i}" for i in range(12545))
    text = (f"discount: 0.95\nstates: {names}\nactions: 13\nobservations: 3\n"
            "T: * identity\nO: * : * : 0 1.0\n")  # fmt: skip
    m = parse_pomdp(text, sparse=True)
    index, values = m.transitions
    assert index.shape == (13 * 12545, 3) and bool((values == 1.0).all())
    assert torch.equal(index[:, 1], index[:, 2])  # the diagonal
    assert m.states[-1] == "s12544"
    with pytest.raises(ParseError, match="duplicate name 's7'") as info:
        parse_pomdp(text.replace("s12544", "s7"), sparse=True)
    assert info.value.line == 2


def test_classic_tiger_file_equals_tasks_classic_tiger():
    _assert_same(read_pomdp(TIGER_TEXT), tiger())
    assert read_pomdp(TIGER_TEXT).actions == tiger().actions
    sparse = read_pomdp(TIGER_TEXT, sparse=True)
    assert isinstance(sparse, SparsePOMDP)
    _assert_same(sparse.to_dense(), tiger())


def test_sparse_reader_refuses_observation_dependent_rewards_and_reads_the_rest():
    with pytest.raises(ParseError, match="sparse reader supports rewards"):
        parse_pomdp(EVERYTHING, sparse=True)
    text = EVERYTHING[: EVERYTHING.index("R: * : * : * : * 1.0")] + "R: 1 : s0 : * : * 5\n"
    dense, sparse = parse_pomdp(text), parse_pomdp(text, sparse=True)
    _assert_same(sparse.to_dense(), dense)
    assert sparse.actions == ("0", "1") and sparse.states == ("s0", "s1", "s2")


def test_benchmark_problem_files_match_generators():
    problems = ROOT / "benchmarks" / "problems"
    if not (problems / "tiger.pomdp").exists():
        pytest.skip("benchmarks/problems not generated (make_problems.py)")
    _assert_same(read_pomdp(problems / "tiger.pomdp"), tiger())
    _assert_same(read_pomdp(problems / "rocksample_4_4.pomdp"), rock_sample(4, 4))
    _assert_same(read_pomdp(problems / "tag.pomdp"), tag())
    hallway2 = problems / "hallway2.pomdp"
    if hallway2.exists():  # re-written from the published definition (Littman et al. 1995)
        m = read_pomdp(hallway2)
        assert (m.num_states, m.num_actions, m.num_observations) == (92, 5, 17)
        # reward 1 on entering the goal: the expected reward of "forward" next to it is 0.8
        assert m.discount == 0.95 and m.R.max().item() == pytest.approx(0.8)


def _canonical(coo: tuple[torch.Tensor, torch.Tensor]) -> tuple[torch.Tensor, torch.Tensor]:
    index, prob = coo
    key = (index[:, 0] * 100_000 + index[:, 1]) * 100_000 + index[:, 2]
    order = key.argsort()
    return key[order], prob[order]


@pytest.mark.slow
def test_rocksample_7_8_file_reads_sparse_and_equals_the_generator(tmp_path):
    # Too large to keep in the repository (11 MB): written here, as make_problems.py does.
    big = write_pomdp(rock_sample(7, 8, form="sparse"), tmp_path / "rocksample_7_8.pomdp")
    m = read_pomdp(big, sparse=True)
    ref = rock_sample(7, 8, form="sparse")
    assert (m.num_states, m.num_actions, m.num_observations) == (12545, 13, 3)
    for got, want in ((m.transitions, ref.transitions), (m.observations_, ref.observations_)):
        for x, y in zip(_canonical(got), _canonical(want)):
            assert torch.equal(x, y)
    assert torch.equal(m.R, ref.R) and torch.equal(m.b0, ref.b0)


def test_models_too_large_for_dense_tensors_are_refused():
    # RockSample(7, 8) (12545 states, 13 actions) would need 2e9 entries of T
    text = "discount: 0.95\nstates: 12545\nactions: 13\nobservations: 3\nT: * identity\n"
    with pytest.raises(ParseError, match="too large to hold densely") as info:
        parse_pomdp(text)
    assert info.value.line == 5


@pytest.mark.parametrize("make", [tiger, lambda: rock_sample(4, 4), tag])
def test_classic_models_round_trip_exactly(make, tmp_path):
    m = make()
    path = write_pomdp(m, tmp_path / "m.pomdp")
    back = read_pomdp(path)
    _assert_same(back, m)
    assert back.states == m.states and back.actions == m.actions
    assert back.observations == m.observations
    numbers_only = read_pomdp(format_pomdp(m, names=False))
    _assert_same(numbers_only, m)
    assert numbers_only.states is None


def test_sparse_model_writes_the_same_file_as_its_dense_form():
    m = rock_sample(4, 4)
    assert format_pomdp(SparsePOMDP.from_dense(m)) == format_pomdp(m)


def test_repeated_coordinates_of_a_sparse_model_are_written_summed():
    # a coordinate list may repeat a cell (the solvers sum it); the file holds one line per
    # cell with the sum, where two lines would have read back as the later one alone
    sp = SparsePOMDP.from_dense(tiger())
    (ti, tp), (zi, zp) = sp.transitions, sp.observations_
    split = SparsePOMDP(
        transitions=(torch.cat([ti, ti]), torch.cat([tp * 0.25, tp * 0.75])),
        observations_=(torch.cat([zi, zi, zi]), torch.cat([zp, zp, zp]) / 3),
        R=sp.R, b0=sp.b0, discount=sp.discount,
        states=sp.states, actions=sp.actions, observations=sp.observations,
    )  # fmt: skip
    text = format_pomdp(split)
    assert text.count("\nT: ") == format_pomdp(sp).count("\nT: ")
    back = parse_pomdp(text)
    ref = tiger()
    for name in ("T", "Z"):
        torch.testing.assert_close(getattr(back, name), getattr(ref, name), rtol=0, atol=1e-15)


def test_write_is_atomic_and_leaves_no_temp_files(tmp_path):
    target = tmp_path / "t.pomdp"
    write_pomdp(tiger(), target)
    write_pomdp(tiger(), target)  # overwrite
    assert [p.name for p in tmp_path.iterdir()] == ["t.pomdp"]
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE(target.stat().st_mode) == 0o666 & ~umask  # not mkstemp's 0o600


def test_batched_models_are_rejected_by_the_writer():
    with pytest.raises(ValueError, match="one problem at a time"):
        format_pomdp(random_pomdp(2, 2, 2, batch_shape=(2,)))


@pytest.mark.parametrize(
    ("text", "line", "column", "reason"),
    [
        (
            TIGER_TEXT.replace("R: listen : * : * : * -1", "R: listen : nowhere : * : * -1"),
            27,
            13,
            "unknown state 'nowhere'",
        ),
        (TIGER_TEXT.replace("0.15 0.85", "0.15 x85"), 19, 6, "expected 4 numbers"),
        (TIGER_TEXT.replace("discount: 0.95", "discount: 1.5"), 2, 11, "discount in"),
        (TIGER_TEXT.replace("values: reward", "values: money"), 3, 9, "'reward' or 'cost'"),
        (
            TIGER_TEXT.replace("T: open-left\nuniform", "T: open-left\n0.2 0.2 0.3 0.3"),
            11,
            1,
            "sums to 0.4",
        ),
        (TIGER_TEXT.replace("T: listen\n", "Q: listen\n"), 8, 1, "expected 'T:', 'O:' or 'R:'"),
        (
            TIGER_TEXT.replace("actions: listen open-left open-right\n", ""),
            7,
            1,
            "missing 'actions:'",
        ),
        (TIGER_TEXT + "T: 7 : 0 : 0 1.0\n", 32, 4, "action 7 out of range"),
        (TIGER_TEXT + "O: listen : 0", 32, 14, "end of file"),
    ],
)
def test_malformed_files_report_line_column_reason(text, line, column, reason):
    with pytest.raises(ParseError) as info:
        read_pomdp(text)
    err = info.value
    assert reason in err.reason, err.reason
    assert (err.line, err.column) == (line, column), str(err)
    assert str(err).startswith(f"<string>:{line}:{column}: ")


def test_missing_file_and_path_in_message(tmp_path):
    with pytest.raises(ParseError, match="cannot read file"):
        read_pomdp(tmp_path / "absent.pomdp")
    bad = tmp_path / "bad.pomdp"
    bad.write_text("discount: 0.9\nstates: 2\nactions: 1\nobservations: 1\nT: 0 : 0 : 5 1\n")
    with pytest.raises(ParseError) as info:
        read_pomdp(bad)
    assert info.value.path == str(bad) and info.value.line == 5


@pytest.mark.parametrize("sparse", [False, True])
def test_probability_out_of_range_names_its_cell_and_the_entry_line(sparse):
    text = "discount: 0.9\nstates: 2\nactions: 1\nobservations: 1\nT: 0 identity\nO: 0 uniform\n"
    text += "T: 0 : 1 : 0 1.5\nT: 0 : 1 : 1 -0.5\n"  # the row sums to 1: only the range fails
    with pytest.raises(ParseError, match=r"T\[0, 1, 0\] = 1\.5 is not a probability") as info:
        parse_pomdp(text, sparse=sparse)
    assert info.value.line == 8  # the row's last entry (the reader keeps one line per row)


def test_unnormalised_row_names_the_entry_line():
    text = "discount: 0.9\nstates: 2\nactions: 1\nobservations: 1\nT: 0 identity\nO: 0 uniform\n"
    text += "T: 0 : 1 : 0 0.5\n"
    with pytest.raises(ParseError, match=r"row for action 0, state 1 sums to 1\.5") as info:
        read_pomdp(text)
    assert info.value.line == 7


# ----------------------------------------------------------------------------- properties


@st.composite
def models(draw):
    S = draw(st.integers(1, 5))
    A = draw(st.integers(1, 3))
    O = draw(st.integers(1, 3))
    seed = draw(st.integers(0, 2**31 - 1))
    sparsity = draw(st.sampled_from([0.0, 0.5]))
    m = random_pomdp(S, A, O, seed=seed, sparsity=sparsity, discount=draw(st.floats(0.01, 1.0)))
    if draw(st.booleans()):
        m = POMDP(
            T=m.T,
            Z=m.Z,
            R=m.R * draw(st.sampled_from([1.0, 1e-7, 1e6])),
            b0=m.b0,
            discount=m.discount,
            states=tuple(f"s{i}" for i in range(S)),
            actions=tuple(f"act-{i}" for i in range(A)),
            observations=tuple(f"o_{i}" for i in range(O)),
        )
    return m


@settings(max_examples=60, deadline=None, derandomize=True)
@given(models())
def test_random_models_round_trip(m):
    back = read_pomdp(format_pomdp(m))
    _assert_same(back, m)
    _assert_same(parse_pomdp(format_pomdp(m), sparse=True).to_dense(), m)
    assert back.states == m.states and back.observations == m.observations
    _assert_same(read_pomdp(format_pomdp(back)), m)


_JUNK = [
    ":",
    "*",
    "foo",
    "1e999",
    "-1",
    "0.5",
    "2",
    "uniform",
    "identity",
    "T",
    "O",
    "R",
    "states",
    "start",
    "include",
    "nan",
    "inf",
    "#",
    "99",
    "-",
    "0",
]


_BASES = [
    TIGER_TEXT,
    EVERYTHING,
    format_pomdp(random_pomdp(3, 2, 2, seed=1, sparsity=0.5)),
    format_pomdp(random_pomdp(2, 2, 3, seed=2), names=False),
]


@st.composite
def corrupted(draw):
    return corrupt(draw, draw(st.sampled_from(_BASES)), _JUNK) + draw(
        st.sampled_from(["", "\n", " :", "\nT"])
    )


@settings(
    max_examples=400, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow]
)
@given(corrupted())
def test_corrupted_files_raise_parse_error_or_parse_to_a_valid_model(text):
    for sparse in (False, True):
        try:
            m = parse_pomdp(text, sparse=sparse)
        except ParseError as e:
            assert e.path == "<string>" and e.reason
            continue
        if sparse:
            m = m.to_dense()
        m.validate()  # a file that still parses gives a valid model
        assert torch.isfinite(m.R).all()


_TOKEN_CHARS = list("T:0a-_.# \t\n\r\x0b\x0c\x1c\x85\u00a0\u2003\u2028x9")


@settings(max_examples=300, deadline=None)
@given(
    st.text(alphabet=st.sampled_from(_TOKEN_CHARS), max_size=80),
    st.sampled_from([(1, 1), (7, 7), (2, 16), (1 << 12, 1 << 18)]),
)
def test_tokens_are_the_grammar_tokens(text: str, pieces: tuple[int, int]) -> None:
    """The tokenizer (str.split after dropping comments and spacing the colons, a piece of
    lines at a time) gives exactly the tokens of the grammar's regex: runs of characters other
    than whitespace, ':' and '#', and each ':' alone, with '#' to the end of the line a
    comment; each at the line and column the regex finds it, and the same again when the
    parser moves back to it (pieces of 1 and 7 characters, cut at the next newline, and of 2
    doubling to 16)."""
    from unittest import mock

    from torchhrc.io.cassandra import tokens

    want = [(m.group(1), m.start(1)) for m in tokens._TOKEN.finditer(text) if m.group(1)]
    first, piece = pieces
    with (
        mock.patch.object(tokens, "_FIRST_PIECE", first),
        mock.patch.object(tokens, "_PIECE", piece),
    ):
        p = tokens._Parser(text, "<text>")
        got = []
        while p.peek() is not None:
            got.append(p.next("a token"))
        assert got == [tok for tok, _ in want]
        for index, (tok, start) in reversed(list(enumerate(want))):
            line = text.count("\n", 0, start) + 1
            assert p.position(index) == (line, start - (text.rfind("\n", 0, start) + 1) + 1)
            p.seek(index)
            assert p.peek() == tok and p.ahead(2) == got[index : index + 2]
        p.seek(0)
        assert p.ahead(len(want) + 1) == got  # across every piece, at once


def test_auto_reads_large_sparse_models_sparsely_and_dense_ones_densely(monkeypatch):
    """``sparse="auto"`` above ``AUTO_SPARSE_ENTRIES``: a model whose T has few nonzeros
    stays sparse; one whose T is dense, or whose rewards depend on the next state, comes back
    dense with the same tensors as a dense read."""
    import torchhrc.io.cassandra as cassandra

    monkeypatch.setattr(cassandra, "AUTO_SPARSE_ENTRIES", 20)  # below every model here
    ring = rock_sample(4, 4)  # deterministic moves: 1 in 257 entries of T nonzero
    assert isinstance(parse_pomdp(format_pomdp(ring), sparse="auto"), SparsePOMDP)
    dense_t = random_pomdp(6, 2, 3, seed=4)  # every entry of T nonzero
    back = parse_pomdp(format_pomdp(dense_t), sparse="auto")
    assert isinstance(back, POMDP)
    _assert_same(back, parse_pomdp(format_pomdp(dense_t)))
    monkeypatch.setattr(cassandra, "AUTO_DENSE_FRACTION", 2.0)  # never dense by density
    # a reward on the next state (the sparse reader refuses it) keeps Tiger dense
    s2_rewards = TIGER_TEXT + "R: listen : tiger-left : tiger-right : * -3\n"
    back = parse_pomdp(s2_rewards, sparse="auto")
    assert isinstance(back, POMDP)
    _assert_same(back, parse_pomdp(s2_rewards))
    assert isinstance(parse_pomdp(format_pomdp(dense_t), sparse="auto"), SparsePOMDP)
    # at the default threshold a 5,000-state model with a few successors a state is sparse,
    # and so is Tag (870 states, 5 actions: 3.8 million entries of T, 0.3 % of them nonzero;
    # its sparse solve took half the memory and time a backup of its dense one), while Tiger
    # and RockSample(4, 4) (3 and 257 states) stay dense
    monkeypatch.undo()
    assert cassandra.AUTO_SPARSE_ENTRIES < 5 * 5000 * 5000
    assert isinstance(parse_pomdp(format_pomdp(tag()), sparse="auto"), SparsePOMDP)
    assert isinstance(parse_pomdp(TIGER_TEXT, sparse="auto"), POMDP)
    assert isinstance(parse_pomdp(format_pomdp(ring), sparse="auto"), POMDP)
