"""Markdown tables for RESULTS.md from the JSON that the benchmark scripts write (``--json``).

    python benchmarks/report.py benchmarks/results/*.json > /tmp/tables.md

Every table carries where its numbers come from: device, date, versions, commit and the exact command.
"""

from __future__ import annotations

import json
import sys
from collections import OrderedDict


def _fmt(v) -> str:
    if v is None:
        return "-"
    if isinstance(v, float):
        if v >= 1e6:
            return f"{v / 1e6:,.1f} M"
        if v >= 100:
            return f"{v:,.0f}"
        return f"{v:.4g}"
    return str(v)


def _provenance(rows: list[dict]) -> str:
    r = rows[0]
    v = r.get("versions", {})
    versions = ", ".join(f"{k} {v[k]}" for k in ("warp-lang", "torch", "mujoco-warp", "mujoco", "magbotsim", "python")
                         if v.get(k))
    return (f"*{r.get('device_name')}, {r.get('date_utc')}, {versions}, commit {r.get('commit') or '?'}.*  \n"
            f"*Command: `{r.get('command')}`*\n")


def table(rows: list[dict], columns: list[tuple[str, str]]) -> str:
    head = "| " + " | ".join(h for _, h in columns) + " |\n|" + "---|" * len(columns) + "\n"
    body = "".join("| " + " | ".join(_fmt(r.get(k)) for k, _ in columns) + " |\n" for r in rows)
    return head + body


def scaling_tables(rows: list[dict]) -> str:
    one = [r for r in rows if r.get("worlds", 1) == 1]
    out = _provenance(rows) + "\n"
    # One row per (movers, shape): engines side by side.
    grid: "OrderedDict[tuple, dict]" = OrderedDict()
    for r in sorted(one, key=lambda r: (r["shape"], r["movers"])):
        key = (r["shape"], r["movers"], r["tiles"])
        name = r["engine"] if r["engine"] != "magwarp" else f"magwarp {r['device']}"
        grid.setdefault(key, {"shape": key[0], "movers": key[1], "tiles": key[2]})[name] = r["ms_per_step"] * 1e3
    engines = sorted({k for g in grid.values() for k in g if k not in ("shape", "movers", "tiles")})
    cols = [("shape", "shape"), ("movers", "movers"), ("tiles", "tiles")] + [(e, f"{e} (µs/step)") for e in engines]
    rows_out = list(grid.values())
    for g in rows_out:
        for ref in ("magbotsim", "magbotsim-controllers"):
            for e in engines:
                if e.startswith("magwarp") and g.get(ref) and g.get(e):
                    g[f"x {ref} / {e}"] = g[ref] / g[e]
    extra = sorted({k for g in rows_out for k in g if k.startswith("x ")})
    out += table(rows_out, cols + [(k, k.replace("x ", "speed-up vs ")) for k in extra])
    small = [r for r in rows if r.get("worlds", 1) > 1]
    if small:
        out += "\nMany small worlds (one step = 40 cycles of 1 ms):\n\n"
        out += table([{**r, "us": r["ms_per_step"] * 1e3} for r in small],
                     [("device", "device"), ("worlds", "worlds"), ("movers", "movers per world"), ("tiles", "layout"),
                      ("cycles", "cycles"), ("us", "µs per step")])
    return out


def env_tables(rows: list[dict]) -> str:
    out = _provenance(rows) + "\n"
    cols = [("engine", "engine"), ("env", "env"), ("device", "device"), ("num_envs", "num_envs"),
            *([("solver", "solver")] if any(r.get("solver") for r in rows) else []), ("adapter", "adapter"), ("check_inputs", "check_inputs"), ("step_ms", "ms/step"),
            ("sim_ms", "physics ms"), ("raw_mjw_ms", "raw mujoco-warp ms"), ("x_raw_mjw", "x raw"),
            ("env_steps_per_s", "env-steps/s")]
    return out + table(rows, cols)


def age_tables(rows: list[dict]) -> str:
    """collisions_by_age.py: one table per policy, its rows the age bins."""
    from collisions_by_age import AGE_COLUMNS  # beside this file; imports nothing heavy at module level

    out = _provenance(rows) + f"\n*{rows[0]['num_envs']} worlds x {rows[0]['total_steps']} steps per policy.*\n"
    for policy in dict.fromkeys(r["policy"] for r in rows):
        out += f"\n`{policy}`:\n\n" + table([r for r in rows if r["policy"] == policy], AGE_COLUMNS)
    return out


