"""Shared pytest set-up: GPU / fox-data markers skip with a reason when unavailable."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
FOX = Path(os.environ.get("CINENERF_FOX", REPO.parent / "shared" / "data" / "fox"))
FOX_SPLAT = Path(os.environ.get("CINENERF_FOX_SPLAT",
                                REPO.parent / "shared" / "data" / "fox_cinesplat" / "fox3000.npz"))  # trained fox


def _cuda() -> bool:
    try:
        import torch

        return torch.cuda.is_available()
    except Exception:  # pragma: no cover
        return False


def pytest_collection_modifyitems(config, items):
    has_cuda = _cuda()
    has_fox = (FOX / "transforms.json").exists()
    for item in items:
        # `make test` runs pytest-xdist workers; tests that bind a port (their module defines free_port) share one
        # worker so two workers never race for the same free port
        if getattr(getattr(item, "module", None), "free_port", None) is not None:
            item.add_marker(pytest.mark.xdist_group("ports"))
        if "gpu" in item.keywords and not has_cuda:
            item.add_marker(pytest.mark.skip(reason="needs a CUDA device (run scripts/gpu_check.sh on a GPU machine)"))
        if "fox" in item.keywords and not has_fox:
            item.add_marker(pytest.mark.skip(reason=f"sample scene not found at {FOX} "
                                             "(../shared/data/fox beside the checkout)"))


@pytest.fixture(scope="session")
def fox_dir() -> Path:
    return FOX


@pytest.fixture(scope="session")
def fox_splat() -> Path:
    """../shared/data/fox_cinesplat/fox3000.npz, a real capture's compact export (skips when it is absent)."""
    if not FOX_SPLAT.exists():
        pytest.skip(f"real-capture splat not found at {FOX_SPLAT} (../shared/data beside the checkout)")
    return FOX_SPLAT
