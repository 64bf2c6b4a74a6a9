"""Property-based fuzzing (hypothesis): random shapes, dtypes, devices, NaN/inf/huge values and random keyword
arguments thrown at the Simulator, every registered env (``gymnasium.make`` and ``make_vec``) and the command line.
Every case must end in a clear error (a ValueError/TypeError whose message is ours, not numpy's or torch's, and no
state change) or in a finite, valid state; the command line must answer with one line and a non-zero exit code.

Profiles (``HYPOTHESIS_PROFILE``): ``ci`` (default; a few examples per test, seconds in all: envs are built once and
reused, since mujoco-warp compiles slowly on the CPU) and ``local`` (hundreds of examples, for a thorough run):

    HYPOTHESIS_PROFILE=local python -m pytest tests/test_fuzz.py
"""

from __future__ import annotations

import dataclasses
import inspect
import math
import os

import numpy as np
import pytest
import torch

import magwarp  # noqa: F401 - registers the env ids (a -k selection may run no other test that imports it)

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, Phase, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

_COMMON = dict(deadline=None, derandomize=False, print_blob=True,
               suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture,
                                      HealthCheck.data_too_large, HealthCheck.filter_too_much])
# CI does not shrink a failure (each example may build an env: shrinking would take minutes); the report still
# names the failing example. Run the local profile to get a minimal one.
settings.register_profile("ci", max_examples=6, phases=[Phase.explicit, Phase.reuse, Phase.generate], **_COMMON)
settings.register_profile("local", max_examples=300, **_COMMON)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))

NAN, INF = float("nan"), float("inf")
#: messages that mean an input reached numpy/torch/Python internals instead of being checked
INTERNAL = ("cannot convert float", "invalid literal for int", "inhomogeneous", "setting an array element",
            "object of type", "unsupported operand", "not supported between instances", "could not convert",
            "must be real number", "argument must be", "only integer tensors", "can't convert", "not 'NoneType'",
            "has no attribute")

weird_floats = st.sampled_from([NAN, INF, -INF, 1e40, -1e40, 3.4e38, -3.4e38, 1e-45, 0.0, -0.0, -1.0, 2.5, 1e6, 1e-9])
# integers: small ones (a valid count must stay cheap: a huge but legal solver_iterations would just run for ages)
# and ones beyond Warp's int32 sizes, which every count must refuse
weird_ints = st.one_of(st.integers(-3, 12), st.sampled_from([2**31, 2**63, 2**64, 2**70, -(2**63)]))
weird_values = st.one_of(
    weird_floats, weird_ints, st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from(["x", "", None, True, False, [1, 2], [NAN], {"a": 1}, (NAN,), torch.device("cpu"), "cuda:7"]),
)
devices = st.sampled_from(["cpu", torch.device("cpu"), "cuda:7", "gpu", "", 3, None])


def _clear(err: BaseException) -> None:
    """A refusal must be a ValueError/TypeError with a message of ours."""
    assert isinstance(err, (ValueError, TypeError)), f"{type(err).__name__}: {err}"
    msg = str(err)
    assert msg and not any(s in msg for s in INTERNAL), f"unclear error: {type(err).__name__}: {msg}"


def _finite(*tensors) -> None:
    for t in tensors:
        if isinstance(t, dict):
            _finite(*t.values())
        elif isinstance(t, (torch.Tensor, np.ndarray)):
            assert torch.isfinite(torch.as_tensor(t).float()).all(), t
        elif isinstance(t, float):
            assert math.isfinite(t)


# ---------------------------------------------------------------------------------------------------- Simulator
SIM_KWARGS = {
    "num_worlds": st.one_of(st.integers(1, 3), weird_values),
    "num_movers": st.one_of(st.sampled_from([1, 2]), weird_values),
    "gravity": st.one_of(st.floats(-30, 30), weird_values),
    "dt": st.one_of(st.floats(1e-4, 1e-2), weird_values),
    "v_max": st.one_of(st.floats(0.1, 5), weird_values),
    "a_max": st.one_of(st.floats(0.1, 50), weird_values),
    "j_max": st.one_of(st.floats(1, 500), weird_values),
    "stiffness_lin": st.one_of(st.tuples(st.floats(0, 10), st.floats(0, 10), st.floats(0, 1e6)), weird_values),
    "stiffness_rot": st.one_of(st.tuples(st.floats(0, 1), st.floats(0, 1), st.floats(0, 10)), weird_values),
    "hold_mask": st.one_of(st.lists(st.integers(0, 1), min_size=6, max_size=6), weird_values),
    "control": st.sampled_from(["acceleration", "jerk", "force", 3]),
    "max_pairs": st.one_of(st.integers(1, 4), weird_values),
    "device": devices,
}