def eval_table(result: dict) -> str:
    """A ``magwarp eval --json`` result as the paper's table: metric, n, mean ± std over repeats."""
    head = (f"*{result['env_id']}, policy `{result['policy']}`, {result['repeats']} repeats x {result['episodes']} "
            f"{'episodes' if result['family'] == 'push' else 'worlds'}, {result['device']}, "
            f"{result['wall_s']:.1f} s wall-clock.*\n\n")
    rows = []
    for r in result["rows"]:
        mean, std = r.get("mean"), r.get("std")
        value = "---" if mean is None else f"{mean:.4g} ± {std:.3g}"
        rows.append({"label": r["label"], "n": r.get("n"), "value": value})
    return head + table(rows, [("label", "Metric"), ("n", "n"), ("value", "mean ± std")])


def eval_summary(results: list[dict]) -> str:
    """One row per ``magwarp eval`` result: success, throughput and collisions (mean ± std over repeats)."""
    rows = []
    for res in results:
        by_key = {r["key"]: r for r in res["rows"]}

        def cell(key):
            r = by_key.get(key)
            return "-" if r is None or r.get("mean") is None else f"{r['mean']:.4g} ± {r['std']:.2g}"

        rows.append({"env": res["env_id"].removeprefix("magwarp/"), "device": res["device"],
                     "runs": f"{res['repeats']} x {res['episodes']}", "success": cell("success_rate"),
                     "throughput": cell("throughput"),
                     "collisions": cell("collisions") if "collisions" in by_key else cell("collisions_per_1k"),
                     "wall": f"{res['wall_s']:.1f}"})
    return table(rows, [("env", "env"), ("device", "device"), ("runs", "repeats x episodes"),
                        ("success", "success rate (%)"), ("throughput", "throughput (goals/s)"),
                        ("collisions", "collisions*"), ("wall", "wall-clock (s)")])


_PROVENANCE_KEYS = ("device_name", "cpu", "date_utc", "versions", "command", "commit", "info", "provenance",
                    "machine", "platform", "cpu_count", "argv")


def generic_tables(data) -> str:
    """Any other benchmark JSON (swarm, collision queries, magnetics, MagBots, distributed, soak): its provenance,
    then one table per list of rows (all columns but the provenance ones) and one row per summary dict."""
    if isinstance(data, list):
        data = {"rows": data}
    prov = next((data[k] for k in ("provenance", "machine", "info", "summary") if isinstance(data.get(k), dict)
                 and "command" in data[k]), None)
    if prov is None:
        prov = next((v[0] for v in data.values() if isinstance(v, list) and v and isinstance(v[0], dict)
                     and "command" in v[0]), {})
    out = _provenance([prov]) + "\n"
    for key, value in data.items():
        if isinstance(value, dict) and key == "summary":
            value = [value]
        if not (isinstance(value, list) and value and isinstance(value[0], dict)):
            continue
        columns = [c for c in OrderedDict.fromkeys(k for r in value for k in r) if c not in _PROVENANCE_KEYS
                   and not isinstance(value[0].get(c), (dict, list))]
        out += ("" if key == "rows" else f"**{key}**\n\n") + table(value, [(c, c) for c in columns]) + "\n"
    return out


def main(paths: list[str]) -> int:
    if paths and paths[0] == "--eval-summary":
        print(eval_summary([json.load(open(p)) for p in paths[1:]]))
        return 0
    for path in paths:
        with open(path) as f:
            rows = json.load(f)
        if not rows:
            continue
        print(f"### `{path}`\n")
        if isinstance(rows, dict) and "rows" in rows and "env_id" in rows:
            print(eval_table(rows))
        elif isinstance(rows, dict):
            print(generic_tables(rows))
        elif "age_bin" in rows[0]:
            print(age_tables(rows))
        elif "ms_per_step" in rows[0] and "movers" in rows[0]:
            print(scaling_tables(rows))
        elif "env" in rows[0] and "step_ms" in rows[0] and "adapter" in rows[0]:
            print(env_tables(rows))
        else:
            print(generic_tables(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
