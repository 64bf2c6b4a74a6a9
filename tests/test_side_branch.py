"""magwarp._streams.SideBranch: work forked onto a second CUDA stream (a parallel branch of a captured graph) and
joined, with the same results as in order; a no-op on the CPU."""

from __future__ import annotations

import pytest
import torch
import warp as wp

from magwarp._streams import SideBranch

wp.init()
CUDA = torch.cuda.is_available() and wp.is_cuda_available()


@wp.kernel
def _scale(x: wp.array(dtype=float), k: float, y: wp.array(dtype=float)):
    i = wp.tid()
    y[i] = k * x[i]


def _step(branch: SideBranch, x: torch.Tensor, a: torch.Tensor, b: torch.Tensor, gen: torch.Generator):
    """b = 3 x on the branch (Warp) and a random draw beside it, a = 2 x on the current stream (torch); joined."""
    with branch.fork():
        wp.launch(_scale, dim=x.shape[0], inputs=[wp.from_torch(x), 3.0], outputs=[wp.from_torch(b)],
                  device=str(x.device))
        noise = torch.rand(x.shape, generator=gen, device=x.device)
        b.add_(noise)
    torch.mul(x, 2.0, out=a)
    branch.join()


def test_side_branch_is_a_no_op_on_the_cpu():
    branch = SideBranch("cpu")
    assert not branch.enabled
    x = torch.arange(5, dtype=torch.float32)
    a, b = torch.zeros(5), torch.zeros(5)
    gen = torch.Generator().manual_seed(0)
    _step(branch, x, a, b, gen)
    noise = torch.rand(5, generator=torch.Generator().manual_seed(0))
    assert torch.equal(a, 2 * x) and torch.equal(b, 3 * x + noise)


@pytest.mark.skipif(not CUDA, reason="needs a CUDA GPU")
def test_side_branch_in_a_captured_graph_gives_the_in_order_results():
    from magwarp.envs.step_graph import record_cuda_graph

    dev = torch.device("cuda:0")
    x = torch.randn(100_000, device=dev)
    outs = {}
    for enabled in (False, True):
        branch = SideBranch(dev, enabled)
        assert branch.enabled is enabled
        a, b = torch.zeros_like(x), torch.zeros_like(x)
        gen = torch.Generator(device=dev).manual_seed(4)
        _step(branch, x, a, b, gen)  # eagerly first (loads the kernel)
        rec = record_cuda_graph(lambda: _step(branch, x, a, b, gen), dev, generators=(gen,))
        rows = [(a.clone(), b.clone())]
        for _ in range(3):
            rec.graph.replay()
            rows.append((a.clone(), b.clone()))
        torch.cuda.synchronize()
        outs[enabled] = rows
    for (a0, b0), (a1, b1) in zip(outs[False], outs[True]):
        assert torch.equal(a0, a1) and torch.equal(b0, b1)
    assert not torch.equal(outs[True][1][1], outs[True][2][1])  # every replay draws new numbers
