"""The one torch + Warp CUDA-graph recorder (:func:`magwarp.envs.step_graph.record_cuda_graph`, used by the push envs'
:class:`~magwarp.envs.step_graph.TaskGraph` and the trajectory env's fused step), on the CPU: torch's and Warp's
capture calls are replaced by stand-ins that log them, so the order of operations, the generator registration, the
stream handling and the failure paths are checked without a GPU (tests/test_graph_step.py and
tests/test_push_step.py -k cuda record real graphs on one)."""

from __future__ import annotations

import contextlib
import re

import pytest
import torch
import warp as wp

from magwarp.envs import step_graph
from magwarp.envs.step_graph import RecordedGraph, TaskGraph, record_cuda_graph


class _Capture:
    """Stand-ins for the torch.cuda and warp calls of a capture, logging each call in ``log``."""

    def __init__(self, monkeypatch, *, can_register: bool = True):
        self.log: list = []
        log = self.log

        class Graph:
            def replay(self):
                log.append("replay")

        if can_register:
            Graph.register_generator_state = lambda self, gen: log.append(("register", gen))

        class Stream:
            def __init__(self, device=None, name="side"):
                self.name = name

            def wait_stream(self, other):
                log.append(("wait", self.name, other.name))

        @contextlib.contextmanager
        def torch_graph(graph, stream=None, capture_error_mode=None):
            log.append(("torch_capture", stream.name, capture_error_mode))
            try:
                yield
            finally:
                log.append("torch_capture_end")

        def scoped(name):
            @contextlib.contextmanager
            def ctx(*args, **kwargs):
                log.append((name, *args, *sorted(kwargs.items())))
                yield
                log.append(f"{name}_exit")
            return ctx

        monkeypatch.setattr(torch.cuda, "CUDAGraph", Graph)
        monkeypatch.setattr(torch.cuda, "Stream", Stream)
        monkeypatch.setattr(torch.cuda, "current_stream", lambda device=None: Stream(name="current"))
        monkeypatch.setattr(torch.cuda, "graph", torch_graph)
        monkeypatch.setattr(wp, "device_from_torch", lambda device: "wdev")
        monkeypatch.setattr(wp, "stream_from_torch", lambda stream: log.append(("wp_stream", stream.name)) or "wstream")
        monkeypatch.setattr(wp, "capture_begin", lambda **kw: log.append(("capture_begin", *sorted(kw.items()))))
        monkeypatch.setattr(wp, "capture_end", lambda **kw: log.append(("capture_end", *sorted(kw.items())))
                            or "warp record")
        monkeypatch.setattr(wp, "ScopedDevice", scoped("device"))
        monkeypatch.setattr(wp, "ScopedStream", scoped("stream"))
        self.recorder = scoped("recorder")


CUDA = torch.device("cuda", 0)  # a device object only: nothing runs on it


def test_records_in_order_and_returns_the_graph_outputs_and_warp_record(monkeypatch):
    cap = _Capture(monkeypatch)
    gens = ("gen0", "gen1")
    rec = record_cuda_graph(lambda: cap.log.append("fn") or {"out": 1}, CUDA, gens, (cap.recorder,))
    assert isinstance(rec, RecordedGraph) and rec.outputs == {"out": 1} and rec.warp_graph == "warp record"
    assert isinstance(rec.graph, torch.cuda.CUDAGraph)
    assert cap.log == [
        ("register", "gen0"), ("register", "gen1"),
        ("wait", "side", "current"),
        ("torch_capture", "side", "thread_local"),
        ("wp_stream", "side"),
        ("capture_begin", ("device", "wdev"), ("external", True), ("force_module_load", False), ("stream", "wstream")),
        ("device", "wdev"), ("stream", "wstream", ("sync_enter", False)), ("recorder", "wstream"),
        "fn",
        "recorder_exit", "stream_exit", "device_exit",
        ("capture_end", ("device", "wdev"), ("stream", "wstream")),
        "torch_capture_end",
        ("wait", "current", "side"),
    ]


def test_a_failing_step_still_ends_both_captures_and_raises(monkeypatch):
    cap = _Capture(monkeypatch)

    def fn():
        raise RuntimeError("operation not permitted when stream is capturing")

    with pytest.raises(RuntimeError, match="not permitted"):
        record_cuda_graph(fn, CUDA)
    assert cap.log[-2:] == [("capture_end", ("device", "wdev"), ("stream", "wstream")), "torch_capture_end"]
    assert ("wait", "current", "side") not in cap.log


def test_a_torch_without_graph_safe_generators_is_refused_before_any_capture(monkeypatch):
    cap = _Capture(monkeypatch, can_register=False)
    message = f"torch {torch.__version__} cannot register generators with a CUDA graph"
    with pytest.raises(RuntimeError, match=re.escape(message)):
        record_cuda_graph(lambda: None, CUDA, generators=("gen",))
    assert cap.log == []
    assert record_cuda_graph(lambda: 3, CUDA).outputs == 3  # no generators: nothing to register


def test_task_graph_replays_what_it_recorded_and_falls_back_to_eager_with_a_warning(monkeypatch):
    cap = _Capture(monkeypatch)
    calls = []
    graph = TaskGraph(lambda: calls.append(1) or torch.ones(2), CUDA, generators=("gen",))
    assert torch.equal(graph(), torch.ones(2)) and len(calls) == 2  # the eager step, then the capture
    assert graph._warp_graph == "warp record" and not graph.failed
    out = graph()
    assert cap.log[-1] == "replay" and len(calls) == 2 and torch.equal(out, torch.ones(2))
    assert out.data_ptr() != graph._out.data_ptr()  # a fresh copy of the graph's output

    failing = TaskGraph(lambda: torch.zeros(1), CUDA)
    monkeypatch.setattr(step_graph, "record_cuda_graph", lambda *a: (_ for _ in ()).throw(RuntimeError("boom")))
    with pytest.warns(RuntimeWarning, match=r"could not be recorded as a CUDA graph \(RuntimeError: boom\); it runs "
                                            r"eagerly"):
        failing()
    assert failing.failed and failing.graph is None


def test_the_trajectory_fused_step_records_physics_then_task_through_it(monkeypatch):
    from types import SimpleNamespace

    from magwarp.envs.trajectory_fused import FusedTrajectoryStep

    cap = _Capture(monkeypatch)
    fused = object.__new__(FusedTrajectoryStep)  # only what _capture reads
    sim = SimpleNamespace(_launch_step=lambda n: cap.log.append(("physics", n)))
    fused.env = SimpleNamespace(sim=sim, num_cycles=40, device=CUDA, sampler=SimpleNamespace(generator="gen"))
    fused._launch_draws = lambda: cap.log.append("draws")
    fused._launch_task = lambda out, slot: cap.log.append(("task", out, slot))
    rec = fused._capture("slot 0 outputs", 0)
    assert isinstance(rec, RecordedGraph) and rec.warp_graph == "warp record"
    assert cap.log[0] == ("register", "gen")
    inside = cap.log.index("stream_exit")
    assert cap.log[inside - 3:inside] == ["draws", ("physics", 40), ("task", "slot 0 outputs", 0)]
    assert cap.log[inside - 4] == ("stream", "wstream", ("sync_enter", False))
