"""Shared plumbing for the benchmark scripts: machine info, timing, tables, JSON and the RESULTS.md header.

Everything here is dependency-light on purpose (stdlib + numpy): the scripts import it before they know whether
warp, torch or magbotsim are installed, and the header of every result must say which versions produced it.
"""

from __future__ import annotations

import datetime as _dt
import importlib.metadata as _md
import json
import math
import os
import platform
import shlex
import statistics
import subprocess
import sys
import time
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

# Distribution names whose versions every result records (import name differs for some: warp-lang -> warp).
VERSIONED_PACKAGES = ("warp-lang", "torch", "mujoco", "mujoco-warp", "magbotsim", "numpy", "gymnasium")


def package_version(dist: str) -> str | None:
    """Installed version of a distribution, or None; reads metadata so nothing heavy (warp, torch) gets imported."""
    try:
        return _md.version(dist)
    except _md.PackageNotFoundError:
        return None


def cpu_name() -> str:
    """CPU model from /proc/cpuinfo (Linux); falls back to platform.processor() elsewhere."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                if line.lower().startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine() or "unknown CPU"


def gpu_name(device: str) -> str:
    """Name of a CUDA device ("cuda", "cuda:1"): torch first (cheap when imported anyway), then warp."""
    index = int(device.split(":", 1)[1]) if ":" in device else 0
    try:
        import torch

        if torch.cuda.is_available():
            return torch.cuda.get_device_name(index)
    except Exception:  # torch missing or built without CUDA: try warp
        pass
    try:
        import warp as wp

        return wp.get_device(f"cuda:{index}").name
    except Exception:
        return f"unknown CUDA device ({device})"


def git_commit(repo: str | os.PathLike | None = None) -> str | None:
    """Short commit of the checkout that ran the benchmark, with '+dirty' when it has local changes.

    ``MAGWARP_COMMIT`` wins when set: a copy of the tree on a remote machine may carry a stale ``.git``."""
    if os.environ.get("MAGWARP_COMMIT"):
        return os.environ["MAGWARP_COMMIT"]
    repo = Path(repo) if repo else Path(__file__).resolve().parent.parent
    try:
        sha = subprocess.run(["git", "-C", str(repo), "rev-parse", "--short", "HEAD"],
                             capture_output=True, text=True, timeout=10, check=True).stdout.strip()
        dirty = subprocess.run(["git", "-C", str(repo), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=10).stdout.strip()
        return sha + ("+dirty" if dirty else "")
    except Exception:
        # A copy of the tree without .git (e.g. on a remote GPU machine): the caller may name the commit.
        return os.environ.get("MAGWARP_COMMIT")


def machine_info(device: str = "cpu") -> dict[str, Any]:
    """Everything a result needs to be reproduced: device name, date (UTC), versions, command line.

    :param device: "cpu" or a CUDA device string; decides whether the CPU model or the GPU name is recorded.
    """
    on_gpu = str(device).startswith("cuda")
    versions = {"python": platform.python_version()}
    versions.update({dist: package_version(dist) for dist in VERSIONED_PACKAGES})
    return {
        "device": str(device),
        "device_name": gpu_name(str(device)) if on_gpu else cpu_name(),
        "cpu": cpu_name(),
        "cpu_count": os.cpu_count(),
        "platform": platform.platform(),
        "date_utc": _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M:%S UTC"),
        "versions": versions,
        "argv": list(sys.argv),
        "command": command_line(),
        "commit": git_commit(),
    }


def provenance(info: dict[str, Any]) -> dict[str, Any]:
    """The fields of :func:`machine_info` that every result row carries (what reproduces it)."""
    return {k: info[k] for k in ("device_name", "cpu", "date_utc", "versions", "command", "commit")}


def header_line(info: dict[str, Any]) -> str:
    """One line naming date, device, versions and command, printed above a benchmark's table."""
    v = info["versions"]
    return (f"# {info['date_utc']}  {info['device_name']}  warp {v.get('warp-lang')}  torch {v.get('torch')}  "
            f"command: {info['command']}")


def start_run(device: str | None) -> tuple[dict[str, Any], list[str]]:
    """A benchmark's opening: Warp quiet, torch on one thread (Warp's CPU kernels are single-threaded; keep torch from
    competing for the cores), the machine info printed as the header line; returns the info and the devices to run
    (``device``, or the CPU plus ``cuda:0`` when present)."""
    import torch
    import warp as wp

    wp.config.quiet = True
    torch.set_num_threads(1)
    info = machine_info(device or "cpu")
    print(header_line(info))
    return info, [device] if device else (["cpu", "cuda:0"] if wp.is_cuda_available() else ["cpu"])


def finish(rows: list[dict[str, Any]], columns: Sequence[str | tuple[str, str]], info: dict[str, Any],
           json_path: str | None) -> int:
    """A benchmark's closing: print the table, write the rows with their provenance to ``json_path`` (if given)."""
    print_table(rows, columns)
    if json_path:
        stamp = provenance(info)
        write_json(json_path, [{**r, **stamp} for r in rows])
    return 0


def command_line(argv: Sequence[str] | None = None) -> str:
    """The exact command as a copy-pastable shell line (python + sys.argv)."""
    argv = list(sys.argv if argv is None else argv)
    return shlex.join(["python", *argv])


def _to_jsonable(obj: Any) -> Any:
    """json.dump fallback for numpy scalars/arrays and paths, which benchmark rows often contain."""
    if hasattr(obj, "tolist"):
        return obj.tolist()
    if hasattr(obj, "item"):
        return obj.item()
    if isinstance(obj, os.PathLike):
        return os.fspath(obj)
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


