"""MagBotSim measured the way its paper measures it, for side-by-side rows in magwarp's benchmarks.

MagBotSim (PyPI ``magbotsim``, MuJoCo on CPU) is the reference we compare against in the same run on the same
machine. This module only *drives* it through its public classes; nothing of it is copied into magwarp.

Two measurements, both returning plain dicts:

* ``scaling_step_ms``: the paper's scalability test (Sec. "Scalability"): a basic env (no RL API, headless) with
  N movers at the centres of a full square tile grid; one step = apply controls to all movers + one
  ``mujoco.mj_step`` + MagBotSim's mover-mover and wall collision checks (``check_mover_collision``,
  ``check_wall_collision``), for the 'circle' or 'box' collision shape. Two variants:

  - ``controllers=False`` ("vectorised"): the x/y accelerations of all movers are written into ``data.ctrl`` at once,
    the way MagBotSim's RL envs write their x/y actuators; the hold actuators (z, roll, pitch, yaw) stay at 0.
  - ``controllers=True``: additionally one ``MoverImpedanceController.update`` per mover per cycle holding z, roll,
    pitch and yaw, exactly as ``LongHorizonGlobalTrajectoryPlanningEnv`` does every cycle.

  Both variants use the same MuJoCo model (x/y acceleration actuators + the controllers' z/a/b/c actuators per
  mover), so their difference is only the Python controller loop.

* ``env_steps_per_s``: ``env.step()`` throughput of MagBotSim's Gymnasium envs (random actions, headless,
  resets on termination/truncation included in the timing).

Construction. The stock ``BasicMagBotEnv`` constructor is quadratic in the number of names in the model (its
``mujoco_utils.extract_mj_names`` slices and splits the whole names buffer once per object), which takes minutes at
1000 movers. ``fast_name_extraction()`` swaps that one function for an equivalent linear one (``mj_id2name`` per
id) while the scaling env is built. It runs only at construction; the timed step never calls it, so the measured
step is unchanged. The RL envs are always built with the stock code, because they rebuild their model on every
reset and resets are part of what ``env_steps_per_s`` times.
"""

from __future__ import annotations

import contextlib
import importlib.util
import inspect
import time
import warnings
from collections.abc import Iterator
from typing import Any

import numpy as np

try:  # imported as benchmarks.magbotsim_ref (namespace package) ...
    from . import common
except ImportError:  # ... or as a top-level module by scripts run from benchmarks/
    import common

# The paper's scalability configurations: (movers, tiles per side), full square grids.
PAPER_SCALING_CONFIGS: tuple[tuple[int, int], ...] = ((50, 10), (100, 12), (200, 17), (400, 27), (1000, 57))

# MagBotSim's RL envs we time, with the throughput DESIGN.md recorded for this machine (steps/s, for reference).
RL_ENV_IDS: dict[str, float] = {
    "LongHorizonGlobalTrajectoryPlanningEnvB0-v0": 17.0,
    "StateBasedPushBoxEnv-v0": 33.0,
    "StateBasedPushTEnv-v0": 21.0,
}

# Collision sizes. Circle: MagBotSim's default radius. Box: MagBotSim's own box examples
# (envs_without_rl_api/magbots/*) use the mover half-size + 1 mm; the default float size is rejected for 'box'.
MOVER_HALF_SIZE = np.array([0.155 / 2, 0.155 / 2, 0.012 / 2])
DEFAULT_C_SIZE = {"circle": 0.11, "box": np.array([0.155 / 2, 0.155 / 2]) + 0.001}

# Impedance controller settings of MagBotSim's RL envs (hold z, roll, pitch, yaw; x/y are acceleration-driven).
CONTROLLER_KW = {
    "joint_mask": np.array([0, 0, 1, 1, 1, 1]),
    "translational_stiffness": np.array([1.0, 1.0, 100.0]),
    "rotational_stiffness": np.array([0.1, 0.1, 1.0]),
}


def magbotsim_available() -> bool:
    """True when the ``magbotsim`` package (and thus mujoco) can be imported."""
    return importlib.util.find_spec("magbotsim") is not None and importlib.util.find_spec("mujoco") is not None


def magbotsim_version() -> str | None:
    """Installed MagBotSim version (for result rows), None if absent."""
    return common.package_version("magbotsim")


