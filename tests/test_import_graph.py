"""The package's import graph flows one way (layout -> Model/State -> kernels -> Simulator -> envs -> adapters, with
policies above the envs): no two modules import each other, type-checking and function-level imports included, beyond
the pairs listed here (each to be broken when its files are next changed)."""

from __future__ import annotations

import ast
import pathlib

import magwarp

#: module pairs that still import each other (sorted names)
KNOWN = {
    ("magwarp.envs.coop_push", "magwarp.policies.coop_push"),
    ("magwarp.envs.trajectory", "magwarp.envs.trajectory_fused"),
    ("magwarp.swarm.env", "magwarp.swarm.planner"),
    ("magwarp.swarm.env", "magwarp.swarm.views"),
    ("magwarp.training.export", "magwarp.training.twincat"),
}


def _modules() -> dict[str, pathlib.Path]:
    root = pathlib.Path(magwarp.__file__).parent
    out = {}
    for f in root.rglob("*.py"):
        parts = ("magwarp", *f.relative_to(root).with_suffix("").parts)
        out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = f
    return out


def _imports(mods: dict[str, pathlib.Path]) -> dict[str, set[str]]:
    def resolve(name: str) -> str | None:
        while name and name not in mods:
            name = name.rpartition(".")[0]
        return name or None

    edges: dict[str, set[str]] = {}
    for m, f in mods.items():
        targets = set()
        for node in ast.walk(ast.parse(f.read_text())):
            if isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").startswith("magwarp"):
                targets |= {resolve(f"{node.module}.{a.name}") or resolve(node.module) for a in node.names}
            elif isinstance(node, ast.Import):
                targets |= {resolve(a.name) for a in node.names if a.name.startswith("magwarp")}
        edges[m] = {t for t in targets if t and t != m}
    return edges


def test_no_new_pair_of_modules_imports_each_other():
    mods = _modules()
    edges = _imports(mods)
    packages = {m for m, f in mods.items() if f.name == "__init__.py"}
    pairs = {tuple(sorted((a, b))) for a, targets in edges.items() for b in targets
             if a in edges.get(b, ()) and a not in packages and b not in packages}
    assert pairs - KNOWN == set(), f"modules that import each other: {sorted(pairs - KNOWN)}"
    assert KNOWN - pairs == set(), f"broken circles still listed as known (drop them): {sorted(KNOWN - pairs)}"


def test_policies_planner_and_layout_stay_one_way():
    """The two circles the design notes named: the planner reads its env structurally, the reference imports the
    layout and not the reverse."""
    edges = _imports(_modules())
    assert "magwarp.envs.trajectory" not in edges["magwarp.policies.planner"]
    assert "magwarp.reference" not in edges["magwarp.layout"]
