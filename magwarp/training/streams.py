"""Two CUDA streams for an off-policy iteration whose env step and updates overlap (``sac_her --overlap``).

An iteration ``t`` of an overlapped run issues, with no host synchronisation:

* on the **learner's stream**, after everything issued on the env's stream so far (the env step ``t - 1``, its buffer
  add, an evaluation): the action of step ``t`` (and the observation normaliser's update) -- *act*;
* on the **env's stream**, after that action: the env step ``t``, its buffer add and the success counters -- *env*;
* on the learner's stream again, concurrently with the env step: the HER sample of steps ``<= t - 1`` and the updates
  -- *learn*. The actor they change acted before them on the same stream.

The env's stream is the stream that was current when the env was built: its physics graph
(:class:`magwarp.physics.MjwBackend`) and the simulator (:class:`magwarp.sim.Simulator`) launch on torch's current
stream of that moment, and the task graph of a push env step (:mod:`magwarp.envs.step_graph`) and the torch
operations on the env's tensors run on torch's current stream, which :meth:`env` makes that same stream. The
learner's stream is a torch stream of its own (non-blocking: it runs beside the legacy default stream).

Each stream's tensors are read by the other only behind those two waits, and every tensor is freed after the waits
that order its readers (the action: after the next ``act`` waited for the env; an observation: after the env step
that waited for the action read it), so the caching allocator never hands a block to one stream while the other still
reads it. Anything that reads the learner's state from the env's stream (log rows, evaluations, checkpoints) calls
:meth:`join` first; the next ``act`` waits for whatever that issued.

On the CPU, or with overlap off, every context is a plain block: the same schedule runs serially.
With ``profile`` (``--profile``), each block is timed on its own stream with CUDA events and the device is synchronised
once per iteration (:meth:`end_iteration`) to read them, so the blocks still overlap inside an iteration.
"""

from __future__ import annotations

import contextlib
import time

import torch

__all__ = ["StreamPair"]


class StreamPair:
    """The env's and the learner's streams of an overlapped iteration (see the module docstring).

    :param device: the env's torch device.
    :param enabled: overlap on: two streams on CUDA; on the CPU one (the same schedule, run serially).
    :param phases: a :class:`~magwarp.training.common.PhaseTimer` (``--profile``): blocks named in :meth:`act`,
        :meth:`env` and :meth:`learn` are timed in it (with CUDA events when the streams overlap).
    """

    def __init__(self, device, enabled: bool, phases=None):
        self.device = torch.device(device)
        self.enabled = bool(enabled)
        self.cuda = self.enabled and self.device.type == "cuda"
        #: steps whose buffer add may still run when the learner samples: what the sample must leave out
        self.lag = 1 if self.enabled else 0
        self.time_in(phases)
        self._timed: list[tuple[str, str, torch.cuda.Event, torch.cuda.Event]] = []
        self._pool: list[torch.cuda.Event] = []
        self._last = time.perf_counter()
        if self.cuda:
            self.env_stream = torch.cuda.current_stream(self.device)  # where the env was built: its graphs launch there
            self.learn_stream = torch.cuda.Stream(self.device)
            self.action_ready = torch.cuda.Event()  # the action of step t: the env may step
            self.env_mark = torch.cuda.Event()  # what the env's stream issued before an act
            self.learn_mark = torch.cuda.Event()  # what the learner's stream issued before a join
            self.reader_mark = torch.cuda.Event()  # what a reader of the learner's state issued before a release

    # ---- the three blocks of an iteration
    @contextlib.contextmanager
    def act(self, name: str = "policy"):
        """The learner's stream, after everything issued on the env's stream so far; the action is ready on exit."""
        if self.cuda:
            self.env_mark.record(self.env_stream)
            self.learn_stream.wait_event(self.env_mark)
        with self._block(name, "learner"):
            yield
        if self.cuda:
            self.action_ready.record(self.learn_stream)

    @contextlib.contextmanager
    def env(self, name: str = "env"):
        """The env's stream, after the action (:meth:`act`)."""
        if self.cuda:
            self.env_stream.wait_event(self.action_ready)
        with self._block(name, "env"):
            yield

    def learn(self, name: str = "update"):
        """The learner's stream (after its own earlier work)."""
        return self._block(name, "learner")

    @contextlib.contextmanager
    def _block(self, name: str, which: str):
        """Torch's current stream is the env's or the learner's (``which``) inside; timed as phase ``name`` with
        ``--profile``. A plain block (a phase of the serial profile) without two streams."""
        if not self.cuda:
            with self.phases(name) if self.profiling else contextlib.nullcontext():
                yield
            return
        stream = self.env_stream if which == "env" else self.learn_stream
        with torch.cuda.stream(stream), self._events(name, which):
            yield

    def join(self) -> None:
        """Torch's current stream waits for the learner's stream (no host sync): call it before reading the learner's
        state (weights, normaliser, losses) on another stream."""
        if self.cuda:
            self.learn_mark.record(self.learn_stream)
            torch.cuda.current_stream(self.device).wait_event(self.learn_mark)

    def side_stream(self):
        """A third CUDA stream (an evaluation's own, ``--async-eval``), or None without two streams."""
        return torch.cuda.Stream(self.device) if self.cuda else None

    def time_in(self, phases) -> None:
        """Time the blocks in ``phases`` (a :class:`~magwarp.training.common.PhaseTimer`, ``--profile``)."""
        self.phases = phases
        self.profiling = phases is not None and phases.enabled

    def release(self) -> None:
        """The learner's stream waits for torch's current stream (no host sync): after reading the learner's state on
        a stream that the next act does not wait for (an evaluation's own), before the learner changes it."""
        if self.cuda:
            self.reader_mark.record()
            self.learn_stream.wait_event(self.reader_mark)

    # ---- profiling
    def _event(self) -> torch.cuda.Event:
        return self._pool.pop() if self._pool else torch.cuda.Event(enable_timing=True)

    @contextlib.contextmanager
    def _events(self, name: str, which: str):
        """Time the block on the current stream (``which``: "env" or "learner") with two CUDA events."""
        if not self.profiling:
            yield
            return
        start, end = self._event(), self._event()
        start.record()
        yield
        end.record()
        self._timed.append((name, which, start, end))

    def end_iteration(self) -> None:
        """``--profile`` with overlapping streams: synchronise the device once, add each block's device time to its
        phase and the iteration's wall time to ``phases.overlap``. Otherwise nothing (no sync)."""
        if not (self.profiling and self.cuda):
            return
        torch.cuda.synchronize(self.device)
        now = time.perf_counter()
        streams = {"env": 0.0, "learner": 0.0}
        for name, which, start, end in self._timed:
            s = start.elapsed_time(end) / 1000.0
            self.phases.add(name, s)
            streams[which] += s
            self._pool += [start, end]
        self._timed.clear()
        o = self.phases.overlap
        o["iterations"] = o.get("iterations", 0) + 1
        o["iteration_s"] = o.get("iteration_s", 0.0) + now - self._last
        for k, v in streams.items():
            o[f"{k}_stream_s"] = o.get(f"{k}_stream_s", 0.0) + v
        self._last = now

    def start_clock(self) -> None:
        """Start the iteration clock of :meth:`end_iteration` (where the training loop starts)."""
        self._last = time.perf_counter()
