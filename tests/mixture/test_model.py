import math

import pytest
import torch

from torchhrc.errors import ModelError, ParseError
from torchhrc.mixture import MarkovChainMixture


def _model(initial=True, dtype=torch.float64):
    g = torch.Generator().manual_seed(0)
    T = torch.rand(3, 4, 4, generator=g, dtype=dtype)
    T[0, 1, 2] = 0.0  # an impossible transition, stored as -inf
    T = T / T.sum(-1, keepdim=True)
    W = torch.tensor([0.2, 0.5, 0.3], dtype=dtype)
    I0 = torch.softmax(torch.rand(3, 4, generator=g, dtype=dtype), -1) if initial else None
    vocab = tuple(("human" if a < 2 else "robot", f"act{a}") for a in range(4))
    return MarkovChainMixture(T.log(), W.log(), None if I0 is None else I0.log(), vocab)


@pytest.mark.parametrize("suffix", [".json", ".safetensors"])
@pytest.mark.parametrize("initial", [False, True])
def test_save_load_round_trip(tmp_path, suffix, initial):
    m = _model(initial)
    path = tmp_path / f"model{suffix}"
    m.save(path)
    back = MarkovChainMixture.load(path)
    torch.testing.assert_close(back.log_transition, m.log_transition)
    assert back.log_transition[0, 1, 2] == -math.inf
    torch.testing.assert_close(back.log_weights, m.log_weights)
    if initial:
        torch.testing.assert_close(back.log_initial, m.log_initial)
    else:
        assert back.log_initial is None
    assert back.vocabulary == m.vocabulary
    assert [p.name for p in tmp_path.iterdir()] == [path.name]  # no temporary left


def test_load_rejects_other_files(tmp_path):
    bad = tmp_path / "x.json"
    bad.write_text('{"format": "something else"}')
    with pytest.raises(ParseError, match=r"x\.json"):
        MarkovChainMixture.load(bad)
    bad.write_text("{not json")
    with pytest.raises(ParseError, match=r"x\.json:1"):
        MarkovChainMixture.load(bad)
    with pytest.raises(ValueError, match=r"\.pkl"):
        _model().save(tmp_path / "m.pkl")


def test_validation_messages():
    T = torch.full((2, 3, 3), 1 / 3, dtype=torch.float64).log()
    W = torch.tensor([0.5, 0.5], dtype=torch.float64).log()
    with pytest.raises(ModelError, match=r"log_transition\[1, 2\] row"):
        bad = T.clone()
        bad[1, 2, 0] = 0.0
        MarkovChainMixture(bad, W)
    with pytest.raises(ModelError, match="log_weights"):
        MarkovChainMixture(T, torch.zeros(3, dtype=torch.float64))
    with pytest.raises(ModelError, match="nan"):
        bad = T.clone()
        bad[0, 0, 0] = math.nan
        MarkovChainMixture(bad, W)
    with pytest.raises(TypeError, match="floating"):
        MarkovChainMixture(torch.zeros(2, 3, 3, dtype=torch.long), W)
    with pytest.raises(ModelError, match="vocabulary"):
        MarkovChainMixture(T, W, vocabulary=("a",))


def test_to_and_batch_shape():
    m = _model()
    m32 = m.to(dtype=torch.float32)
    assert m32.log_transition.dtype == torch.float32 and m32.log_initial.dtype == torch.float32
    batched = MarkovChainMixture(m.log_transition.expand(5, 3, 4, 4), m.log_weights, m.log_initial)
    assert batched.batch_shape == (5,)
    assert m.num_parameters() == 3 * 4 * 3 + 2 + 3 * 3
