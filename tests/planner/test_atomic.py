"""The one atomic writer: all or nothing, 0644, the old file kept on failure."""
import os
import stat
from unittest import mock

import pytest

from cinenerf_ns.planner.atomic import atomic_open, atomic_write


@pytest.mark.parametrize("data", ["text ✓", b"\x00\x01bytes"])
def test_writes_text_and_bytes_with_mode_0644(tmp_path, data):
    p = atomic_write(tmp_path / "sub" / "f", data)
    assert (p.read_bytes() if isinstance(data, bytes) else p.read_text(encoding="utf-8")) == data
    assert stat.S_IMODE(os.stat(p).st_mode) == 0o644


def test_failure_keeps_the_old_file_and_leaves_no_temp(tmp_path):
    p = tmp_path / "f"
    p.write_text("old")
    with pytest.raises(RuntimeError):
        with atomic_open(p) as f:
            f.write("half")
            raise RuntimeError("stop")
    with mock.patch("cinenerf_ns.planner.atomic.os.replace", side_effect=OSError("disk full")):
        with pytest.raises(OSError):
            atomic_write(p, "new")
    assert p.read_text() == "old" and os.listdir(tmp_path) == ["f"]