def _tiles(tiles_xy: int | tuple[int, int] | str) -> tuple[int, int]:
    """Accept 57, (57, 57) or "57x57"."""
    if isinstance(tiles_xy, str):
        nx, ny = (int(v) for v in tiles_xy.lower().split("x"))
    elif isinstance(tiles_xy, (int, np.integer)):
        nx = ny = int(tiles_xy)
    else:
        nx, ny = (int(v) for v in tiles_xy)
    if nx < 1 or ny < 1:
        raise ValueError(f"tiles_xy must be positive, got {tiles_xy!r}")
    return nx, ny


# ---------------------------------------------------------------------------------------------------------------
# Construction
# ---------------------------------------------------------------------------------------------------------------

_OBJ_COUNT_FIELD = {  # mjtObj name -> MjModel size field, for the object types extract_mj_names supports
    "mjOBJ_BODY": "nbody", "mjOBJ_JOINT": "njnt", "mjOBJ_GEOM": "ngeom", "mjOBJ_SITE": "nsite",
    "mjOBJ_LIGHT": "nlight", "mjOBJ_CAMERA": "ncam", "mjOBJ_ACTUATOR": "nu", "mjOBJ_SENSOR": "nsensor",
    "mjOBJ_TENDON": "ntendon", "mjOBJ_MESH": "nmesh",
}


def _extract_mj_names_linear(model, obj_type):
    """Same result as ``magbotsim.utils.mujoco_utils.extract_mj_names``, in O(names) instead of O(names^2).

    Returns (names ordered by id, name2id, id2name with None for unnamed objects), like the original.
    """
    import mujoco

    field = _OBJ_COUNT_FIELD.get(mujoco.mjtObj(obj_type).name)
    if field is None:
        raise ValueError(f"unsupported MuJoCo object type {obj_type!r}")
    id2name: dict[int, str | None] = {}
    name2id: dict[str, int] = {}
    for i in range(getattr(model, field)):
        name = mujoco.mj_id2name(model, obj_type, i)
        id2name[i] = name or None
        if name:
            name2id[name] = i
    return tuple(id2name[i] for i in sorted(name2id.values())), name2id, id2name


@contextlib.contextmanager
def fast_name_extraction(enabled: bool = True) -> Iterator[None]:
    """Temporarily replace MagBotSim's quadratic name extraction with the linear equivalent (construction only)."""
    if not enabled:
        yield
        return
    from magbotsim.utils import mujoco_utils

    original = mujoco_utils.extract_mj_names
    mujoco_utils.extract_mj_names = _extract_mj_names_linear
    try:
        yield
    finally:
        mujoco_utils.extract_mj_names = original


def _actuator_xml(num_movers: int, mover_mass: float) -> str:
    """Per mover: x/y acceleration actuators (gain = mass, as in MagBotSim's RL envs) and the four actuators that
    ``MoverImpedanceController.generate_actuator_xml_string`` declares for the z/a/b/c mask (checked after build)."""
    lines = ["\n\t<actuator>"]
    for i in range(num_movers):
        joint = f"mover_joint_{i}"
        for axis, gear in (("x", "1 0 0 0 0 0"), ("y", "0 1 0 0 0 0")):
            lines.append(f'\t\t<general name="mover_actuator_{axis}_{i}" joint="{joint}" gear="{gear}" dyntype="none" '
                         f'gaintype="fixed" gainprm="{mover_mass} 0 0" biastype="none"/>')
        for k, axis in enumerate("zabc", start=2):
            gear = " ".join("1" if j == k else "0" for j in range(6))
            lines.append(f'\t\t<general name="mover_actuator_{axis}_{i}" joint="{joint}" gear="{gear}" '
                         'dyntype="none" gaintype="fixed" biastype="none"/>')
    lines.append("\t</actuator>")
    return "\n".join(lines)


