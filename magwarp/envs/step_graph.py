"""The task work of an env step (observations, rewards, terminations, goal resampling, autoreset) as one CUDA graph.

:class:`TaskGraph` records a step function that issues torch operations and Warp kernels on one stream as one
``torch.cuda.CUDAGraph`` and replays it: one launch from Python per step, no host synchronisation, no allocation
inside the graph (torch keeps its tensors in the graph's private memory pool). The first call runs the function eagerly (a real step
that also loads every Warp module and creates every constant the step uses); the capture follows it and executes
nothing. Randomness stays seeded: the env's ``torch.Generator`` is registered with the graph, so each replay draws the
numbers the eager step would draw (Philox offsets advance per replay as they do per eager call).

Warp inside the capture: ``wp.capture_begin(external=True)`` tells Warp that torch's capture is in progress, and
simulation objects issue their kernels into it through a ``recording(stream)`` context (see
:meth:`magwarp.physics.MjwBackend.recording`) instead of replaying graphs of their own.

Why the physics stays a graph of its own (one more launch per step): mujoco-warp's solver loop is a conditional graph
node (``wp.capture_while``), CUDA refuses conditional nodes inside child graphs and a graph launch inside a capture
(NVIDIA/warp#1827), and recording it live would pause and resume torch's capture under a new capture id, which
torch's allocator does not follow. So a push env step on CUDA is: one copy of the action, the physics graph
(:class:`~magwarp.physics.MjwBackend`), this graph; all on one stream, no host sync.

The replay returns fresh tensors (clones of the graph's outputs), so what a caller keeps from one step is not
overwritten by the next. CUDA only; on the CPU the env calls its step function directly.
"""

from __future__ import annotations

import contextlib
import warnings
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import torch
import warp as wp

from magwarp._streams import gc_paused

__all__ = ["RecordedGraph", "TaskGraph", "clone_outputs", "continued_generator", "record_cuda_graph"]


def clone_outputs(out: Any) -> Any:
    """A copy of a nest of tuples, lists and dicts of tensors (other leaves as they are)."""
    if isinstance(out, torch.Tensor):
        return out.clone()
    if isinstance(out, dict):
        return {k: clone_outputs(v) for k, v in out.items()}
    if isinstance(out, (tuple, list)):
        return type(out)(clone_outputs(v) for v in out)
    return out


def continued_generator(old: torch.Generator) -> torch.Generator:
    """A new generator that continues from ``old``'s state (a fresh seed from it where its state cannot be read): a
    CUDA graph capture that failed may leave ``old`` registered with the dead graph, where torch refuses every later
    draw outside a capture."""
    fresh = torch.Generator(device=old.device)
    try:
        fresh.set_state(old.get_state())
    except RuntimeError:
        fresh.manual_seed(int(old.initial_seed()) + 1)
    return fresh


class RecordedGraph(NamedTuple):
    """What :func:`record_cuda_graph` recorded: the torch graph, ``fn``'s outputs (the graph's static tensors) and
    Warp's record of the capture (keep it with the graph: it keeps the modules and arrays the graph launches alive)."""

    graph: torch.cuda.CUDAGraph
    outputs: Any
    warp_graph: Any


def record_cuda_graph(fn: Callable[[], Any], device: torch.device, generators: Sequence[torch.Generator] = (),
                      recorders: Sequence[Callable[[wp.Stream], contextlib.AbstractContextManager]] = ()
                      ) -> RecordedGraph:
    """Record ``fn()`` (torch operations and Warp launches) as one ``torch.cuda.CUDAGraph`` on a side stream of the CUDA
    device ``device`` (CUDA cannot capture torch's legacy default stream); nothing is executed.

    In order: the ``generators`` are registered with the graph (a RuntimeError if this torch cannot); a new torch
    stream waits for the current one; inside ``torch.cuda.graph`` (thread-local capture mode) Warp joins the capture
    (``wp.capture_begin(external=True)``, no module loading: ``fn`` must have run eagerly before), the stream is
    Warp's current stream (no wait on entry) with each of the ``recorders`` entered on it (``stream -> context
    manager`` factories of the simulation objects ``fn`` steps, e.g. ``backend.recording``), ``fn()`` runs and Warp's
    capture is ended (also when ``fn`` raises); then the current stream waits for the side stream. Whatever fails is
    raised: the caller chooses its fallback."""
    graph = torch.cuda.CUDAGraph()
    for gen in generators:
        if not hasattr(graph, "register_generator_state"):
            raise RuntimeError(f"torch {torch.__version__} cannot register generators with a CUDA graph")
        graph.register_generator_state(gen)
    stream = torch.cuda.Stream(device)
    stream.wait_stream(torch.cuda.current_stream(device))
    wdev = wp.device_from_torch(device)
    with gc_paused(), torch.cuda.graph(graph, stream=stream, capture_error_mode="thread_local"):
        wstream = wp.stream_from_torch(stream)
        wp.capture_begin(device=wdev, stream=wstream, external=True, force_module_load=False)
        try:
            with contextlib.ExitStack() as stack:
                stack.enter_context(wp.ScopedDevice(wdev))
                stack.enter_context(wp.ScopedStream(wstream, sync_enter=False))  # no wait on a stream outside
                for rec in recorders:
                    stack.enter_context(rec(wstream))
                out = fn()
        finally:
            # Warp's record of the capture keeps the modules and arrays it launched with alive
            warp_graph = wp.capture_end(device=wdev, stream=wstream)
    torch.cuda.current_stream(device).wait_stream(stream)
    return RecordedGraph(graph, out, warp_graph)


class TaskGraph:
    """Replays ``fn()`` (no arguments: it reads the state it needs from fixed tensors) as one CUDA graph.

    :param fn: the step's task work; returns a nest of tensors.
    :param device: its torch CUDA device.
    :param generators: torch generators ``fn`` draws from (registered with the graph).
    :param recorders: ``stream -> context manager`` factories of the simulation objects ``fn`` steps or resets
        (e.g. ``backend.recording``), entered for the capture.

    If the capture fails (an operation that cannot be captured, an old torch without graph-safe generators), the
    failure is reported once as a warning, :attr:`failed` is set and the caller runs ``fn`` eagerly from then on.
    """

    def __init__(self, fn: Callable[[], Any], device: torch.device, generators: Sequence[torch.Generator] = (),
                 recorders: Sequence[Callable[[wp.Stream], contextlib.AbstractContextManager]] = ()):
        self.fn = fn
        self.device = torch.device(device)
        if self.device.type != "cuda":
            raise ValueError(f"TaskGraph records CUDA graphs; device {self.device} is not a CUDA device")
        self.generators = tuple(generators)
        self.recorders = tuple(recorders)
        self.graph: torch.cuda.CUDAGraph | None = None
        self.failed = False
        self._out = None
        self._warp_graph = None

    def __call__(self) -> Any:
        if self.graph is not None:
            self.graph.replay()
            return clone_outputs(self._out)
        out = self.fn()  # a real step, eagerly: loads modules, makes constants
        self._capture()
        return out

    def _capture(self) -> None:
        try:
            recorded = record_cuda_graph(self.fn, self.device, self.generators, self.recorders)
        except Exception as e:  # noqa: BLE001 - any capture failure: report it and run eagerly
            self.failed = True
            warnings.warn(f"the env step could not be recorded as a CUDA graph ({type(e).__name__}: {e}); it runs "
                          "eagerly (same results, more launches)", RuntimeWarning, stacklevel=3)
            return
        self.graph, self._out, self._warp_graph = recorded
