"""SAC + HER with ``--overlap``: the learner of iteration t samples only steps <= t - 1 (never the slot the concurrent
buffer add writes, nor a future goal from it), the serial schedule is unchanged, and an overlapped run on the CPU (the
same schedule, serially) trains and writes its summary. The two CUDA streams themselves are exercised on a GPU
(``benchmarks/gpu_levers.sh``; the CUDA test below runs where a GPU is)."""

from __future__ import annotations

import argparse
import json
import math

import pytest
import torch

from magwarp.training import sac_her as sac

TINY_ENV = "magwarp/TrajectoryPlanning-v0"
TINY_KWARGS = '{"layout": [[1, 1, 1], [1, 1, 1], [1, 1, 1]], "num_movers": 1}'
TINY = ["--env-id", TINY_ENV, "--env-kwargs", TINY_KWARGS, "--seed", "0", "--num-envs", "16", "--batch-size", "128",
        "--hidden", "32,32", "--learning-starts", "4", "--buffer-steps", "64", "--updates-per-step", "8",
        "--no-progress", "--log-every", "1000", "--eval-steps", "0", "--total-steps", "320"]


def _filled_buffer(T: int, N: int, steps: int, seed: int) -> sac.HerReplayBuffer:
    """A buffer whose every stored value encodes its (global step, env): observation = (step, env), achieved goal
    after the step = (episode id * 10 + env, step)."""
    dims = {k: 2 for k in ("observation", "achieved_goal", "desired_goal")}
    dims.update({"next_" + k: 2 for k in list(dims)}, action=1)
    buf = sac.HerReplayBuffer(T, N, dims, ["mover_collision"], "cpu")
    gen = torch.Generator().manual_seed(seed)
    episode = torch.zeros(N, dtype=torch.int64)
    envs = torch.arange(N).float()
    for g in range(steps):
        done = torch.rand(N, generator=gen) < 0.25
        ag = torch.stack([episode * 10 + envs, torch.full((N,), float(g))], -1)
        obs = {"observation": torch.stack([torch.full((N,), float(g)), envs], -1), "achieved_goal": ag,
               "desired_goal": torch.zeros(N, 2)}
        nxt = {**obs, "achieved_goal": ag}
        buf.add(obs, torch.full((N, 1), float(g)), torch.full((N,), float(g)), nxt,
                torch.zeros(N, dtype=torch.bool), done, {"mover_collision": torch.zeros(N, dtype=torch.bool)})
        episode += done.long()
    return buf


def _reward(achieved, desired, info):
    return (achieved == desired).all(-1).float()


@pytest.mark.parametrize("steps", [5, 8, 9, 30])  # before, at and after the ring's first wrap-around
def test_sample_upto_reads_only_committed_steps_and_future_goals(steps):
    T, N = 8, 3
    buf = _filled_buffer(T, N, steps, seed=steps)
    upto = buf.g - 1  # the newest step's add still in flight (--overlap)
    out = buf.sample(4096, 1.0, _reward, upto=upto)
    step, env = out["observation"][:, 0], out["observation"][:, 1]
    lowest = max(0, steps - T)
    assert int(step.min()) == lowest and int(step.max()) == upto - 1, "the window is [g - capacity, upto)"
    assert torch.equal(out["action"][:, 0], step) and torch.equal(out["next_observation"][:, 0], step)
    goal, ach = out["desired_goal"], out["next_achieved_goal"]
    assert torch.equal(goal[:, 0], ach[:, 0]), "relabelled goal from another env or episode"
    assert bool((goal[:, 1] >= step).all()) and bool((goal[:, 1] <= upto - 1).all()), "future goal beyond upto - 1"
    assert torch.equal(ach[:, 0] % 10, env)


