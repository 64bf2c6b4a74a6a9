"""Graph captures and Python's garbage collector (:func:`magwarp._streams.gc_paused`): a ``torch.cuda.CUDAGraph``
dropped earlier in a reference cycle must not be destroyed while a capture is open (CUDA invalidates the capture:
"operation failed due to a previous error during capture")."""

from __future__ import annotations

import gc

import numpy as np
import pytest
import torch
import warp as wp

from magwarp._streams import gc_paused


class _Cycle:
    """Garbage only the cyclic collector frees; ``freed`` records when."""

    freed: list[str] = []

    def __init__(self, name: str, payload=None):
        self.name, self.payload, self.me = name, payload, self

    def __del__(self):
        _Cycle.freed.append(self.name)


def test_gc_paused_collects_first_and_keeps_the_collector_off_inside():
    _Cycle.freed.clear()
    _Cycle("before")
    assert gc.isenabled()
    with gc_paused():
        assert _Cycle.freed == ["before"]  # collected on the way in
        assert not gc.isenabled()
        _Cycle("inside")
        for _ in range(20000):  # far past generation 0's threshold
            [object()]
        assert _Cycle.freed == ["before"]
    assert gc.isenabled()
    gc.collect()
    assert _Cycle.freed == ["before", "inside"]


def test_gc_paused_restores_the_collector_on_errors_and_leaves_it_off_if_it_was():
    with pytest.raises(KeyError):
        with gc_paused():
            raise KeyError("x")
    assert gc.isenabled()
    gc.disable()
    try:
        with gc_paused():
            assert not gc.isenabled()
        assert not gc.isenabled()
    finally:
        gc.enable()


def test_nested_gc_paused_collects_nothing():
    """A block inside another (a capture inside an open one) must not collect: only the outer one does."""
    _Cycle.freed.clear()
    with gc_paused():
        _Cycle("between")
        with gc_paused():
            assert _Cycle.freed == [] and not gc.isenabled()
        assert not gc.isenabled()
    assert gc.isenabled()
    with gc_paused():
        assert _Cycle.freed == ["between"]


def test_gc_paused_off_for_the_cpu_collects_nothing():
    _Cycle.freed.clear()
    _Cycle("cpu")
    with gc_paused(cuda=False):
        assert gc.isenabled() and _Cycle.freed == []
    gc.collect()
    assert _Cycle.freed == ["cpu"]


def _dropped_cuda_graphs(n: int = 4) -> None:
    """``n`` captured torch CUDA graphs, each left in a reference cycle (garbage the cyclic collector frees)."""
    x = torch.zeros(8, device="cuda:0")
    for i in range(n):
        g = torch.cuda.CUDAGraph()
        side = torch.cuda.Stream()
        side.wait_stream(torch.cuda.current_stream())
        with torch.cuda.stream(side):
            x.add_(1.0)
        torch.cuda.current_stream().wait_stream(side)
        with torch.cuda.graph(g):
            x.add_(1.0)
        _Cycle(f"graph{i}", g)


def _collect_inside(seen: list):
    """What the collector does by itself at any allocation: here, inside the capture, on purpose (``seen``: what was
    freed before)."""
    seen.extend(_Cycle.freed)
    gc.enable()
    gc.set_threshold(1, 1, 1)
    for _ in range(100):
        [object()]


@pytest.mark.skipif(not (torch.cuda.is_available() and wp.is_cuda_available()), reason="needs a CUDA GPU")
@pytest.mark.parametrize("what", ["simulator", "torch_graph"])
def test_captures_survive_dropped_cuda_graphs(what):
    """Garbage holding captured torch graphs is left behind (the collector off, so nothing frees it early), then a
    capture starts and the collector runs inside it: a simulator's step (a Warp capture) and a torch capture with
    Warp inside (:func:`record_cuda_graph`, the envs' step graphs) record, replay and stay finite."""
    from magwarp.envs.step_graph import record_cuda_graph
    from magwarp.layout import Layout
    from magwarp.sim import Simulator

    thresholds = gc.get_threshold()
    sim = Simulator(Layout(np.ones((3, 3))), num_movers=3, num_worlds=4, device="cuda:0")
    sim.step(5)  # loads the step's modules (no compiling inside a capture)
    try:
        gc.collect()
        gc.disable()
        _Cycle.freed.clear()
        _dropped_cuda_graphs()
        seen = []
        if what == "simulator":
            graph = sim._capture(lambda: (_collect_inside(seen), sim._launch_step(5)))
            wp.capture_launch(graph)
            out = sim.pos
        else:
            x = torch.ones(16, device="cuda:0")
            recorded = record_cuda_graph(lambda: (_collect_inside(seen), sim._launch_step(5), x * 2.0)[-1],
                                         torch.device("cuda:0"))
            recorded.graph.replay()
            out = torch.cat([recorded.outputs, sim.pos.flatten()])
            assert torch.equal(recorded.outputs, torch.full((16,), 2.0, device="cuda:0"))
        torch.cuda.synchronize()
        assert torch.isfinite(out).all()
        assert sorted(seen) == [f"graph{i}" for i in range(4)]  # freed on the capture's way in, none inside
    finally:
        gc.set_threshold(*thresholds)
        gc.enable()
        gc.collect()
