"""All-or-nothing outputs: files appear together at the end, an exception leaves the folder as it was, an earlier
run's files under the same name are removed, files are 0644."""
import os
import stat

import pytest

from cinenerf_ns.output_set import OutputSet, check_name, check_writable
from cinenerf_ns.planner.errors import InvalidInputError


def _mode(p):
    return stat.S_IMODE(os.stat(p).st_mode)


def test_files_appear_together_with_mode_0644(tmp_path):
    with OutputSet(tmp_path / "out", "shot") as out:
        for f in ("shot_0.json", "shot_1.json", "shot_report.json"):
            out.path(f).write_text("{}")
        assert not (tmp_path / "out" / "shot_0.json").exists()  # nothing visible until the end
    names = sorted(p.name for p in (tmp_path / "out").iterdir())
    assert names == ["shot_0.json", "shot_1.json", "shot_report.json"]
    assert all(_mode(tmp_path / "out" / n) == 0o644 for n in names)


def test_failure_leaves_the_folder_as_it_was(tmp_path):
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    (out_dir / "shot_0.json").write_text("old")
    with pytest.raises(KeyboardInterrupt):
        with OutputSet(out_dir, "shot") as out:
            out.path("shot_0.json").write_text("new")
            raise KeyboardInterrupt
    assert [p.name for p in out_dir.iterdir()] == ["shot_0.json"]
    assert (out_dir / "shot_0.json").read_text() == "old"


def test_stale_files_of_the_same_name_are_removed_others_kept(tmp_path):
    out_dir = tmp_path / "out"
    out_dir.mkdir()
    for n in ("shot_0.json", "shot_1.json", "shot_2.json", "shot_report.json", "other_0.json", "shotgun.json"):
        (out_dir / n).write_text("old")
    with OutputSet(out_dir, "shot") as out:
        out.path("shot_0.json").write_text("new")
        out.path("shot_report.json").write_text("new")
    assert sorted(p.name for p in out_dir.iterdir()) == ["other_0.json", "shot_0.json", "shot_report.json",
                                                        "shotgun.json"]


@pytest.mark.parametrize("bad", ["", "../x", "a/b", ".hidden", "x" * 101, "sp ace"])
def test_bad_names(bad):
    with pytest.raises(InvalidInputError, match="--name"):
        check_name(bad)


def test_writable_checks_create_nothing(tmp_path):
    target = tmp_path / "a" / "b"
    assert check_writable(target) == target
    assert not (tmp_path / "a").exists()
    f = tmp_path / "file"
    f.write_text("x")
    with pytest.raises(InvalidInputError, match="is a file"):
        check_writable(f)
    with pytest.raises(InvalidInputError, match="not a folder"):
        check_writable(f / "sub")


def test_a_write_that_fails_names_the_folder_and_leaves_nothing(tmp_path):
    """A full disk or a file-size limit while staging: one InvalidInputError naming the folder, nothing left."""
    import errno

    out = tmp_path / "out"
    with pytest.raises(InvalidInputError, match=rf"cannot write the outputs into {out}: File too large; nothing"):
        with OutputSet(out, "shot") as o:
            o.path("shot_0.json").write_text("{}")
            raise OSError(errno.EFBIG, os.strerror(errno.EFBIG))
    assert not out.exists()
    with pytest.raises(FileNotFoundError):  # other errors are not disguised
        with OutputSet(out, "shot"):
            raise FileNotFoundError(errno.ENOENT, "the scene moved")
    assert not out.exists()


def test_remove_stale_false_keeps_earlier_files(tmp_path):
    (tmp_path / "shot_0.json").write_text("the input")
    with OutputSet(tmp_path, "shot_0", remove_stale=False) as o:
        o.path("shot_0.mp4").write_bytes(b"video")
    assert sorted(os.listdir(tmp_path)) == ["shot_0.json", "shot_0.mp4"]


def test_folders_that_take_no_files_and_a_small_file_size_limit(tmp_path, monkeypatch):
    from cinenerf_ns.output_set import check_file_size_limit

    if os.path.isdir("/proc"):
        with pytest.raises(InvalidInputError, match=r"--output-dir /proc/x: cannot write into /proc"):
            check_writable("/proc/x")
    resource = pytest.importorskip("resource")
    monkeypatch.setattr(resource, "getrlimit", lambda what: (1000, resource.RLIM_INFINITY))
    with pytest.raises(InvalidInputError, match=rf"--output-dir {tmp_path}: the file-size limit \(ulimit -f\) is 1000"):
        check_file_size_limit(tmp_path)
    monkeypatch.setattr(resource, "getrlimit", lambda what: (resource.RLIM_INFINITY, resource.RLIM_INFINITY))
    check_file_size_limit(tmp_path)


def test_a_failed_set_removes_the_folders_it_made(tmp_path):
    (tmp_path / "kept").mkdir()
    for folder in (tmp_path / "new" / "deeper", tmp_path / "kept"):
        with pytest.raises(KeyboardInterrupt):
            with OutputSet(folder, "shot") as o:
                o.path("shot_0.json").write_text("{}")
                raise KeyboardInterrupt
    assert sorted(os.listdir(tmp_path)) == ["kept"] and os.listdir(tmp_path / "kept") == []
