"""Shared test setup: a git-ignored Warp kernel cache, quiet Warp, a fresh random seed per test (printed on
failure) and the list of devices to run device-parametrised tests on."""

from __future__ import annotations

import os
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
# Must be set before warp is imported anywhere: the cache path is read when warp initialises.
os.environ.setdefault("WARP_CACHE_PATH", str(REPO / ".warp_cache"))

import numpy as np  # noqa: E402
import pytest  # noqa: E402
import warp as wp  # noqa: E402

wp.config.quiet = True


class SeededRNG(np.random.Generator):
    """A numpy Generator that remembers its seed; ``str(rng)`` reads ``seed=<n>`` for assert messages."""

    def __init__(self, seed: int):
        super().__init__(np.random.PCG64(seed))
        self.seed = seed

    def __str__(self) -> str:
        return f"seed={self.seed}"

    __repr__ = __str__


@pytest.fixture
def rng(request) -> SeededRNG:
    """A generator with a fresh seed per run; set MAGWARP_TEST_SEED to replay a failure."""
    env = os.environ.get("MAGWARP_TEST_SEED")
    seed = int(env) if env else int(np.random.SeedSequence().entropy % (2**63))
    gen = SeededRNG(seed)
    yield gen
    if getattr(request.node, "rep_call", None) is not None and request.node.rep_call.failed:
        print(f"\n[{request.node.nodeid}] random seed: MAGWARP_TEST_SEED={seed}")


@pytest.hookimpl(wrapper=True, tryfirst=True)
def pytest_runtest_makereport(item, call):
    rep = yield
    if rep.when == "call":
        item.rep_call = rep
        seed = getattr(item.funcargs.get("rng"), "seed", None) if hasattr(item, "funcargs") else None
        if rep.failed and seed is not None:
            rep.sections.append(("random seed", f"replay with MAGWARP_TEST_SEED={seed}"))
    return rep


def cuda_available() -> bool:
    wp.init()
    return wp.is_cuda_available()


@pytest.fixture(scope="session")
def devices() -> list[str]:
    """``["cpu"]`` plus ``"cuda:0"`` when Warp sees a GPU."""
    return ["cpu"] + (["cuda:0"] if cuda_available() else [])
