import torch

from torchhrc.mixture._em import column_blocks, run_groups


def test_run_groups_pack_every_used_slot_once():
    g = torch.Generator().manual_seed(0)
    mask = torch.rand(30, 7, generator=g) < 0.5
    seen = torch.zeros_like(mask)
    previous_k = 0
    for runs, slots in run_groups(mask):
        k = slots.shape[1]
        assert k > previous_k  # increasing k, one group per k
        previous_k = k
        assert (mask[runs].sum(-1) == k).all()
        assert (slots[:, 1:] > slots[:, :-1]).all()  # ascending slots
        assert mask[runs[:, None], slots].all()
        seen[runs[:, None], slots] = True
    assert torch.equal(seen, mask)


def test_column_blocks_cover_the_columns_in_order():
    blocks = column_blocks(1000, 3000)
    covered = torch.cat([torch.arange(1000)[b] for b in blocks])
    assert torch.equal(covered, torch.arange(1000))
    assert column_blocks(0, 5) == [slice(0, 0)]