@given(kwargs=st.fixed_dictionaries({}, optional=SIM_KWARGS), layout=st.sampled_from([(2, 2), (3, 2)]))
def test_simulator_construction_is_refused_clearly_or_runs_finite(kwargs, layout):
    from magwarp.sim import Simulator

    kwargs.setdefault("num_movers", 1)
    try:
        sim = Simulator(np.ones(layout), **kwargs)
    except Exception as e:  # noqa: BLE001 - the property: only clear errors
        _clear(e)
        return
    lim = sim.model.limits
    top = lim.j_max if sim.control == "jerk" else lim.a_max
    angle = torch.rand(sim.num_worlds, sim.num_movers, 1) * 2 * math.pi
    cmd = top * torch.cat([angle.cos(), angle.sin()], -1)  # the largest legal command, random directions
    sim.step(25, cmd)
    _finite(sim.pos, sim.vel, sim.quat, sim.omega)
    assert sim.nonfinite_worlds() == []


@pytest.fixture(scope="module")
def shared_sim():
    from magwarp.sim import Simulator

    return Simulator(np.ones((3, 3)), 2, 3, device="cpu")


command_arrays = st.builds(
    lambda shape, dtype, fill, spot: (shape, dtype, fill, spot),
    shape=st.sampled_from([(3, 2, 2), (3, 2, 2), (3, 4), (2, 2, 2), (3, 2, 3), (), (3, 2, 2, 1)]),
    dtype=st.sampled_from([torch.float32, torch.float64, torch.float16, torch.int32, torch.bool, "numpy", "list"]),
    fill=st.one_of(st.floats(-20, 20), weird_floats),
    spot=weird_floats,
)


@given(spec=command_arrays)
def test_simulator_commands_are_refused_without_state_change_or_stay_finite(shared_sim, spec):
    sim = shared_sim
    shape, dtype, fill, spot = spec
    values = np.full(shape, fill, dtype=np.float64)
    if values.size:
        values.reshape(-1)[0] = spot
    if dtype == "numpy":
        cmd = values
    elif dtype == "list":
        cmd = values.tolist()
    else:
        with np.errstate(over="ignore", invalid="ignore"):
            cmd = torch.as_tensor(values).to(dtype)
    before = [t.clone() for t in (sim.pos, sim.vel, sim.cmd)]
    try:
        sim.step(3, cmd)
    except Exception as e:  # noqa: BLE001
        _clear(e)
        for b, a in zip(before, (sim.pos, sim.vel, sim.cmd)):
            assert torch.equal(b, a)
        return
    _finite(sim.pos, sim.vel, sim.quat, sim.omega)
    assert sim.nonfinite_worlds() == []


# ---------------------------------------------------------------------------------------------------- envs
def _env_ids() -> list[str]:
    import magwarp  # noqa: F401 - registers the ids
    from magwarp.registration import env_ids

    return sorted(env_ids())


#: one id per env class (each is built once per session and reused by the action fuzzing)
REPRESENTATIVES = ["magwarp/TrajectoryPlanningB3-v0", "magwarp/PushBox-v0", "magwarp/PushTB5-v0", "magwarp/PushL-v0",
                   "magwarp/PushX-v0", "magwarp/PushWithObstacles-v0", "magwarp/Swarm-v0", "magwarp/SwarmResidual-v0",
                   "magwarp/PlatformPose-v0", "magwarp/CoopPush-v0", "magwarp/CoopPushResidual-v0",
                   "magwarp/Levitation-v0", "magwarp/LevitationResidual-v0", "magwarp/PlatformPickPlace-v0",
                   "magwarp/GripperPickPlace-v0"]
_ENVS: dict = {}