def build_scaling_env(num_movers: int, tiles_xy, shape: str = "circle", c_size=None,
                      fast_construction: bool = True):
    """A headless ``BasicMagBotEnv`` with movers at the tile centres of a full grid, plus one impedance controller per
    mover (as MagBotSim's RL envs build them). Returns (env, controllers)."""
    from magbotsim import BasicMagBotEnv, MoverImpedanceController

    if shape not in DEFAULT_C_SIZE:
        raise ValueError(f"shape must be 'circle' or 'box', got {shape!r}")
    nx, ny = _tiles(tiles_xy)
    if num_movers > nx * ny:
        raise ValueError(f"{num_movers} movers do not fit on {nx}x{ny} tiles (one mover per tile centre)")
    mass = 1.24  # MagBotSim's default mover mass; also its default in BasicMagBotEnv
    actuator_xml = _actuator_xml(num_movers, mass)
    with fast_name_extraction(fast_construction):
        env = BasicMagBotEnv(
            layout_tiles=np.ones((nx, ny), dtype=np.int8),
            num_movers=num_movers,
            mover_params={"mass": mass, "size": MOVER_HALF_SIZE.copy()},
            render_mode=None,
            collision_params={"shape": shape, "size": DEFAULT_C_SIZE[shape] if c_size is None else c_size},
            custom_model_xml_strings={"custom_outworldbody_xml_str": actuator_xml},
        )
    model_lines = {line.strip() for line in actuator_xml.splitlines()}
    controllers = []
    for i, joint_name in enumerate(env.mover_joint_names):
        ctrl = MoverImpedanceController(model=env.model, mover_joint_name=joint_name,
                                        mover_half_height=env.mover_size[i, 2], **CONTROLLER_KW)
        # Declares the controller's actuator names. Its actuators must be exactly the ones already in the model,
        # so the model is the one MagBotSim's RL envs build (they compile twice to get there; we compile once).
        own = [line.strip() for line in ctrl.generate_actuator_xml_string(idx_mover=i).splitlines() if line.strip()]
        if len(own) != 4 or not set(own) <= model_lines:
            raise RuntimeError(f"MagBotSim's impedance actuators changed; expected them in the model: {own}")
        ctrl.update_cached_mujoco_data(env.model)
        controllers.append(ctrl)
    return env, controllers


# ---------------------------------------------------------------------------------------------------------------
# Scaling step
# ---------------------------------------------------------------------------------------------------------------


def _make_step(env, controllers, actions: np.ndarray, use_controllers: bool, counters: dict):
    """The timed step closure: controls for all movers, one mj_step, MagBotSim's wall + mover collision checks,
    with the same arguments its RL envs use every cycle (current qpos, qpos noise on, no safety offset)."""
    import mujoco

    model, data = env.model, env.data
    x_ids = np.array([model.actuator(f"mover_actuator_x_{i}").id for i in range(env.num_movers)])
    y_ids = np.array([model.actuator(f"mover_actuator_y_{i}").id for i in range(env.num_movers)])
    names, c_size = env.mover_names, env.c_size  # the identical list object keeps get_mover_qpos on its fast path
    sizes = env.mover_size

    def step() -> None:
        a = actions[counters["k"] % len(actions)]
        counters["k"] += 1
        data.ctrl[x_ids] = a[:, 0]
        data.ctrl[y_ids] = a[:, 1]
        if use_controllers:  # per-mover Python controllers, as in LongHorizonGlobalTrajectoryPlanningEnv
            for i, ctrl in enumerate(controllers):
                ctrl.update(model=model, data=data,
                            pos_d=np.array([0, 0, env.initial_mover_zpos + sizes[i, 2]]),
                            quat_d=np.array([1, 0, 0, 0]))
        mujoco.mj_step(model, data, nstep=1)
        wall = env.check_wall_collision(mover_names=names, c_size=c_size, add_safety_offset=False,
                                        mover_qpos=None, add_qpos_noise=True).any()
        mover = env.check_mover_collision(mover_names=names, c_size=c_size, add_safety_offset=False,
                                          mover_qpos=None, add_qpos_noise=True)
        counters["collisions"] += int(bool(wall or mover))

    return step


