"""The one atomic writer: whole files or none, the umask's mode, no temporary file left behind."""

import os
import stat

import pytest

from meta_sim.core.fileio import atomic_dir, atomic_path, made_folder, write_bytes_atomic, write_text_atomic


def test_written_file_has_the_mode_a_plain_open_gives(tmp_path):
    umask = os.umask(0o022)
    os.umask(umask)
    plain = tmp_path / "plain.txt"
    plain.write_text("x")
    path = write_text_atomic(tmp_path / "sub" / "a.json", "{}\n")
    assert path.read_text() == "{}\n"
    assert stat.S_IMODE(path.stat().st_mode) == stat.S_IMODE(plain.stat().st_mode) == 0o666 & ~umask
    assert sorted(p.name for p in (tmp_path / "sub").iterdir()) == ["a.json"]


def test_an_error_while_writing_keeps_the_old_file_and_removes_the_temporary(tmp_path):
    path = write_bytes_atomic(tmp_path / "tile.exr", b"old")
    with pytest.raises(RuntimeError):
        with atomic_path(path) as tmp:
            assert tmp.parent == tmp_path and tmp.name.startswith(".tile.tmp") and tmp.suffix == ".exr"
            tmp.write_bytes(b"half a")
            raise RuntimeError("disk full")
    assert path.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == ["tile.exr"]


def test_a_writer_that_takes_a_file_name_goes_through_atomic_path(tmp_path):
    with atomic_path(tmp_path / "model.pt") as tmp:
        tmp.write_bytes(b"weights")
        assert not (tmp_path / "model.pt").exists()
    assert (tmp_path / "model.pt").read_bytes() == b"weights"
    assert [p.name for p in tmp_path.iterdir()] == ["model.pt"]


def test_a_folder_is_built_beside_and_renamed_into_place_with_the_umask_mode(tmp_path):
    umask = os.umask(0o022)
    os.umask(umask)
    with atomic_dir(tmp_path / "bank") as tmp:
        assert tmp.parent == tmp_path and not (tmp_path / "bank").exists()
        (tmp / "manifest.json").write_text("{}")
    assert (tmp_path / "bank" / "manifest.json").read_text() == "{}"
    assert stat.S_IMODE((tmp_path / "bank").stat().st_mode) == 0o777 & ~umask
    with pytest.raises(RuntimeError):
        with atomic_dir(tmp_path / "other") as tmp:
            (tmp / "half").write_text("x")
            raise RuntimeError("interrupted")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bank"]


def test_a_folder_another_process_put_in_place_first_is_kept(tmp_path):
    with atomic_dir(tmp_path / "bank") as tmp:
        (tmp / "mine").write_text("late")
        (tmp_path / "bank").mkdir()
        (tmp_path / "bank" / "theirs").write_text("first")
    assert [p.name for p in (tmp_path / "bank").iterdir()] == ["theirs"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bank"]


def test_a_temporary_file_is_abandoned_only_when_its_writer_is_gone(tmp_path):
    import subprocess
    import sys
    import time

    from meta_sim.core import fileio

    with atomic_path(tmp_path / "tile.exr") as tmp:
        assert fileio.temp_owner(tmp.name) == (os.getpid(), fileio._host())
        assert not fileio.abandoned(tmp)  # this process writes it
    gone = int(subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                              text=True).stdout)
    dead = tmp_path / f".tile.tmp{gone}-{fileio._host()}-abc.exr"
    foreign = tmp_path / ".tile.tmp1-otherhost-abc.exr"
    for path in (dead, foreign):
        path.write_bytes(b"half")
    assert fileio.abandoned(dead) and not fileio.abandoned(foreign)
    assert fileio.abandoned(foreign, now=time.time() + fileio.STALE_SECONDS + 1)


def test_a_full_disk_is_one_line_and_leaves_no_temporary(tmp_path):
    import errno

    from meta_sim.core.errors import MetaSimError

    with pytest.raises(MetaSimError, match=r"cannot write .*cache\.pt: No space left on device"):
        with atomic_path(tmp_path / "cache.pt") as tmp:
            tmp.write_bytes(b"part")
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    assert list(tmp_path.iterdir()) == []


def test_a_failed_block_removes_the_folders_made_for_it_while_empty(tmp_path):
    (tmp_path / "kept").mkdir()
    with pytest.raises(RuntimeError):
        with made_folder(tmp_path / "kept" / "a" / "b"):
            raise RuntimeError
    assert [p.name for p in tmp_path.rglob("*")] == ["kept"]  # the folder that was there stays
    with pytest.raises(RuntimeError):
        with made_folder(tmp_path / "kept" / "a" / "b") as folder:
            (folder / "tile.exr").write_text("written before the error")
            raise RuntimeError
    assert (tmp_path / "kept" / "a" / "b" / "tile.exr").is_file()
