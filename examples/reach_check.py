"""Which box configurations of the hand-finishing task can the robot reach and the person use?

Runs the Panda reach check (batched inverse kinematics) and the human comfort check on every
(horizontal, vertical, tilt) configuration of the default box grid, prints the fractions and,
if a path is given, writes a PNG of the kept configurations.

Usage: ``python examples/reach_check.py [out.png] [--seed 0]``
"""

from __future__ import annotations

import argparse

from torchhrc.tasks.hand_finishing.geometry import BoxGeometry, feasible_box_configurations


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("png", nargs="?", help="write a PNG of the configurations here")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    geometry = BoxGeometry()
    result = feasible_box_configurations(geometry, seed=args.seed)
    H, V, T = geometry.shape
    print(f"box configurations: {H} horizontal x {V} vertical x {T} tilt = {H * V * T}")
    print(f"reachable by the robot:       {result.reachable.double().mean().item():.3f}")
    print(f"comfortable, left surface:    {result.comfortable[..., 0].double().mean().item():.3f}")
    print(f"comfortable, right surface:   {result.comfortable[..., 1].double().mean().item():.3f}")
    print(f"kept (reachable, comfortable): {result.fraction:.3f}")
    if args.png:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, axes = plt.subplots(1, T, figsize=(2.6 * T, 2.8), sharey=True)
        code = result.reachable.int() + result.mask.int()  # 0 unreachable, 1 reach only, 2 kept
        for t, ax in enumerate(axes):
            ax.imshow(
                code[:, :, t].T.numpy(),
                origin="lower",
                vmin=0,
                vmax=2,
                cmap="RdYlGn",
                extent=(-0.5, H - 0.5, -0.5, V - 0.5),
            )
            ax.set_xticks(range(H), [f"{h:+.1f}" for h in geometry.horizontal], fontsize=7)
            ax.set_yticks(range(V), [f"{v:.2f}" for v in geometry.vertical], fontsize=7)
            ax.set_title(f"tilt {geometry.tilt[t] * 57.2958:+.0f} deg", fontsize=9)
            ax.set_xlabel("horizontal (m)", fontsize=8)
        axes[0].set_ylabel("vertical (m)", fontsize=8)
        fig.suptitle(
            "red: unreachable, yellow: reachable, green: reachable and comfortable", fontsize=9
        )
        fig.tight_layout()
        fig.savefig(args.png, dpi=120)
        print(f"wrote {args.png}")


if __name__ == "__main__":
    main()