def scaling_step_ms(num_movers: int, tiles_xy, shape: str = "circle", steps: int = 100,
                    controllers: bool = False, warmup: int = 10, seed: int = 0, accel: float = 1.0,
                    c_size=None, fast_construction: bool = True) -> dict[str, Any]:
    """Mean/std ms of one MagBotSim simulation step (paper's scalability test). See the module docstring.

    :param num_movers: movers, one per tile centre (filled in MagBotSim's order)
    :param tiles_xy: tiles per side (int), (nx, ny) or "NxM"
    :param shape: collision shape, 'circle' or 'box'
    :param steps: timed steps (the paper uses 100)
    :param controllers: False = vectorised controls only; True = plus per-mover impedance controllers
    :param warmup: untimed steps first
    :param accel: bound of the random x/y accelerations (m/s^2); small so movers stay near their tiles and the
        collision checks see the paper's configuration (no collisions) throughout
    :param c_size: collision size override (default: DEFAULT_C_SIZE[shape])
    :param fast_construction: build with the linear name lookup (does not change the timed step)
    :return: dict with ms_per_step (= mean_ms), std_ms, median_ms, cpu_mean_ms (process time), construct_s, ...
    """
    import magbotsim  # noqa: F401  (first import takes ~0.4 s; keep it out of construct_s)

    t0 = time.perf_counter()
    env, ctrls = build_scaling_env(num_movers, tiles_xy, shape, c_size, fast_construction)
    construct_s = time.perf_counter() - t0

    rng = np.random.default_rng(seed)
    # Pre-drawn so random number generation is not timed.
    actions = rng.uniform(-accel, accel, size=(warmup + steps, num_movers, 2))
    counters = {"k": 0, "collisions": 0}
    step = _make_step(env, ctrls, actions, controllers, counters)
    wall, cpu = common.time_samples(step, repeats=steps, warmup=warmup)
    mean, std, median = common.summarize_ms(wall)
    nx, ny = _tiles(tiles_xy)
    env.close()
    return {
        # One engine name per plotted series; `variant` says the same in words.
        "engine": "magbotsim-controllers" if controllers else "magbotsim",
        "variant": "controllers" if controllers else "vectorised",
        "device": "cpu",
        "movers": num_movers,
        "tiles": f"{nx}x{ny}",
        "shape": shape,
        "steps": steps,
        "warmup": warmup,
        "ms_per_step": mean,
        "mean_ms": mean,
        "std_ms": std,
        "median_ms": median,
        "min_ms": min(wall),
        "cpu_mean_ms": float(np.mean(cpu)),
        "construct_s": construct_s,
        "fast_construction": fast_construction,
        "collision_steps": counters["collisions"],
        "magbotsim": magbotsim_version(),
    }


# ---------------------------------------------------------------------------------------------------------------
# RL env throughput
# ---------------------------------------------------------------------------------------------------------------

# Values for constructor arguments that have no default in some MagBotSim envs (headless, no extra windows).
_REQUIRED_ARG_VALUES = {"show_2D_plot": False}


def rl_env_kwargs(env_id: str) -> dict[str, Any]:
    """Minimal constructor kwargs for a registered MagBotSim env: render_mode=None plus its required arguments."""
    import gymnasium as gym

    import magbotsim  # noqa: F401  (registers the envs)

    cls = gym.envs.registration.load_env_creator(gym.spec(env_id).entry_point)
    kwargs: dict[str, Any] = {"render_mode": None}
    for name, p in inspect.signature(cls.__init__).parameters.items():
        if name == "self" or p.default is not inspect.Parameter.empty or p.kind in (p.VAR_POSITIONAL, p.VAR_KEYWORD):
            continue
        if name not in _REQUIRED_ARG_VALUES:
            raise ValueError(f"{env_id}: no benchmark value for required constructor argument {name!r}")
        kwargs[name] = _REQUIRED_ARG_VALUES[name]
    return kwargs


def env_steps_per_s(env_id: str, steps: int = 200, warmup: int = 5, seed: int = 0) -> dict[str, Any]:
    """``env.step()`` throughput of a MagBotSim Gymnasium env with random actions; resets on done are timed too.

    Built with ``gymnasium.make`` (so the registered TimeLimit applies) and the passive env checker off (it only
    inspects the first calls). Actions are drawn before the clock starts.

    :return: dict with steps_per_s (wall clock, including resets), cpu_steps_per_s (process time), step_ms_mean/median
        (step calls only), cycles_per_step (MuJoCo steps per env step: 40 unless a collision ends the step early),
        resets, reset_ms_mean, terminated/truncated counts, make_s (construction), ...
    """
    import gymnasium as gym

    import magbotsim  # noqa: F401  (registers the envs)

    kwargs = rl_env_kwargs(env_id)  # also imports magbotsim, outside make_s
    t0 = time.perf_counter()
    env = gym.make(env_id, disable_env_checker=True, **kwargs)
    make_s = time.perf_counter() - t0
    env.action_space.seed(seed)
    actions = [env.action_space.sample() for _ in range(warmup + steps)]
    counts = {"terminated": 0, "truncated": 0}
    step_ms: list[float] = []
    reset_ms: list[float] = []
    with warnings.catch_warnings():
        # MagBotSim warns on slow start-position sampling in resets; the cost stays in the timing, the text does not.
        warnings.simplefilter("ignore")
        env.reset(seed=seed)
        for a in actions[:warmup]:
            _, _, term, trunc, _ = env.step(a)
            if term or trunc:
                env.reset()
        env.reset()  # timed run starts from a fresh episode
        base = env.unwrapped
        cycles = 0  # MuJoCo steps actually run: a step stops its 40-cycle loop early on a collision
        cpu_start, start = time.process_time(), time.perf_counter()
        for a in actions[warmup:]:
            sim_t0 = base.data.time
            t1 = time.perf_counter()
            _, _, term, trunc, _ = env.step(a)
            t2 = time.perf_counter()
            step_ms.append((t2 - t1) * 1e3)
            cycles += round((base.data.time - sim_t0) / base.model.opt.timestep)
            if term or trunc:
                counts["terminated"] += bool(term)
                counts["truncated"] += bool(trunc and not term)
                env.reset()
                reset_ms.append((time.perf_counter() - t2) * 1e3)
        total_s = time.perf_counter() - start
        cpu_s = time.process_time() - cpu_start
    env.close()
    return {
        "engine": "magbotsim",
        "env_id": env_id,
        "device": "cpu",
        "num_envs": 1,
        "steps": steps,
        "steps_per_s": steps / total_s,
        "cpu_steps_per_s": steps / cpu_s if cpu_s > 0 else None,
        "cycles_per_step": cycles / steps,
        "step_ms_mean": float(np.mean(step_ms)),
        "step_ms_median": float(np.median(step_ms)),
        "resets": len(reset_ms),
        "reset_ms_mean": float(np.mean(reset_ms)) if reset_ms else None,
        "terminated": counts["terminated"],
        "truncated": counts["truncated"],
        "resets_timed": True,
        "make_s": make_s,
        "magbotsim": magbotsim_version(),
    }


