"""Where a MagBot mechanism's joints live in ``qpos``: shared by the platform and gripper joint maps.

A mechanism ``i`` with prefix ``pre`` has 1-dof joints ``{pre}{i}_{name}`` and a root body ``{pre}{i}_base``, and is
carried by movers ``mover_{2i}`` and ``mover_{2i+1}``. The index tensors are kept per device (copied once), so
reading or writing a batch of states inside an env step makes no host-to-device copy.
"""

from __future__ import annotations

import mujoco
import numpy as np
import torch

from magwarp.layout import LayoutError

__all__ = ["MechanismJoints"]


class MechanismJoints:
    """``qpos_adr`` ``[N, J]``, ``mover_qpos_adr`` ``[N, 2]`` (free-joint starts of movers A, B) and ``base_pos0``
    ``[N, 3]`` (model position of each root body) of the ``N`` mechanisms named ``{prefix}{i}_...`` in ``mjm``."""

    def __init__(self, mjm: mujoco.MjModel, prefix: str, joints: tuple[str, ...], label: str):
        def body(name: str) -> int:
            return mujoco.mj_name2id(mjm, mujoco.mjtObj.mjOBJ_BODY, name)

        n = 0
        while body(f"{prefix}{n}_base") >= 0:
            n += 1
        if n == 0:
            raise LayoutError(f"the model has no {label} (no body '{prefix}0_base')")
        self.count = n
        self.joints = joints
        adr = np.zeros((n, len(joints)), dtype=np.int64)
        for i in range(n):
            for j, name in enumerate(joints):
                jid = mujoco.mj_name2id(mjm, mujoco.mjtObj.mjOBJ_JOINT, f"{prefix}{i}_{name}")
                if jid < 0:
                    raise LayoutError(f"{label} {i} has no joint '{prefix}{i}_{name}'")
                adr[i, j] = mjm.jnt_qposadr[jid]
        movers = np.zeros((n, 2), dtype=np.int64)
        for k in range(2 * n):
            bid = body(f"mover_{k}")
            if bid < 0:
                raise LayoutError(f"{label} {k // 2} needs body 'mover_{k}'")
            movers[k // 2, k % 2] = mjm.jnt_qposadr[mjm.body_jntadr[bid]]
        self.qpos_adr = torch.as_tensor(adr)
        self.mover_qpos_adr = torch.as_tensor(movers)
        self.base_pos0 = torch.as_tensor(np.array([mjm.body_pos[body(f"{prefix}{i}_base")] for i in range(n)]))
        self._cache: dict[tuple, torch.Tensor] = {}

    def on(self, name: str, like: torch.Tensor, dtype: torch.dtype | None = None) -> torch.Tensor:
        """Attribute ``name`` on ``like``'s device (and ``dtype``), copied once and then reused."""
        key = (name, like.device, dtype)
        if key not in self._cache:
            t = getattr(self, name)
            self._cache[key] = t.to(like.device) if dtype is None else t.to(like.device, dtype)
        return self._cache[key]

    def gather(self, qpos: torch.Tensor) -> torch.Tensor:
        """The mechanisms' joint values ``[W, N, J]`` from ``qpos`` ``[W, nq]``."""
        return qpos[:, self.on("qpos_adr", qpos)]

    def scatter(self, qpos: torch.Tensor, values: dict[str, torch.Tensor]) -> None:
        """Write ``values[name]`` ``[W, N]`` for every joint name into ``qpos`` ``[W, nq]`` in place."""
        j = self.on("qpos_adr", qpos)
        for k, name in enumerate(self.joints):
            qpos[:, j[:, k]] = values[name]
