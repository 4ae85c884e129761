"""The ``ffmpeg`` console script this package installs: runs the imageio-ffmpeg wheel's bundled ffmpeg.

Stock ``ns-render`` checks for ``ffmpeg`` on PATH (nerfstudio utils/install_checks.check_ffmpeg_installed,
shutil.which) and mediapy writes its videos through the ``ffmpeg`` it finds on PATH, so a machine without a
system ffmpeg can still write mp4s once the environment's bin folder is on PATH. Kept free of heavy imports:
it starts on every ffmpeg call.

ffmpeg 7 removed ``-vsync`` (mediapy 1.2's reader still passes it); it is rewritten to ``-fps_mode`` (ffmpeg >= 5.1).
"""
from __future__ import annotations

import os
import sys
from typing import List, Optional, Sequence


def bundled_ffmpeg() -> str:
    """Path of the imageio-ffmpeg wheel's ffmpeg binary (raises RuntimeError when the wheel has none)."""
    import imageio_ffmpeg

    return imageio_ffmpeg.get_ffmpeg_exe()


VSYNC_TO_FPS_MODE = {"0": "passthrough", "1": "cfr", "2": "vfr", "-1": "auto"}


def translate_args(args: Sequence[str]) -> List[str]:
    """Arguments for the bundled ffmpeg: ``-vsync X`` becomes ``-fps_mode X`` (numeric modes by name)."""
    out: List[str] = []
    i = 0
    while i < len(args):
        if args[i] == "-vsync" and i + 1 < len(args):
            out += ["-fps_mode", VSYNC_TO_FPS_MODE.get(args[i + 1], args[i + 1])]
            i += 2
        else:
            out.append(args[i])
            i += 1
    return out


def binary_version(exe: str) -> Optional[tuple]:
    """(major, minor) of an imageio-ffmpeg binary from its file name ('ffmpeg-linux64-v4.2.2',
    'ffmpeg-linux-x86_64-v9.0.2'), else from imageio_ffmpeg.get_ffmpeg_version(); None when neither says."""
    import re

    m = re.search(r"-v(\d+)\.(\d+)", os.path.basename(exe))
    if m is None:
        try:
            import imageio_ffmpeg

            m = re.match(r"(\d+)\.(\d+)", imageio_ffmpeg.get_ffmpeg_version())
        except Exception:  # noqa: BLE001 - unknown version: pass the arguments through unchanged
            return None
    return (int(m.group(1)), int(m.group(2))) if m else None


def main(argv: Optional[Sequence[str]] = None) -> None:
    """Replace this process with the bundled ffmpeg, passing the arguments through (os.execv); ``-vsync`` becomes
    ``-fps_mode`` only for an ffmpeg that has it (>= 5.1; 7 removed -vsync, 4.x does not know -fps_mode)."""
    args = list(sys.argv[1:] if argv is None else argv)
    try:
        exe = bundled_ffmpeg()
    except (ImportError, RuntimeError) as e:
        print(f"ffmpeg (cinenerf_ns): no bundled ffmpeg: {e} (pip install imageio-ffmpeg)", file=sys.stderr)
        raise SystemExit(127)
    version = binary_version(exe)
    if version is not None and version >= (5, 1):
        args = translate_args(args)
    sys.stdout.flush()
    sys.stderr.flush()
    os.execv(exe, [exe, *args])


if __name__ == "__main__":
    main()


def ensure_on_path() -> bool:
    """Put this environment's bin folder (where pip installed the ``ffmpeg`` script) on PATH when no ffmpeg is found
    there: ``.venv/bin/ns-render`` run without activating the venv then still passes nerfstudio's ffmpeg check and
    mediapy finds the same binary. Returns whether an ffmpeg is on PATH afterwards."""
    import shutil

    if shutil.which("ffmpeg"):
        return True
    here = os.path.dirname(os.path.abspath(sys.executable))
    if os.path.isfile(os.path.join(here, "ffmpeg")) and os.access(os.path.join(here, "ffmpeg"), os.X_OK):
        os.environ["PATH"] = here + os.pathsep + os.environ.get("PATH", "")
    return shutil.which("ffmpeg") is not None
