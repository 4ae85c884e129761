"""What every benchmark shares: the device label of a result and appending it to benchmarks/RESULTS.md."""
from __future__ import annotations

from pathlib import Path

import torch

RESULTS = Path(__file__).resolve().parent / "RESULTS.md"


def device_name(device: str | torch.device) -> str:
    """'NVIDIA H100 80GB HBM3' on CUDA; 'CPU <model name> (<n> torch threads)' otherwise."""
    device = torch.device(device)
    if device.type == "cuda" and torch.cuda.is_available():
        return torch.cuda.get_device_name(device)
    try:
        model = next(ln.split(":", 1)[1].strip() for ln in open("/proc/cpuinfo") if ln.startswith("model name"))
    except (OSError, StopIteration):
        model = "cpu"
    return f"CPU {model} ({torch.get_num_threads()} torch threads)"


def append_results(text: str, path: Path = RESULTS) -> Path:
    """Append a result block (markdown) to RESULTS.md and say so."""
    with open(path, "a") as f:
        f.write("\n" + text.rstrip("\n") + "\n")
    print(f"appended to {path}")
    return path