@pytest.mark.parametrize("steps", [6, 8, 9, 21])
def test_sample_upto_is_the_same_before_and_after_the_add_in_flight(steps):
    """With the newest add in flight, the device holds anything between the buffer before it and after it: the
    sample of steps < g - 1 reads the same either way (same random numbers)."""
    T, N = 8, 3
    after = _filled_buffer(T, N, steps, seed=1)
    before = _filled_buffer(T, N, steps - 1, seed=1)  # the same first steps - 1 adds (same generator draws)
    before.g = after.g  # the host counted the add when it issued it
    i = (steps - 1) % T
    for v in before.data.values():
        v[i] = float("nan")  # whatever the slot in flight holds must not be read
    torch.manual_seed(3)
    a = after.sample(2048, 0.8, _reward, upto=steps - 1)
    torch.manual_seed(3)
    b = before.sample(2048, 0.8, _reward, upto=steps - 1)
    for k in a:
        assert torch.equal(a[k], b[k]), k


def test_sample_default_is_upto_every_added_step_and_refuses_an_empty_window():
    buf = _filled_buffer(8, 3, 11, seed=0)
    torch.manual_seed(0)
    a = buf.sample(512, 0.5, _reward)
    torch.manual_seed(0)
    b = buf.sample(512, 0.5, _reward, upto=buf.g)
    assert all(torch.equal(a[k], b[k]) for k in a)
    with pytest.raises(ValueError, match=r"steps \[3, 3\)"):
        buf.sample(8, 0.5, _reward, upto=3)  # step 2 was overwritten: nothing below 3 is stored
    with pytest.raises(ValueError, match=r"steps \[3, 12\)"):
        buf.sample(8, 0.5, _reward, upto=12)  # not added yet
    empty = _filled_buffer(8, 3, 1, seed=0)
    with pytest.raises(ValueError, match="nothing committed"):
        empty.sample(8, 0.5, _reward, upto=0)


def _record_samples(monkeypatch) -> list[tuple[int, int]]:
    """Record ``(steps added, upto)`` of every sample the training loop draws."""
    calls: list[tuple[int, int]] = []
    sample = sac.HerReplayBuffer.sample

    def recording(self, batch, her_ratio, compute_reward, upto=None):
        calls.append((self.g, self.g if upto is None else upto))
        return sample(self, batch, her_ratio, compute_reward, upto)

    monkeypatch.setattr(sac.HerReplayBuffer, "sample", recording)
    return calls


@pytest.mark.parametrize("overlap", ["off", "on"])
def test_overlap_learner_samples_steps_up_to_the_previous_one(tmp_path, monkeypatch, overlap):
    """Iteration t (steps 0..t added): serially the learner samples steps <= t; overlapped, steps <= t - 1, from the
    first iteration with --learning-starts of them on. On the CPU the overlapped schedule runs serially and trains."""
    calls = _record_samples(monkeypatch)
    summary = sac.train(sac.parse_args([*TINY, "--device", "cpu", "--overlap", overlap, "--out", str(tmp_path),
                                        "--profile"]))
    lag = 1 if overlap == "on" else 0
    iterations = 320 // 16
    assert [g for g, _ in calls] == list(range(4 + lag, iterations + 1))
    assert all(upto == g - lag for g, upto in calls)
    assert summary["overlap"] is (overlap == "on")
    assert summary["updates"] == 8 * len(calls) and summary["global_step"] == 320
    assert summary["env_steps_per_s"] > 0
    startup = summary["startup_s"]
    assert list(startup) == ["imports", "train_env", "learner", "first_env_step", "eval_env", "clock_start",
                             "first_update"]
    assert all(b >= a for a, b in zip(startup.values(), list(startup.values())[1:]))
    assert {"policy", "env", "buffer", "sample", "update"} <= set(summary["profile"])
    assert summary["profile"]["update"]["calls"] == len(calls)
    ckpt = torch.load(tmp_path / "checkpoint.pt", weights_only=False)
    assert ckpt["updates"] == summary["updates"]
    assert all(bool(torch.isfinite(v).all()) for v in ckpt["actor"].values())