def _env(env_id: str, vector: bool):
    import gymnasium as gym

    key = (env_id, vector)
    if key not in _ENVS:
        _ENVS[key] = (gym.make_vec(env_id, num_envs=2, device="cpu") if vector else
                      gym.make(env_id, device="cpu").unwrapped)
        _ENVS[key].reset(seed=0)
    return _ENVS[key]


def test_every_registered_id_names_a_known_env():
    import gymnasium as gym

    from magwarp.registration import ENV_CLASSES, env_ids

    ids = _env_ids()
    assert len(ids) >= 40
    classes = {cls for cls, _ in env_ids().values()}
    assert classes == set(ENV_CLASSES)
    for rep in REPRESENTATIVES:
        assert rep in gym.registry
    assert {env_ids()[r][0] for r in REPRESENTATIVES} == classes  # the action fuzzing covers every class


def _state(env):
    vec = getattr(env, "vec", env)
    if hasattr(vec, "sim"):
        return [vec.sim.pos.clone(), vec.sim.vel.clone()]
    return [vec.backend.qpos_t.clone(), vec.backend.qvel_t.clone()]


actions = st.builds(
    lambda kind, dtype, fill, spot, shape_change: (kind, dtype, fill, spot, shape_change),
    kind=st.sampled_from(["legal", "legal", "weird"]),
    dtype=st.sampled_from([np.float32, np.float64, np.float16, np.int64, "torch64", "list"]),
    fill=st.one_of(st.floats(-1, 1), weird_floats),
    spot=weird_floats,
    shape_change=st.sampled_from([None, None, None, +1, -1, "batch"]),
)


def _make_action(env, vector: bool, spec):
    kind, dtype, fill, spot, shape_change = spec
    space = env.single_action_space if vector else env.action_space
    shape = (env.num_envs, *space.shape) if vector else space.shape
    high = np.asarray(space.high, dtype=np.float64)
    if kind == "legal":  # the extremes of the action space (the norm clip keeps them legal)
        values = np.sign(fill if math.isfinite(fill) and fill != 0 else 1.0) * np.broadcast_to(high, shape)
    else:
        values = np.full(shape, fill, dtype=np.float64)
        values.reshape(-1)[0] = spot
    if shape_change == "batch":
        values = values[None]
    elif shape_change is not None:
        values = np.resize(values, (*values.shape[:-1], max(values.shape[-1] + shape_change, 0)))
    if dtype == "list":
        return values.tolist()
    with np.errstate(over="ignore", invalid="ignore"):
        if dtype == "torch64":
            return torch.as_tensor(values)
        arr = values.astype(dtype)
    return torch.as_tensor(arr) if vector and dtype in (np.float32, np.int64) else arr


# every class batched (make_vec); the single-env view (make) of a trajectory and a pushing env
ENV_CASES = [(r, True) for r in REPRESENTATIVES] + [(r, False) for r in REPRESENTATIVES[:2]]


@pytest.mark.parametrize("env_id, vector", ENV_CASES, ids=[f"{'make_vec' if v else 'make'}-{r.split('/')[1]}"
                                                           for r, v in ENV_CASES])
@given(data=st.data())
def test_env_actions_are_refused_without_state_change_or_stay_finite(env_id, vector, data):
    env = _env(env_id, vector)
    before = _state(env)
    for _ in range(2):
        action = _make_action(env, vector, data.draw(actions))
        try:
            obs, reward, terminated, truncated, info = env.step(action)
        except Exception as e:  # noqa: BLE001
            _clear(e)
            for b, a in zip(before, _state(env)):
                assert torch.equal(b, a)
            continue
        _finite(obs, reward if vector else float(reward))
        if vector:
            assert not info["nonfinite"].any()
        if not vector and (terminated or truncated):
            env.reset()
        before = _state(env)


def _kwarg_names(env_id: str) -> list[str]:
    from magwarp.registration import ENV_CLASSES, _load, env_ids

    cls = _load(env_ids()[env_id][0])
    names = set()
    for klass in cls.__mro__:
        if klass.__module__.startswith("magwarp.envs") and "__init__" in vars(klass):
            params = inspect.signature(klass.__init__).parameters
            names |= {n for n, p in params.items() if n not in ("self", "kwargs", "device", "render_mode")
                      and p.kind is not p.VAR_KEYWORD}
    if getattr(cls, "config_class", None) is not None:  # MagBot envs: the config's fields are keyword options
        names |= {f.name for f in dataclasses.fields(cls.config_class)}
    assert ENV_CLASSES
    return sorted(names)