# ---------------------------------------------------------------------------------------------------------------
# Convenience: the whole paper sweep, and a small CLI for running the reference on its own
# ---------------------------------------------------------------------------------------------------------------


def paper_scaling_rows(configs=PAPER_SCALING_CONFIGS, shapes=("circle", "box"), controllers=(False, True),
                       steps: int = 100, max_movers: int | None = None, verbose: bool = False) -> list[dict[str, Any]]:
    """scaling_step_ms over the paper's (movers, tiles) configs x shapes x variants; max_movers trims the sweep."""
    rows = []
    for movers, tiles in configs:
        if max_movers is not None and movers > max_movers:
            continue
        for shape in shapes:
            for ctrl in controllers:
                rows.append(scaling_step_ms(movers, tiles, shape, steps=steps, controllers=ctrl))
                if verbose:
                    r = rows[-1]
                    print(f"  {r['engine']:22s} {movers:5d} movers {r['tiles']:>6s} {shape:6s} "
                          f"{r['ms_per_step']:9.3f} ms (std {r['std_ms']:.3f}, built in {r['construct_s']:.2f} s)",
                          flush=True)
    return rows


def main(argv: list[str] | None = None) -> int:
    """python benchmarks/magbotsim_ref.py [--max-movers N] [--steps S] [--env-steps E] [--json PATH]"""
    import argparse

    parser = argparse.ArgumentParser(description=main.__doc__)
    parser.add_argument("--max-movers", type=int, default=50, help="largest paper config to run (1000 = all)")
    parser.add_argument("--steps", type=int, default=100, help="timed simulation steps per config (paper: 100)")
    parser.add_argument("--env-steps", type=int, default=100, help="timed env.step() calls per RL env (0: skip)")
    parser.add_argument("--json", help="write all rows and the machine info to this file")
    args = parser.parse_args(argv)
    if not magbotsim_available():
        print("magbotsim is not installed: nothing to measure")
        return 1
    info = common.machine_info("cpu")
    print(common.markdown_header(info))
    rows = paper_scaling_rows(steps=args.steps, max_movers=args.max_movers, verbose=True)
    common.print_table(rows, ["engine", "movers", "tiles", "shape", ("ms_per_step", "ms/step"), ("std_ms", "std"),
                              ("cpu_mean_ms", "cpu ms"), ("construct_s", "build s"), "collision_steps"])
    env_rows = [env_steps_per_s(e, steps=args.env_steps) for e in RL_ENV_IDS] if args.env_steps > 0 else []
    if env_rows:
        print()
        common.print_table(env_rows, ["env_id", "steps", "steps_per_s", "cpu_steps_per_s", "step_ms_median",
                                           "cycles_per_step", "resets", "reset_ms_mean"])
    if args.json:
        common.write_json(args.json, {"machine": info, "scaling": rows, "env_throughput": env_rows})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