def test_overlap_options_are_checked():
    args = argparse.Namespace(overlap="on", buffer_steps=1)
    with pytest.raises(ValueError, match="--buffer-steps >= 2"):
        sac.overlap_enabled(args, torch.device("cpu"))
    assert sac.overlap_enabled(argparse.Namespace(overlap="auto", buffer_steps=8), torch.device("cpu")) is False
    assert sac.overlap_enabled(argparse.Namespace(overlap="auto", buffer_steps=8), torch.device("cuda:0")) is True
    assert sac.overlap_enabled(argparse.Namespace(overlap="off", buffer_steps=8), torch.device("cuda:0")) is False
    with pytest.raises(ValueError, match="--async-eval on .* needs --overlap on"):
        sac.overlap_enabled(argparse.Namespace(overlap="auto", buffer_steps=8, async_eval="on"), torch.device("cpu"))


def test_overlap_on_is_refused_under_torchrun(monkeypatch):
    monkeypatch.setattr(sac.dist, "world_size", lambda: 2)
    with pytest.raises(ValueError, match="not supported under torchrun"):
        sac.overlap_enabled(argparse.Namespace(overlap="on", buffer_steps=8), torch.device("cuda:0"))
    assert sac.overlap_enabled(argparse.Namespace(overlap="auto", buffer_steps=8), torch.device("cuda:0")) is False


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
@pytest.mark.parametrize("async_eval", ["off", "on"])
def test_overlapped_cuda_run_trains_on_two_streams(tmp_path, monkeypatch, async_eval):
    calls = _record_samples(monkeypatch)
    summary = sac.train(sac.parse_args([*TINY, "--device", "cuda", "--overlap", "on", "--out", str(tmp_path),
                                        "--profile", "--async-eval", async_eval, "--target", "0.99",
                                        "--eval-every", "1e-6", "--eval-envs", "4", "--target-eval-steps", "2"]))
    assert summary["overlap"] is True and all(upto == g - 1 for g, upto in calls)
    evals = json.loads((tmp_path / "run.json").read_text())["evals"]
    assert len(evals) >= (1 if async_eval == "on" else 320 // 16)
    assert all(0.0 <= e["success_rate"] <= 1.0 or math.isnan(e["success_rate"]) for e in evals)
    overlap = summary["profile_overlap"]
    assert overlap["iterations"] == 320 // 16 and overlap["env_stream_s"] > 0 and overlap["learner_stream_s"] > 0
    ckpt = torch.load(tmp_path / "checkpoint.pt", weights_only=False)
    assert all(bool(torch.isfinite(v).all()) for v in ckpt["actor"].values())


class _FakeCuda:
    """Stand-ins for torch.cuda's streams and events that log what is issued where (the CPU does the work)."""

    def __init__(self):
        self.log: list[tuple[str, ...]] = []
        self.current = _FakeCuda.Stream(self, "env")

    class Stream:
        def __init__(self, cuda, name="learner"):
            self.cuda, self.name = cuda, name

        def wait_event(self, event):
            self.cuda.log.append(("wait", event.name, self.name))

    class Event:
        def __init__(self, cuda):
            self.cuda, self.name = cuda, "?"

        def record(self, stream=None):
            self.cuda.log.append(("record", self.name, (stream or self.cuda.current).name))

        def query(self):
            return True

    def patch(self, monkeypatch):
        import contextlib

        @contextlib.contextmanager
        def stream(s):
            before, self.current = self.current, s
            try:
                yield
            finally:
                self.current = before

        monkeypatch.setattr(torch.cuda, "current_stream", lambda device=None: self.current)
        monkeypatch.setattr(torch.cuda, "Stream", lambda device=None: _FakeCuda.Stream(self))
        monkeypatch.setattr(torch.cuda, "Event", lambda **kw: _FakeCuda.Event(self))
        monkeypatch.setattr(torch.cuda, "stream", stream)

    def note(self, what: str) -> None:
        self.log.append((what, self.current.name))


@pytest.mark.parametrize("async_eval", ["off", "on"])
def test_overlapped_schedule_issues_each_block_on_its_stream_behind_its_events(tmp_path, monkeypatch, async_eval):
    """The two-stream wiring, device independent (fake streams and events log what the loop issues where): the action
    and the updates on the learner's stream, after the env's last work; the env step's buffer add on the env's stream,
    after the action; evaluations and log rows read the learner's state after a join (--async-eval: the evaluation
    runs on a third stream, on a copy that the learner's next work waits for)."""
    from magwarp.training import streams as streams_mod
    from magwarp.training.common import SuccessTracker

    fake = _FakeCuda()
    fake.patch(monkeypatch)

    def pair(device, enabled, phases=None):
        sp = streams_mod.StreamPair(torch.device("cuda:0"), enabled, phases)  # the CUDA path, on fakes
        for name in ("action_ready", "env_mark", "learn_mark", "reader_mark"):
            getattr(sp, name).name = name
        side = sp.side_stream
        sp.side_stream = lambda: setattr(stream := side(), "name", "eval") or stream
        return sp

    monkeypatch.setattr(sac, "StreamPair", pair)

    def noting(cls, attr, what):
        fn = getattr(cls, attr)

        def wrapped(self, *a, **k):
            fake.note(what(a, k) if callable(what) else what)
            return fn(self, *a, **k)

        monkeypatch.setattr(cls, attr, wrapped)

    noting(sac.HerReplayBuffer, "add", "add")
    noting(sac.HerReplayBuffer, "sample", "sample")
    noting(sac.SacLearner, "learn", "learn")
    noting(SuccessTracker, "update", "count")
    noting(sac.Actor, "forward", lambda a, k: "act_eval" if k.get("deterministic", a[1:2] == (True,)) else "act")
    summary = sac.train(sac.parse_args([*TINY, "--device", "cpu", "--overlap", "on", "--out", str(tmp_path),
                                        "--log-every", "0", "--target", "0.99", "--eval-every", "1e-6",
                                        "--eval-envs", "4", "--target-eval-steps", "2", "--eval-steps", "2",
                                        "--learning-starts", "0", "--async-eval", async_eval]))
    log = fake.log
    where = {}
    for entry in log:
        if entry[0] in ("add", "sample", "learn", "act", "act_eval"):
            where.setdefault(entry[0], set()).add(entry[1])
    periodic = "eval" if async_eval == "on" else "env"
    assert where == {"add": {"env"}, "sample": {"learner"}, "learn": {"learner"}, "act": {"learner"},
                     "act_eval": {"env", periodic}}
    evals = json.loads((tmp_path / "run.json").read_text())["evals"]
    assert len(evals) == 320 // 16  # each periodic evaluation recorded (launched ones when done)
    assert summary["time_to_target_s"] in (None, *(e["process_s"] for e in evals))
    ready = waited = False
    joined = {"env": False, "eval": False}
    released = True
    for i, entry in enumerate(log):
        if entry == ("record", "action_ready", "learner"):
            ready, waited = True, False
        elif entry == ("wait", "action_ready", "env"):
            assert ready, "the env waited for an action not yet marked"
            waited = True
        elif entry == ("wait", "env_mark", "learner"):
            assert log[i - 1] == ("record", "env_mark", "env"), "the learner waited for an old mark of the env"
            ready = False
        elif entry[0] == "add":
            assert waited, "a buffer add issued before the env waited for the action"
        elif entry[:2] == ("wait", "learn_mark"):
            assert log[i - 1] == ("record", "learn_mark", "learner")
            joined[entry[2]] = True
            released = released and entry[2] != "eval"
        elif entry == ("wait", "reader_mark", "learner"):
            assert log[i - 1] == ("record", "reader_mark", "eval")
            released = True
        elif entry[0] in ("sample", "learn", "act"):
            assert released, "the learner changed its state before the evaluation's copy of it was released"
            joined = {"env": False, "eval": False}  # new learner work: a reader on another stream must join again
        elif entry[0] == "act_eval":
            assert joined[entry[1]], "an evaluation read the actor without joining the learner's stream"
    assert sum(e[0] == "act_eval" for e in log) >= 2 * 20 + 2 and sum(e[0] == "learn" for e in log) == 19