@given(data=st.data())
def test_env_kwargs_are_refused_clearly_or_give_a_finite_env(data):
    import gymnasium as gym

    env_id = data.draw(st.sampled_from(_env_ids()), label="env_id")
    names = _kwarg_names(env_id)
    kwargs = {}
    for name in data.draw(st.lists(st.sampled_from(names), min_size=1, max_size=2, unique=True), label="names"):
        kwargs[name] = data.draw(weird_values, label=name)
    vector = data.draw(st.booleans(), label="vector")
    try:
        env = (gym.make_vec(env_id, num_envs=2, device="cpu", **kwargs) if vector else
               gym.make(env_id, device="cpu", **kwargs).unwrapped)
        obs, _ = env.reset(seed=0)
        action = env.action_space.sample() * 0.0 if not vector else torch.zeros(env.action_space.shape)
        step = env.step(action)
    except Exception as e:  # noqa: BLE001
        _clear(e)
        return
    _finite(obs, step[0], step[1] if vector else float(step[1]))


# ---------------------------------------------------------------------------------------------------- command line
CLI_CASES = {
    "eval": ["eval", "TrajectoryPlanningB0", "--episodes", "1", "--repeats", "1", "--steps", "1", "--device", "cpu"],
    "render": ["render", "--synthetic", "--layout", "B0", "--worlds", "1", "--steps", "1", "--device", "cpu"],
    "export": ["export", "pretrained:b0_ppo"],
    "train": ["train", "--resume"],
}
CLI_OPTIONS = {
    "eval": ["--episodes", "--repeats", "--steps", "--seed", "--device", "--env-kwargs", "--policy", "--max-worlds",
             "--makespan-goals", "--json"],
    "render": ["--worlds", "--steps", "--layout", "--device", "-o"],
    "export": ["--onnx", "--opset", "--obs-dim", "--atol"],
    "train": ["--num-envs", "--minutes", "--seed", "--env-kwargs", "--target", "--nproc-per-node"],
}
cli_values = st.sampled_from(["nan", "NaN", "-1", "0", "2.5", "1e400", "", "x", "/dev/full", "/proc/x.gif",
                              "/etc/hostname/x", "cuda:7", '{"reward_per_step": NaN}', '{"num_cycles": 0}', "[1]",
                              "os:getcwd", "README.md", "policies", "B99", "-inf"])
#: values too large to be refused by every count option (a valid but huge --steps would just run for ages)
HUGE = {"--seed": "18446744073709551616", "--opset": "9" * 30}


@given(data=st.data())
def test_cli_mistakes_are_one_line(capsys, data, tmp_path_factory):
    from magwarp import cli

    cmd = data.draw(st.sampled_from(sorted(CLI_CASES)), label="command")
    argv = list(CLI_CASES[cmd])
    if cmd == "train":
        argv.append(data.draw(cli_values, label="resume"))
    for opt in data.draw(st.lists(st.sampled_from(CLI_OPTIONS[cmd]), max_size=2, unique=True), label="options"):
        values = cli_values if opt not in HUGE else st.one_of(cli_values, st.just(HUGE[opt]))
        argv += [opt, data.draw(values, label=opt)]
    if cmd == "render" and "-o" not in argv:
        argv += ["-o", "x.png"]
    if cmd == "export" and "--onnx" not in argv:
        argv += ["--onnx", "/etc/hostname/x.onnx"]
    cwd = os.getcwd()
    os.chdir(tmp_path_factory.mktemp("cwd"))  # whatever a valid call writes lands in a scratch folder
    try:
        rc = cli.main(argv)
    finally:
        os.chdir(cwd)
    out, err = capsys.readouterr()
    assert "Traceback" not in err, (argv, err)
    if rc != 0:
        errors = [line for line in err.strip().splitlines() if "error" in line]
        assert len(errors) == 1, (argv, err)
    else:
        assert "error" not in err.lower(), (argv, err)
