"""inspect.stack() for building nerfstudio's method list in tests: the same frames and ``.function`` names, without
looking up each frame's source file.

nerfstudio 1.1.5's ExternalMethodDummyTrainerConfig.__post_init__ reads ``inspect.stack()[2].function`` 26 times
while nerfstudio.configs.method_configs is imported. The real stack() resolves every frame's source file through
inspect.getmodule, which scans all ~4,000 loaded modules per frame (~5 s of CPU on the 2-core box, more under pytest's
deep stack), and reads source lines nobody reads. The branch nerfstudio takes depends on ``.function`` only."""
from __future__ import annotations

import inspect
import sys


def stack_without_sources(context: int = 1) -> list:
    """inspect.stack()'s frames, caller first, as FrameInfo with the frame's code filename and no source lines."""
    frames, f = [], sys._getframe(1)
    while f is not None:
        frames.append(inspect.FrameInfo(f, f.f_code.co_filename, f.f_lineno, f.f_code.co_name, None, None))
        f = f.f_back
    return frames
