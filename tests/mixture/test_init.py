import torch

from torchhrc.mixture import kmeans_pp_init, random_init, sufficient_statistics


def _blobs():
    # three groups of identical sequences: 0 0 0.., 1 1 1.., 0 1 0 1..
    seqs = torch.tensor([[0] * 6] * 5 + [[1] * 6] * 4 + [[0, 1] * 3] * 3)
    return sufficient_statistics(seqs, torch.full((12,), 6), 2)


def test_kmeans_pp_separates_distinct_groups():
    stats = _blobs()
    mask = torch.ones(8, 3, dtype=torch.bool)
    z = kmeans_pp_init(stats, mask, generator=torch.Generator().manual_seed(0))
    assert z.shape == (3, 8)
    for r in range(8):  # three distinct rows, three clusters: all different
        assert len(set(z[:, r].tolist())) == 3


def test_inits_respect_k_and_seed():
    stats = _blobs()
    ks = torch.tensor([1, 2, 3, 2])
    mask = torch.arange(3) < ks[:, None]
    for init in (kmeans_pp_init, lambda s, m, generator: random_init(s, m, generator=generator)[1]):
        a = init(stats, mask, generator=torch.Generator().manual_seed(3))
        b = init(stats, mask, generator=torch.Generator().manual_seed(3))
        assert torch.equal(a, b)
        assert (a < ks).all() and (a >= 0).all()
    lt, _ = random_init(stats, mask, generator=torch.Generator().manual_seed(0))
    torch.testing.assert_close(lt.exp().sum(-1), torch.ones(4, 3, 2, dtype=torch.float64))