def write_json(path: str | os.PathLike, rows: Any) -> Path:
    """Write rows (usually a list of dicts) as indented JSON, creating parent folders; returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", encoding="utf-8") as f:
        json.dump(rows, f, indent=2, default=_to_jsonable)
        f.write("\n")
    return path


def read_json(path: str | os.PathLike) -> Any:
    """Counterpart of write_json (for tests and for scripts that merge earlier runs)."""
    with open(path, encoding="utf-8") as f:
        return json.load(f)


def format_value(value: Any) -> str:
    """Compact cell text: floats get 4 significant digits (no exponent for everyday magnitudes), None is '-'."""
    if value is None:
        return "-"
    if isinstance(value, bool):
        return str(value)
    if isinstance(value, float) or type(value).__name__.startswith("float"):
        value = float(value)
        if math.isnan(value) or math.isinf(value):
            return str(value)
        if value != 0 and (abs(value) >= 1e6 or abs(value) < 1e-3):
            return f"{value:.3e}"
        return f"{value:.4g}" if abs(value) < 1e4 else f"{value:.0f}"
    return str(value)


def format_table(rows: Iterable[dict[str, Any]], columns: Sequence[str | tuple[str, str]]) -> str:
    """Aligned plain-text table. Columns are keys or (key, header) pairs; numbers right-, text left-aligned."""
    cols = [(c, c) if isinstance(c, str) else (c[0], c[1]) for c in columns]
    rows = list(rows)
    cells = [[format_value(r.get(key)) for key, _ in cols] for r in rows]
    numeric = [all(isinstance(r.get(key), (int, float)) or r.get(key) is None or hasattr(r.get(key), "dtype")
                   for r in rows) for key, _ in cols]
    widths = [max([len(h)] + [len(row[i]) for row in cells]) for i, (_, h) in enumerate(cols)]

    def line(values: Sequence[str]) -> str:
        return "  ".join(v.rjust(w) if num else v.ljust(w) for v, w, num in zip(values, widths, numeric)).rstrip()

    out = [line([h for _, h in cols]), "  ".join("-" * w for w in widths)]
    out += [line(row) for row in cells]
    return "\n".join(out)


def print_table(rows: Iterable[dict[str, Any]], columns: Sequence[str | tuple[str, str]], file=None) -> str:
    """Print format_table(rows, columns) and return the text (so scripts can also put it in RESULTS.md)."""
    text = format_table(rows, columns)
    print(text, file=file or sys.stdout, flush=True)
    return text


def time_samples(fn: Callable[[], Any], repeats: int, warmup: int = 0,
                 sync: Callable[[], Any] | None = None) -> tuple[list[float], list[float]]:
    """Per-call wall and process (CPU) times in ms of `repeats` calls of fn, after `warmup` untimed calls.

    `sync` (e.g. ``wp.synchronize_device``) runs before the clock starts and inside the timed region after each
    call, so asynchronous GPU work is charged to the call that launched it. Process time is recorded too because
    on a shared CPU it is less disturbed by other users than wall time (the MagBotSim paper reports process time).
    """
    if repeats < 1:
        raise ValueError(f"repeats must be >= 1, got {repeats}")
    for _ in range(warmup):
        fn()
    if sync is not None:
        sync()
    wall, cpu = [], []
    for _ in range(repeats):
        c0, t0 = time.process_time(), time.perf_counter()
        fn()
        if sync is not None:
            sync()
        t1, c1 = time.perf_counter(), time.process_time()
        wall.append((t1 - t0) * 1e3)
        cpu.append((c1 - c0) * 1e3)
    return wall, cpu


def summarize_ms(samples: Sequence[float]) -> tuple[float, float, float]:
    """(mean, population std, median) of timing samples in ms."""
    return statistics.fmean(samples), statistics.pstdev(samples), statistics.median(samples)


def time_call(fn: Callable[[], Any], repeats: int, warmup: int = 0,
              sync: Callable[[], Any] | None = None) -> tuple[float, float, float]:
    """Wall-clock (time.perf_counter) cost of one call of fn: (mean_ms, std_ms, median_ms). See time_samples."""
    wall, _ = time_samples(fn, repeats, warmup, sync)
    return summarize_ms(wall)


def sync_device(device: str) -> None:
    """Wait for a CUDA device's queued torch/Warp work (Warp launches on torch's stream here); nothing on the CPU."""
    if device.startswith("cuda"):
        import torch

        torch.cuda.synchronize(torch.device(device))


def batched_ms(fn: Callable[[], Any], device: str, calls: int, samples: int = 5, warmup: int = 3) -> float:
    """Median over ``samples`` of the wall-clock ms per call of ``calls`` back-to-back calls of ``fn`` (the device
    synchronised once per sample, not after each call: the launches' own cost, not the host's round trips)."""
    for _ in range(warmup):
        fn()
    sync_device(device)
    out = []
    for _ in range(samples):
        t = time.perf_counter()
        for _ in range(calls):
            fn()
        sync_device(device)
        out.append((time.perf_counter() - t) / calls * 1e3)
    return statistics.median(out)


def markdown_header(info: dict[str, Any]) -> str:
    """Device/date/versions/command block that heads every section of benchmarks/RESULTS.md."""
    versions = ", ".join(f"{name} {ver}" for name, ver in info.get("versions", {}).items() if ver)
    lines = [
        f"- **Device:** {info.get('device_name', '?')} (`{info.get('device', '?')}`"
        + (f", {info['cpu_count']} CPU cores" if info.get("cpu_count") else "") + ")",
        f"- **Date:** {info.get('date_utc', '?')}",
        f"- **Versions:** {versions or '?'}",
        f"- **Command:** `{info.get('command') or command_line(info.get('argv', []))}`",
    ]
    if info.get("commit"):
        lines.append(f"- **Commit:** `{info['commit']}`")
    return "\n".join(lines) + "\n"
