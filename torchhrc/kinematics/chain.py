"""Serial kinematic chains from URDF: batched forward kinematics, Jacobians, inverse kinematics
within joint limits, and reach checks.

Kinematic chains are read from URDF by pytorch-kinematics (the ``full`` extra) and compiled
into a flat serial chain (one fixed transform per joint and the joint axes) whose forward
kinematics and geometric Jacobian are a few batched tensor products; this is what makes the
batched inverse kinematics fast (tests compare it with pytorch-kinematics and pinocchio).

Example:
    >>> arm = SerialArm.panda()
    >>> arm.dof, arm.forward(torch.zeros(7, dtype=torch.float64)).shape
    (7, torch.Size([4, 4]))
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import torch

from torchhrc._checks import check_shape, check_tensor
from torchhrc.errors import ModelError
from torchhrc.kinematics.human_arm import human_arm_urdf
from torchhrc.kinematics.poses import _as_matrices, _frame_with_z, _rotation_angle

__all__ = ["IKResult", "ReachResult", "SerialArm", "asset_path", "reach_check"]

_FULL_EXTRA = "pip install torchhrc[full]"
# Joint vectors in the table of inverse-kinematics starts (see SerialArm._nearest_seeds).
_SEED_TABLE_SIZE = 4096
# Targets per block when looking up their nearest table entries (keeps the block in cache).
_NEAREST_BLOCK = 128
# Starts per stage of the IK restarts after the first (the rest run in a last stage).
_RESTART_STAGES = (2,)


def _import_pk():
    try:
        import pytorch_kinematics as pk
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError(f"torchhrc.kinematics needs pytorch-kinematics: {_FULL_EXTRA}") from exc
    return pk


def asset_path(name: str) -> Path:
    """Path of a shipped asset (top-level ``assets/``; :func:`torchhrc.resources.shipped_path`).

    Args:
        name: relative name, e.g. ``"panda/panda.urdf"``.

    Returns:
        The file's path.

    Raises:
        FileNotFoundError: no such asset.

    Example:
        >>> asset_path("panda/panda.urdf").name
        'panda.urdf'
    """
    from torchhrc.resources import shipped_path

    return shipped_path("assets", name)


def _dls_step(jac: torch.Tensor, e: torch.Tensor, eye: torch.Tensor) -> torch.Tensor:
    """Damped least-squares step ``J^T (J J^T + lambda^2 I)^-1 e`` ``(n, DOF)`` for Jacobians
    ``jac (n, rows, DOF)``, errors ``e (n, rows)`` and ``eye = lambda^2 I (rows, rows)``."""
    jjt = jac @ jac.transpose(-1, -2) + eye  # (n, rows, rows)
    return (jac.transpose(-1, -2) @ torch.linalg.solve(jjt, e.unsqueeze(-1))).squeeze(-1)


# ------------------------------------------------------------------------- the arm
@dataclass(frozen=True)
class IKResult:
    """Result of :meth:`SerialArm.inverse` (batch shape ``(...)`` of the targets).

    Attributes:
        joints: ``(..., DOF)`` the best joint vector found (within the joint limits).
        position_error: ``(...)`` distance between the reached and target origin (m).
        rotation_error: ``(...)`` geodesic angle between reached and target orientation
            (rad; zero for position-only targets).
        success: ``(...)`` bool, both errors within the tolerances.
    """

    joints: torch.Tensor
    position_error: torch.Tensor
    rotation_error: torch.Tensor
    success: torch.Tensor


class SerialArm:
    """A serial kinematic chain with batched forward kinematics, Jacobian and inverse kinematics.

    Built from a URDF with pytorch-kinematics, then compiled into ``DOF`` joint transforms
    ``F_i`` and axes ``a_i`` so that ``FK(q) = F_0 Rot(a_0, q_0) F_1 ... Rot(a_{n-1}, q_{n-1})
    F_n`` (revolute joints; prismatic joints translate along ``a_i``).

    Args:
        urdf: URDF text or a path to a URDF file.
        end_link: the end-effector link.
        root_link: the chain's root link (default: the URDF's root).
        dtype: float dtype of the compiled chain (float64 default).
        device: its device.

    Raises:
        ImportError: pytorch-kinematics is missing (``pip install torchhrc[full]``).

    Example:
        >>> arm = SerialArm.panda()
        >>> arm.joint_names[0], arm.lower.shape
        ('panda_joint1', torch.Size([7]))
    """

    def __init__(
        self,
        urdf: str | Path,
        end_link: str,
        *,
        root_link: str = "",
        dtype: torch.dtype = torch.float64,
        device: torch.device | str | None = None,
    ) -> None:
        pk = _import_pk()
        text = (
            Path(urdf).read_text()
            if isinstance(urdf, Path) or not str(urdf).lstrip().startswith("<")
            else str(urdf)
        )
        try:
            chain = pk.build_serial_chain_from_urdf(text.encode(), end_link, root_link)
        except (KeyError, ValueError, AttributeError) as exc:
            raise ModelError(f"cannot build a chain to end_link {end_link!r}: {exc}") from exc
        self.chain = chain.to(dtype=dtype, device=device)
        self.dtype, self.device = dtype, torch.device(device or "cpu")
        eye = torch.eye(4, dtype=dtype, device=self.device)
        fixed: list[torch.Tensor] = []
        axes: list[torch.Tensor] = []
        kinds: list[bool] = []  # True: revolute
        names: list[str] = []
        lower: list[float] = []
        upper: list[float] = []
        current = eye
        for frame in chain._serial_frames:  # the path from root to end link, in order
            joint = frame.joint
            lo = eye if frame.link.offset is None else frame.link.offset.get_matrix()[0]
            jo = eye if joint.offset is None else joint.offset.get_matrix()[0]
            current = (
                current
                @ lo.to(dtype=dtype, device=self.device)
                @ jo.to(dtype=dtype, device=self.device)
            )
            if joint.joint_type in ("revolute", "continuous", "prismatic"):
                fixed.append(current)
                current = eye
                axis = joint.axis.to(dtype=dtype, device=self.device)
                axes.append(axis / axis.norm())
                kinds.append(joint.joint_type != "prismatic")
                names.append(joint.name)
                lim = joint.limits if joint.limits is not None else (-math.inf, math.inf)
                if joint.joint_type == "continuous":
                    lim = (-math.inf, math.inf)
                lower.append(float(lim[0]))
                upper.append(float(lim[1]))
        fixed.append(current)
        if not axes:
            raise ModelError(f"the chain to {end_link!r} has no movable joint")
        # Fold a rotation P_i with P_i e_z = a_i into the fixed transforms around each joint
        # (F_i <- F_i P_i, F_i+1 <- P_i^T F_i+1), so that every joint moves about / along its
        # local z axis: T @ Rot_z(q) only mixes two columns of T (no matrix product).
        folded = [f.clone() for f in fixed]
        for i, axis in enumerate(axes):
            frame = _frame_with_z(axis / axis.norm())
            folded[i] = folded[i] @ frame
            folded[i + 1] = frame.transpose(-1, -2) @ folded[i + 1]
        self._fixed = torch.stack(folded)  # (DOF + 1, 4, 4)
        # Nonzero entries (row, value) of each column of F_1 .. F_DOF, for _frames.
        self._terms = tuple(
            tuple(
                tuple((k, float(f[k, j])) for k in range(4) if float(f[k, j]) != 0.0)
                for j in range(4)
            )
            for f in self._fixed[1:].double().cpu()
        )
        self._revolute = torch.tensor(kinds, device=self.device)
        self._kinds: tuple[bool, ...] = tuple(kinds)
        self.joint_names: tuple[str, ...] = tuple(names)
        self.end_link = end_link
        self.lower = torch.tensor(lower, dtype=dtype, device=self.device)  # (DOF,)
        self.upper = torch.tensor(upper, dtype=dtype, device=self.device)  # (DOF,)
        # An upper bound of the distance from the first joint to the end effector: the sum of
        # the translations between joints (triangle inequality); a cheap reach pre-check.
        self._first_joint = self._fixed[0]
        self.max_reach = float(self._fixed[1:, :3, 3].norm(dim=-1).sum())
        self._wrist = self._wrist_constants() if all(kinds) and len(kinds) >= 2 else None

    def _wrist_constants(self) -> tuple[float, float, float, float]:
        """Constants of the exact wrist pre-check (all-revolute chains, see
        :meth:`_provably_unreachable`): ``(bound, h, rho, tcp_offset)``.

        With ``p_i`` the origin of joint ``i`` and ``t_k`` the translation of ``F_k``, the last
        joint's origin ``p_{n-1}`` is fixed by the end-effector pose (a revolute joint does not
        move the points of its axis) and ``p_{n-2}`` lies on a circle about the last axis
        (axial offset ``h``, radius ``rho``). ``bound`` is an upper bound of ``|p_{n-2} - p_0|``
        over all joint values: the triangle inequality over the segments ``t_1 .. t_{n-2}``,
        where two consecutive segments around joint ``k`` may be taken together with their
        exact maximum ``max_q |u + Rot_z(q) w|^2 = |u|^2 + |w|^2 + 2 (u_z w_z + |u_xy| |w_xy|)``
        (``u = R_k^T t_k``, ``w = t_{k+1}``), the best split chosen by dynamic programming.
        """
        fixed = self._fixed.double().cpu()
        n = self.dof
        t = fixed[:, :3, 3]  # (DOF + 1, 3)
        best = [0.0, 0.0]  # best[i]: bound over the segments t_1 .. t_{i - 1}
        for i in range(1, n - 1):  # add segment t_i
            single = best[-1] + float(t[i].norm())
            if i >= 2:
                u, w = fixed[i - 1, :3, :3].T @ t[i - 1], t[i]
                pair2 = (
                    u.dot(u) + w.dot(w) + 2 * (u[2] * w[2] + u[:2].norm() * w[:2].norm())
                ).clamp_min(0)
                single = min(single, best[-2] + float(pair2.sqrt()))
            best.append(single)
        v = fixed[n - 1, :3, :3].T @ t[n - 1]  # p_{n-2} - p_{n-1} in the last joint's frame
        return best[-1], float(v[2]), float(v[:2].norm()), float(t[n].norm())

    def _provably_unreachable(
        self, mats: torch.Tensor, position_tolerance: float, rotation_tolerance: float
    ) -> torch.Tensor:
        """``(N,)`` bool: end-effector poses ``(N, 4, 4)`` that no joint vector (even ignoring
        the joint limits) reaches within the tolerances; an exact necessary condition, no IK.

        Rejects a pose when the nearest point of the circle on which ``p_{n-2}`` must lie is
        farther from ``p_0`` than ``bound`` (:meth:`_wrist_constants`) plus a margin for the
        tolerances: a pose within ``position_tolerance`` and ``rotation_tolerance`` moves that
        circle by at most ``ptol + rtol (tcp_offset + |h| + rho)``.
        """
        origin = self._fixed[0, :3, 3]
        far = (mats[:, :3, 3] - origin).norm(dim=-1) > self.max_reach + position_tolerance
        if self._wrist is None:
            return far
        bound, h, rho, offset = self._wrist
        last = self._fixed[-1]  # (4, 4): TCP in the last joint's frame
        rot = mats[:, :3, :3] @ last[:3, :3].T  # (N, 3, 3) the last joint's frame
        p = mats[:, :3, 3] - rot @ last[:3, 3]  # (N, 3) its origin
        axis = rot[..., 2]  # (N, 3)
        w = origin - (p - h * axis)  # (N, 3) from the circle's centre to p_0
        along = (w * axis).sum(-1)
        radial = (w - along[:, None] * axis).norm(dim=-1)
        nearest = torch.hypot(along, radial - rho)  # (N,) p_0 to the circle
        eps = 1e-6 if mats.dtype == torch.float64 else 1e-4
        margin = position_tolerance + rotation_tolerance * (offset + abs(h) + rho) + eps
        return far | (nearest > bound + margin)

    @classmethod
    def panda(
        cls, *, dtype: torch.dtype = torch.float64, device: torch.device | str | None = None
    ) -> SerialArm:
        """The shipped Franka Emika Panda, base ``panda_link0`` to ``panda_hand_tcp``."""
        return cls(asset_path("panda/panda.urdf"), "panda_hand_tcp", dtype=dtype, device=device)

    @classmethod
    def human_arm(
        cls,
        *,
        height: float = 1.75,
        dtype: torch.dtype = torch.float64,
        device: torch.device | str | None = None,
    ) -> SerialArm:
        """The anthropometric human right arm (:func:`human_arm_urdf`), ``body`` to ``palm``."""
        return cls(human_arm_urdf(height=height), "palm", dtype=dtype, device=device)

    @property
    def dof(self) -> int:
        """The number of movable joints."""
        return len(self._kinds)

    @property
    def first_joint_transform(self) -> torch.Tensor:
        """``(4, 4)`` the fixed transform from the root link to the first joint's frame (its
        translation is the first joint's origin: a human arm's shoulder,
        :func:`human_arm_urdf`)."""
        return self._first_joint

    def _check_q(self, q: torch.Tensor) -> torch.Tensor:
        q = check_tensor("q", q)
        check_shape("q", q, (self.dof,), f"(..., DOF={self.dof})")
        return q.to(dtype=self.dtype, device=self.device)

    def _frames(self, q: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Joint frames ``(..., DOF, 3, 4)`` (the top rows of each joint's frame before its
        motion; the joint moves about / along its ``z`` column) and the end-effector pose
        ``(..., 3, 4)``."""
        batch = q.shape[:-1]
        c, s = torch.cos(q), torch.sin(q)
        frames = []
        t = self._fixed[0, :3].expand(*batch, 3, 4)
        for i, revolute in enumerate(self._kinds):  # DOF (~7) steps along the chain
            frames.append(t)
            col = t.unbind(-1)
            if revolute:  # T @ Rot_z(q): x' = c x + s y, y' = -s x + c y
                ci, si = c[..., i, None], s[..., i, None]
                moved = (ci * col[0] + si * col[1], ci * col[1] - si * col[0], col[2], col[3])
            else:  # T @ Trans_z(q)
                moved = (col[0], col[1], col[2], col[3] + q[..., i, None] * col[2])
            # (..., 3, 4) @ F_{i+1}, column by column over F's nonzero entries (mostly 0 / +-1
            # after folding: a few adds, much cheaper than a GEMM with K = N = 4 on CPU)
            out = []
            for terms in self._terms[i]:
                acc = torch.zeros_like(moved[0]) if not terms else None
                for k, coef in terms:
                    if acc is None:
                        acc = moved[k] if coef == 1.0 else moved[k] * coef
                    elif coef == 1.0:
                        acc = acc + moved[k]
                    elif coef == -1.0:
                        acc = acc - moved[k]
                    else:
                        acc = acc + moved[k] * coef
                out.append(acc)
            t = torch.stack(out, dim=-1)
        return torch.stack(frames, dim=-3), t

    def _homogeneous(self, top: torch.Tensor) -> torch.Tensor:
        bottom = torch.zeros_like(top[..., :1, :])
        bottom[..., 0, 3] = 1.0
        return torch.cat([top, bottom], dim=-2)

    def forward(self, q: torch.Tensor) -> torch.Tensor:
        """End-effector poses ``(..., 4, 4)`` in the base frame for joints ``q (..., DOF)``."""
        return self._homogeneous(self._frames(self._check_q(q))[1])

    def forward_and_jacobian(self, q: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Poses ``(..., 4, 4)`` and geometric Jacobians ``(..., 6, DOF)`` (rows: linear
        velocity of the end-effector origin, then angular velocity, both in the base frame)."""
        q = self._check_q(q)
        frames, end = self._frames(q)
        z = frames[..., :3, 2]  # (..., DOF, 3) joint axes in the base frame
        p = frames[..., :3, 3]  # (..., DOF, 3) joint origins
        lever = end[..., None, :3, 3] - p
        rev = self._revolute.unsqueeze(-1)
        lin = torch.where(rev, torch.linalg.cross(z, lever, dim=-1), z)
        ang = torch.where(rev, z, torch.zeros_like(z))
        return self._homogeneous(end), torch.cat([lin, ang], dim=-1).transpose(-1, -2)

    def jacobian(self, q: torch.Tensor) -> torch.Tensor:
        """Geometric Jacobians ``(..., 6, DOF)``; see :meth:`forward_and_jacobian`."""
        return self.forward_and_jacobian(q)[1]

    def inverse(
        self,
        targets: torch.Tensor,
        *,
        position_only: bool = False,
        restarts: int = 8,
        iterations: int = 30,
        damping: float = 0.02,
        position_tolerance: float = 1e-4,
        rotation_tolerance: float = 1e-3,
        initial: torch.Tensor | None = None,
        lower: torch.Tensor | None = None,
        upper: torch.Tensor | None = None,
        seed: int = 0,
    ) -> IKResult:
        """Batched inverse kinematics by damped least squares with restarts.

        Each iteration solves ``dq = J^T (J J^T + lambda^2 I)^-1 e`` (Wampler 1986;
        Buss 2004, "Introduction to inverse kinematics with Jacobian transpose, pseudoinverse
        and damped least squares methods"), with ``e`` the position error and the
        orientation error ``1/2 sum_k r_k x r*_k`` over the columns of the current and target
        rotations (Luh, Walker, Paul 1980), a step of at most 0.5 rad, and projection onto
        the joint limits (joints at a limit pushed outward are frozen for the step). A row
        stops when it converges or stalls (error down by less than 1 % in 5 iterations).
        Starts: a table of 4096 scrambled-Sobol joint vectors (seeded, cached) is mapped
        through forward kinematics once; each target starts from the table entries whose
        poses are nearest to it. Round 1 runs every target from its nearest entry (or
        ``initial``); round 2 runs the unsolved ones from their next ``restarts - 1``
        entries, nearest first, in stages (the next 2 starts at once, then the rest at once
        for the targets still unsolved); a target leaves a stage as soon as one of its
        starts converges, and a converged start is preferred to any unconverged one. A
        target's result does not depend on the other targets in the batch.

        Args:
            targets: ``(..., 4, 4)`` or ``(..., 7)`` poses, or ``(..., 3)`` positions with
                ``position_only=True``.
            position_only: ignore the orientation.
            restarts: number of starts per target (>= 1).
            iterations: DLS iterations per start (at most).
            damping: ``lambda``.
            position_tolerance: success threshold on the position error (m).
            rotation_tolerance: success threshold on the rotation error (rad).
            initial: ``(DOF,)`` or ``(..., DOF)`` first start (default: the nearest table entry).
            lower, upper: ``(DOF,)`` joint limits to use instead of the URDF's.
            seed: seed of the table of starts.

        Returns:
            :class:`IKResult` with batch shape ``(...)``.

        Example:
            >>> arm = SerialArm.panda()
            >>> q = torch.tensor([0.1, -0.3, 0.2, -2.0, 0.1, 1.8, 0.5], dtype=torch.float64)
            >>> bool(arm.inverse(arm.forward(q)).success)
            True
        """
        if not isinstance(restarts, int) or restarts < 1:
            raise ModelError(f"expected restarts to be a positive int, got {restarts!r}")
        targets = check_tensor("targets", targets).to(dtype=self.dtype, device=self.device)
        if position_only:
            check_shape("targets", targets, (3,), "(..., 3) positions")
            batch = targets.shape[:-1]
            tgt = targets.reshape(-1, 3)
            t_pos, t_rot = tgt, None
        else:
            mats = _as_matrices("targets", targets)
            batch = mats.shape[:-2]
            mats = mats.reshape(-1, 4, 4)
            t_pos, t_rot = mats[:, :3, 3], mats[:, :3, :3]
        n = t_pos.shape[0]
        lo = self.lower if lower is None else lower.to(dtype=self.dtype, device=self.device)
        hi = self.upper if upper is None else upper.to(dtype=self.dtype, device=self.device)
        start0 = None
        if initial is not None:
            start0 = self._check_q(initial).expand(*batch, self.dof).reshape(n, self.dof)
        tol = (position_tolerance, rotation_tolerance)
        seeds = self._nearest_seeds(t_pos, t_rot, lo, hi, restarts, int(seed))  # (n, R, DOF)
        first = seeds[:, 0] if initial is None else start0
        # Round 1: every target from its first start.
        best_q, best_p, best_r = self._dls(t_pos, t_rot, first, lo, hi, iterations, damping, tol)
        solved = (best_p <= position_tolerance) & (best_r <= rotation_tolerance)
        # Round 2: the unsolved targets from their other starts, nearest first, in stages
        # of _RESTART_STAGES starts at once (n_todo * K rows; a target leaves a stage as soon
        # as one of its starts converges, and later stages only run the still unsolved ones).
        cols = list(range(1 if initial is None else 0, restarts))
        stages = []
        for size in _RESTART_STAGES:
            stages.append(cols[:size])
            cols = cols[size:]
        for stage in [st for st in [*stages, cols] if st]:
            todo = torch.nonzero(~solved).squeeze(-1)
            if not todo.numel():
                break
            k = len(stage)
            q0 = seeds[todo][:, stage].reshape(-1, self.dof)
            rep = todo.repeat_interleave(k)
            q, perr, rerr = self._dls(
                t_pos[rep],
                None if t_rot is None else t_rot[rep],
                q0,
                lo,
                hi,
                iterations,
                damping,
                tol,
                groups=torch.arange(todo.numel(), device=self.device).repeat_interleave(k),
            )
            # A converged start beats any other; then the smaller scaled error.
            score = (perr / position_tolerance + rerr / rotation_tolerance).reshape(-1, k)
            miss = (perr > position_tolerance) | (rerr > rotation_tolerance)
            score = score + 1e6 * miss.reshape(-1, k)
            pick = score.argmin(-1)  # (n_todo,) best start of each target
            rows = torch.arange(todo.numel(), device=self.device) * k + pick
            old = best_p[todo] / position_tolerance + best_r[todo] / rotation_tolerance + 1e6
            better = score.gather(-1, pick[:, None]).squeeze(-1) < old
            idx, rows = todo[better], rows[better]
            best_q[idx], best_p[idx], best_r[idx] = q[rows], perr[rows], rerr[rows]
            solved = (best_p <= position_tolerance) & (best_r <= rotation_tolerance)
        return IKResult(
            joints=best_q.reshape(*batch, self.dof),
            position_error=best_p.reshape(batch),
            rotation_error=best_r.reshape(batch),
            success=solved.reshape(batch),
        )

    def _seed_table(
        self, lo: torch.Tensor, hi: torch.Tensor, seed: int
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """A cached table of ``M`` scrambled-Sobol joint vectors in the limits and their poses
        ``(M, 3, 4)``."""
        key = (tuple(lo.tolist()), tuple(hi.tolist()), seed)
        cache = self.__dict__.setdefault("_tables", {})
        if key not in cache:
            box_lo = torch.where(torch.isfinite(lo), lo, torch.full_like(lo, -math.pi))
            box_hi = torch.where(torch.isfinite(hi), hi, torch.full_like(hi, math.pi))
            sobol = torch.quasirandom.SobolEngine(self.dof, scramble=True, seed=seed)
            u = sobol.draw(_SEED_TABLE_SIZE, dtype=self.dtype).to(self.device)
            q = box_lo + (box_hi - box_lo) * u
            cache[key] = (q, self._frames(q)[1])
        return cache[key]

    def _nearest_seeds(
        self,
        t_pos: torch.Tensor,
        t_rot: torch.Tensor | None,
        lo: torch.Tensor,
        hi: torch.Tensor,
        k: int,
        seed: int,
    ) -> torch.Tensor:
        """``(n, k, DOF)`` starts: the table entries whose poses are nearest each target
        (distance ``|dp| + 0.3 m * |dR|_F``), nearest first."""
        table_q, table_pose = self._seed_table(lo, hi, seed)
        k = min(k, table_q.shape[0])
        # Float64 tables are searched in float32 for k + 8 candidates, which are then ranked
        # by their exact distances: float32 rounding (~1e-6) only matters between candidates.
        coarse = table_pose.dtype == torch.float64
        m = min(k + 8, table_q.shape[0]) if coarse else k
        table_pose_c = table_pose.float() if coarse else table_pose
        # |t - p|^2 = [t, 1, |t|^2] . [-2 p, |p|^2, 1] and 6 - 2 tr(R_t^T R) = [R_t, 1] . [-2 R, 6]:
        # one small GEMM each per block of targets.
        pos = table_pose_c[:, :, 3]  # (M, 3)
        table_pos = torch.cat(
            [-2 * pos, pos.square().sum(-1, keepdim=True), torch.ones_like(pos[:, :1])], -1
        ).T  # (5, M)
        t_pos_c = t_pos.to(pos.dtype)
        t_pos_c = torch.cat(
            [t_pos_c, torch.ones_like(t_pos_c[:, :1]), t_pos_c.square().sum(-1, keepdim=True)], -1
        )
        if t_rot is not None:
            rot = table_pose_c[:, :, :3].reshape(-1, 9)
            table_rot = torch.cat([-2 * rot, torch.full_like(rot[:, :1], 6.0)], -1).T  # (10, M)
            t_rot_c = t_rot.reshape(-1, 9).to(pos.dtype)
            t_rot_c = torch.cat([t_rot_c, torch.ones_like(t_rot_c[:, :1])], -1)  # (n, 10)
        idx = torch.empty(t_pos.shape[0], m, dtype=torch.long, device=t_pos.device)
        # In blocks of targets so that the (block, M) distances stay in cache; in place.
        for start in range(0, t_pos.shape[0], _NEAREST_BLOCK):
            stop = start + _NEAREST_BLOCK
            dist = (t_pos_c[start:stop] @ table_pos).clamp_min_(0).sqrt_()  # (block, M)
            if t_rot is not None:
                rot_dist = (t_rot_c[start:stop] @ table_rot).clamp_min_(0).sqrt_()
                dist.add_(rot_dist, alpha=0.3)
            idx[start:stop] = dist.topk(m, dim=-1, largest=False).indices
        if coarse:
            cand = table_pose[idx]  # (n, m, 3, 4)
            dist = (cand[..., 3] - t_pos[:, None]).norm(dim=-1)  # (n, m)
            if t_rot is not None:
                tr = (cand[..., :3] * t_rot[:, None]).sum((-2, -1))
                dist = dist + 0.3 * (6 - 2 * tr).clamp_min(0).sqrt()
            idx = idx.gather(-1, dist.topk(k, dim=-1, largest=False).indices)
        return table_q[idx]

    def _dls(
        self,
        t_pos: torch.Tensor,
        t_rot: torch.Tensor | None,
        q: torch.Tensor,
        lo: torch.Tensor,
        hi: torch.Tensor,
        iterations: int,
        damping: float,
        tol: tuple[float, float],
        groups: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Damped least squares from ``q (n, DOF)``; returns final joints and errors ``(n,)``.

        A row leaves the active set when it converges, or when it stalls (its error fell by
        less than 1 % over the last 5 iterations: a joint limit or an unreachable target),
        so the work shrinks as targets are settled. With ``groups (n,)`` (ids of the target
        of each row, several starts per target), all rows of a target leave as soon as one of
        them converges.
        """
        ptol, rtol = tol
        n = q.shape[0]
        q = q.clone()
        out_q, out_p, out_r = q.clone(), q.new_full((n,), math.inf), q.new_zeros(n)
        active = torch.arange(n, device=q.device)
        rows = 3 if t_rot is None else 6
        eye = torch.eye(rows, dtype=q.dtype, device=q.device) * damping**2
        tp, tr = t_pos, t_rot
        checkpoint = q.new_full((n,), math.inf)
        for it in range(iterations + 1):
            frames, end = self._frames(q)
            e_pos = tp - end[:, :, 3]
            perr = e_pos.norm(dim=-1)
            if tr is None:
                rerr = torch.zeros_like(perr)
                e = e_pos
            else:
                rot = end[:, :, :3]
                rerr = _rotation_angle(tr, rot)
                e = torch.cat([e_pos, 0.5 * torch.linalg.cross(rot, tr, dim=-2).sum(-1)], dim=-1)
            done = (perr <= ptol) & (rerr <= rtol)
            if groups is not None and done.any():
                solved = torch.zeros(int(groups.max()) + 1, dtype=torch.bool, device=q.device)
                done = done | solved.index_fill_(0, groups[done], True)[groups]
            if it == iterations:
                done = torch.ones_like(done)
            elif it % 5 == 0 and it > 0:
                score = perr / ptol + rerr / rtol
                done = done | (score > 0.99 * checkpoint)
                checkpoint = score
            if done.any():
                idx = active[done]
                out_q[idx], out_p[idx], out_r[idx] = q[done], perr[done], rerr[done]
                keep = ~done
                active, q, tp, e = active[keep], q[keep], tp[keep], e[keep]
                groups = None if groups is None else groups[keep]
                frames, end, checkpoint = frames[keep], end[keep], checkpoint[keep]
                tr = None if tr is None else tr[keep]
                if active.numel() == 0:
                    break
            z = frames[..., 2]  # (n, DOF, 3) joint axes
            lin = torch.linalg.cross(z, end[:, None, :, 3] - frames[..., 3], dim=-1)
            ang = z
            if not all(self._kinds):  # prismatic joints: linear part z, no angular part
                rev = self._revolute.unsqueeze(-1)
                lin, ang = torch.where(rev, lin, z), torch.where(rev, z, 0.0)
            jac = lin if tr is None else torch.cat([lin, ang], dim=-1)
            jac = jac.transpose(-1, -2)  # (n, rows, DOF)
            dq = _dls_step(jac, e, eye)
            # Joints at a limit that the step pushes outward are frozen for this step (their
            # Jacobian columns zeroed) and the step recomputed (Baerlocher & Boulic 2004).
            blocked = ((q <= lo) & (dq < 0)) | ((q >= hi) & (dq > 0))
            hit = torch.nonzero(blocked.any(-1)).squeeze(-1)
            if hit.numel():
                jac_hit = jac[hit] * (~blocked[hit]).unsqueeze(-2)
                dq[hit] = _dls_step(jac_hit, e[hit], eye)
            step = dq.abs().amax(-1, keepdim=True).clamp_min(0.5) / 0.5
            q = torch.minimum(torch.maximum(q + dq / step, lo), hi)
        return out_q, out_p, out_r


# ------------------------------------------------------------------- reach checks
@dataclass(frozen=True)
class ReachResult:
    """Result of :func:`reach_check` for ``N`` poses.

    Attributes:
        reachable: ``(N,)`` bool, an IK solution within the joint limits reaches the pose.
        joints: ``(N, DOF)`` the solutions (the best attempt where unreachable; the
            mid-range for poses rejected by the pre-check of :func:`reach_check`).
        error: ``(N,)`` position error of the best attempt (m).
        rotation_error: ``(N,)`` rotation error of the best attempt (rad).
    """

    reachable: torch.Tensor
    joints: torch.Tensor
    error: torch.Tensor
    rotation_error: torch.Tensor


def reach_check(
    poses: torch.Tensor,
    *,
    arm: SerialArm | None = None,
    restarts: int = 8,
    iterations: int = 30,
    position_tolerance: float = 1e-3,
    rotation_tolerance: float = 1e-2,
    seed: int = 0,
) -> ReachResult:
    """Which end-effector poses the arm can reach within its joint limits (batched IK).

    Poses that no joint vector reaches within the tolerances, by an exact necessary condition
    (the wrist pre-check: for an all-revolute chain the last joint's origin is fixed by the
    pose and the one before lies on a circle around the last axis, which must come within the
    largest possible distance from the first joint, plus a margin for the tolerances; see
    ``SerialArm._provably_unreachable``), are rejected without IK (their ``joints`` are the
    mid-range and ``error`` its position error); the others run :meth:`SerialArm.inverse`
    with restarts. The pre-check drops no pose that the IK reaches.

    Args:
        poses: ``(N, 4, 4)`` or ``(N, 7)`` target poses of the end effector in the base frame.
        arm: the arm (default: the shipped Panda, float64).
        restarts, iterations: IK effort per pose.
        position_tolerance: reach tolerance on the position (m, default 1 mm).
        rotation_tolerance: reach tolerance on the orientation (rad, default 0.01).
        seed: seed of the IK restarts.

    Returns:
        :class:`ReachResult`.

    Example:
        >>> arm = SerialArm.panda()
        >>> far = torch.eye(4, dtype=torch.float64).clone(); far[0, 3] = 3.0
        >>> reach_check(torch.stack([arm.forward(torch.zeros(7, dtype=torch.float64)), far]),
        ...             arm=arm).reachable.tolist()
        [True, False]
    """
    arm = SerialArm.panda() if arm is None else arm
    mats = _as_matrices("poses", poses).to(dtype=arm.dtype, device=arm.device)
    if mats.dim() != 3:
        raise ModelError(
            f"expected poses to have shape (N, 4, 4) or (N, 7), actual shape = {tuple(poses.shape)}"
        )
    if not torch.isfinite(mats).all():
        raise ModelError("poses has non-finite entries")
    n = mats.shape[0]
    within = ~arm._provably_unreachable(mats, position_tolerance, rotation_tolerance)
    joints = ((arm.lower + arm.upper) / 2).nan_to_num(0.0).expand(n, arm.dof).clone()
    err = (mats[:, :3, 3] - arm.forward(joints[:1])[0, :3, 3]).norm(dim=-1)
    rot_err = torch.full((n,), math.pi, dtype=arm.dtype, device=arm.device)
    reachable = torch.zeros(n, dtype=torch.bool, device=arm.device)
    idx = torch.nonzero(within).squeeze(-1)
    if idx.numel():
        res = arm.inverse(
            mats[idx],
            restarts=restarts,
            iterations=iterations,
            position_tolerance=position_tolerance,
            rotation_tolerance=rotation_tolerance,
            seed=seed,
        )
        joints[idx], err[idx], rot_err[idx], reachable[idx] = (
            res.joints,
            res.position_error,
            res.rotation_error,
            res.success,
        )
    return ReachResult(reachable=reachable, joints=joints, error=err, rotation_error=rot_err)
