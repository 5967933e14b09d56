"""Learn the hand-position observation model (a discretized 2D Gaussian) from simulated tracks.

The paper specifies the observation function by hand; here it is learned from hand tracks by
maximising their log marginal likelihood through the belief filter, with the person's type
unknown. Prints the true and the learned means and standard deviations.

Usage: ``python examples/observation_model.py [--tracks 200] [--seed 0]``
"""

from __future__ import annotations

import argparse

import torch

from torchhrc.pomdp.observation import DiscretizedGaussianObservation, ObservationGrid
from torchhrc.pomdp.observation_fit import fit_observation_model, simulate_tracks


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tracks", type=int, default=200)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    d = torch.float64

    # Hand positions on a 10 x 8 grid of the floor in front of the box (m); two types: left
    # side first and right side first; the mean moves with the task progress x (3 values).
    grid = ObservationGrid.uniform((-1.0, 1.0), (0.0, 1.6), (10, 8))
    X, Y = 3, 2
    progress = torch.tensor([0.0, 0.3, 0.6], dtype=d).view(X, 1, 1) * torch.tensor(
        [0.0, 1.0], dtype=d
    )
    gen = torch.Generator().manual_seed(args.seed)
    Tx = torch.rand(1, X, Y, X, generator=gen, dtype=d) + 0.2
    Tx = Tx / Tx.sum(-1, keepdim=True)
    true = DiscretizedGaussianObservation(
        grid,
        torch.tensor([[-0.45, 0.4], [0.45, 0.4]], dtype=d),
        torch.tensor([[0.20, 0.15], [0.25, 0.12]], dtype=d),
        offset=progress,
        num_observed=X,
        num_hidden=Y,
    )
    tracks = simulate_tracks(true, Tx, num_tracks=args.tracks, length=10, seed=args.seed)
    model = DiscretizedGaussianObservation(
        grid,
        torch.tensor([[-0.2, 0.6], [0.2, 0.6]], dtype=d),
        torch.full((2, 2), 0.4, dtype=d),
        offset=progress,
        num_observed=X,
        num_hidden=Y,
    )
    fit = fit_observation_model(model, Tx, tracks, optimizer="lbfgs", lr=1.0, steps=20)
    print(
        f"{args.tracks} tracks x 10 steps; log likelihood {fit.initial_log_likelihood:.1f} -> "
        f"{fit.log_likelihood:.1f} in {fit.steps} L-BFGS steps"
    )
    for y, name in enumerate(("left first", "right first")):
        print(
            f"type {name}: mean true {true.loc[y].tolist()} learned "
            f"{[round(v, 3) for v in model.loc[y].tolist()]}"
        )
        print(
            f"{'':>16} std  true {[round(v, 3) for v in true.scale()[0, y].tolist()]} learned "
            f"{[round(v, 3) for v in model.scale()[0, y].tolist()]}"
        )


if __name__ == "__main__":
    main()
