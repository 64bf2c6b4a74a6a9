"""The trained policies shipped with magwarp (package data in ``magwarp/pretrained/``), by name.

    magwarp eval magwarp/PushBox-v0 --policy pretrained:pushbox_sac --episodes 200 --repeats 100
    magwarp export pretrained:b0_ppo --onnx b0.onnx

    from magwarp.training import load_pretrained
    policy = load_pretrained("pushbox_sac", device="cuda:0")     # policy(obs) -> actions (TorchScript)

How each one was trained and what it reaches: ``magwarp/pretrained/README.md``.
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["PREFIX", "pretrained_names", "pretrained_path", "resolve_policy", "load_pretrained"]

PREFIX = "pretrained:"
FOLDER = Path(__file__).resolve().parent.parent / "pretrained"


def pretrained_names() -> list[str]:
    """The shipped policies' names (``b0_ppo``, ``pushbox_sac``, ...)."""
    return sorted(p.stem for p in FOLDER.glob("*.pt"))


def pretrained_path(name: str) -> str:
    """The file of the shipped policy ``name`` (``pretrained:`` prefix and ``.pt`` suffix optional)."""
    stem = name[len(PREFIX):] if name.startswith(PREFIX) else name
    stem = stem[:-3] if stem.endswith(".pt") else stem
    path = FOLDER / f"{stem}.pt"
    if not stem or "/" in stem or "\\" in stem or not path.is_file():
        raise ValueError(f"no pretrained policy {name!r}; shipped: {', '.join(pretrained_names()) or 'none'}")
    return str(path)


def resolve_policy(spec: str) -> str:
    """``pretrained:NAME`` -> the shipped file's path; any other policy spec is returned unchanged."""
    return pretrained_path(spec) if isinstance(spec, str) and spec.startswith(PREFIX) else spec


def load_pretrained(name: str, device="cpu"):
    """The shipped policy ``name`` as a module (:func:`magwarp.training.policy.load_policy`)."""
    from magwarp.training.policy import load_policy

    return load_policy(pretrained_path(name), device)
