"""Warp's view of torch's current CUDA stream, one wrapper per CUDA stream for the whole process.

magwarp launches Warp kernels on torch's current stream, so that they are ordered with the torch operations on the
same tensors without host synchronisation. ``wp.stream_from_torch`` makes a new, non-owning ``wp.Stream`` at each
call, and when such a wrapper is garbage collected Warp unregisters its CUDA stream from its stream table (keyed by the
CUDA handle, whichever wrapper registered it). A temporary wrapper of the stream a CUDA graph is being captured on
thus makes the capture's end fail ("Warp error: unknown capture stream"), and one of torch's default stream drops the
registration that a long-lived wrapper (a simulator's) relies on. :func:`torch_stream` returns Warp's current stream
when it is torch's (inside a capture, :func:`magwarp.envs.step_graph.record_cuda_graph` makes it so), else one cached
wrapper per CUDA stream that lives as long as the process.

:func:`gc_paused` wraps every graph capture: Python's cyclic garbage collector can run at any allocation, and when
it frees an unreachable ``torch.cuda.CUDAGraph`` (of an env or trainer dropped earlier) while a capture is open, the
graph's destructor calls CUDA's graph destroy on the capturing thread. CUDA refuses that ("operation not permitted
when stream is capturing") and invalidates the capture, whose next launch then fails with error 901 ("operation
failed due to a previous error during capture").
"""

from __future__ import annotations

import contextlib
import gc

import torch
import warp as wp

__all__ = ["SideBranch", "gc_paused", "torch_stream"]

_WRAPPERS: dict[tuple[int, int], wp.Stream] = {}


def torch_stream(device) -> wp.Stream:
    """The ``wp.Stream`` of torch's current stream on the CUDA ``device`` (a torch device, or its name)."""
    stream = torch.cuda.current_stream(torch.device(device))
    wdev = wp.device_from_torch(stream.device)
    current = wdev.stream
    if current.cuda_stream == stream.cuda_stream:
        return current
    key = (wdev.ordinal, int(stream.cuda_stream))
    wrapper = _WRAPPERS.get(key)
    if wrapper is None:
        wrapper = _WRAPPERS[key] = wp.stream_from_torch(stream)
    return wrapper


_GC_DEPTH = [0]  # gc_paused blocks open (a nested one, inside an open capture, must not collect)


@contextlib.contextmanager
def gc_paused(cuda: bool = True):
    """Collect Python's cyclic garbage now (a graph dropped earlier is destroyed here, outside any capture), then keep
    the collector off inside the block; it is switched on again on the way out (also when the block raises) unless it
    was off before. A block nested in another collects nothing (the outer one's capture may be open). With
    ``cuda=False`` (a capture on Warp's CPU device, which has no such trap) it does nothing: a collection costs about
    0.1 s."""
    if not cuda:
        yield
        return
    if _GC_DEPTH[0] == 0:
        gc.collect()
    was_on = gc.isenabled()
    gc.disable()
    _GC_DEPTH[0] += 1
    try:
        yield
    finally:
        _GC_DEPTH[0] -= 1
        if was_on:
            gc.enable()


class SideBranch:
    """A second CUDA stream for work of a step that the step's next launches do not read: :meth:`fork` runs a block
    on it (torch operations and Warp launches alike) after everything issued so far on the current stream, and
    :meth:`join` makes the current stream wait for it. Inside a CUDA graph capture the block becomes a parallel
    branch of the graph; eagerly it overlaps the launches issued on the current stream in between. On the CPU (or
    with ``enabled=False``) both are no-ops and the block runs in order. Every :meth:`fork` needs a :meth:`join`
    before the step ends (a capture must end joined)."""

    def __init__(self, device, enabled: bool = True):
        self.device = torch.device(device)
        self.enabled = bool(enabled) and self.device.type == "cuda"
        self._stream = torch.cuda.Stream(self.device) if self.enabled else None

    @contextlib.contextmanager
    def fork(self):
        if not self.enabled:
            yield
            return
        self._stream.wait_stream(torch.cuda.current_stream(self.device))
        with torch.cuda.stream(self._stream):
            with wp.ScopedStream(torch_stream(self.device), sync_enter=False):
                yield

    def join(self) -> None:
        if self.enabled:
            torch.cuda.current_stream(self.device).wait_stream(self._stream)
