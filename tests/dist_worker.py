"""Run by torchrun from tests/test_distributed.py (not a test module itself): one rank of a small gloo job.

    python -m torch.distributed.run --standalone --nproc-per-node 2 tests/dist_worker.py grad OUT
    python -m torch.distributed.run --standalone --nproc-per-node 2 tests/dist_worker.py ppo|sac OUT TRAINING-OPTIONS...

``grad``: every rank takes its own batch; the all-reduced gradient is compared with the single-process gradient on
the union of the batches (written to OUT/grad_rank<r>.json). ``ppo``/``sac``: the training module runs with the
options given, and every rank writes the learned tensors it holds at the start and the end to OUT/rank<r>.pt.
``hang``: rank 1 stops answering; rank 0's next collective fails after the 3 s timeout.
"""

from __future__ import annotations

import copy
import json
import sys
from pathlib import Path

import torch


def loss_fn(agent, batch: dict[str, torch.Tensor]) -> torch.Tensor:
    """A mean over the batch (value regression, policy gradient, entropy): the union's loss is the ranks' mean."""
    dist_ = agent.dist(batch["obs"])
    pg = -(dist_.log_prob(batch["act"]).sum(-1) * batch["adv"]).mean()
    v = (agent.value(batch["obs"]) - batch["ret"]).square().mean()
    return pg + 0.5 * v - 0.01 * dist_.entropy().sum(-1).mean()


def grad(out: Path) -> None:
    from magwarp.training import distributed as dist
    from magwarp.training.ppo import Agent

    dist.setup("cpu", 60)
    rank, world = dist.rank(), dist.world_size()
    torch.manual_seed(0)
    agent = Agent(6, 2, [32, 32], -0.5)
    reference = copy.deepcopy(agent)
    batches = []
    for r in range(world):  # every rank's batch (different sizes would weigh the mean differently: equal here)
        g = torch.Generator().manual_seed(100 + r)
        batches.append({"obs": torch.randn(64, 6, generator=g),
                        "act": torch.randn(64, 2, generator=g),
                        "adv": torch.randn(64, generator=g),
                        "ret": torch.randn(64, generator=g)})
    loss_fn(agent, batches[rank]).backward()
    dist.average_gradients(agent.parameters())
    union = {k: torch.cat([b[k] for b in batches]) for k in batches[0]}
    loss_fn(reference, union).backward()
    diff = max(float((p.grad - q.grad).abs().max()) for p, q in zip(agent.parameters(), reference.parameters()))
    scale = max(float(q.grad.abs().max()) for q in reference.parameters())
    dist.check_in_sync(agent.parameters())  # the same weights on every rank: passes
    try:  # rank 1 off by 1e-6 in one tensor: every rank raises
        dist.check_in_sync([p + (torch.finfo(p.dtype).eps * 8 if rank == 1 and i == 3 else 0)
                            for i, p in enumerate(agent.parameters())])
        diverged = ""
    except RuntimeError as e:
        diverged = str(e)
    (out / f"grad_rank{rank}.json").write_text(json.dumps({"max_diff": diff, "max_grad": scale, "world": world,
                                                           "diverged": diverged}))
    dist.shutdown()


def train(algo: str, out: Path, argv: list[str]) -> None:
    from magwarp.training import distributed as dist
    from magwarp.training import ppo, sac_her

    held, initial = [], []
    if algo == "ppo":
        class Agent(ppo.Agent):
            def __init__(self, *a, **k):
                super().__init__(*a, **k)
                held.append(lambda: [*self.parameters()])
                initial.append([t.detach().clone() for t in self.parameters()])

        ppo.Agent = Agent
        module = ppo
    else:
        class Learner(sac_her.SacLearner):
            def __init__(self, *a, **k):
                super().__init__(*a, **k)
                held.append(self.tensors)
                initial.append([t.detach().clone() for t in self.tensors()])

        sac_her.SacLearner = Learner
        module = sac_her
    rank = {}
    original = dist.shutdown

    def shutdown(wait: bool = True):  # the rank, read before the group is gone
        rank["r"] = dist.rank()
        original(wait)

    dist.shutdown = shutdown
    summary = module.train(module.parse_args(argv))
    torch.save({"tensors": [t.detach().clone() for t in held[0]()], "initial": initial[0], "summary": summary},
               out / f"rank{rank['r']}.pt")


def hang() -> None:
    import time

    from magwarp.training import distributed as dist

    dist.setup("cpu", 3)
    dist.all_reduce_sum_(torch.ones(1))  # both ranks are up
    if dist.rank() == 1:
        time.sleep(600)
    dist.all_reduce_sum_(torch.ones(1))


if __name__ == "__main__":
    mode, out = sys.argv[1], Path(sys.argv[2])
    if mode == "grad":
        grad(out)
    elif mode == "hang":
        hang()
    else:
        train(mode, out, sys.argv[3:])
    from magwarp.training import distributed

    distributed.leave(0)
