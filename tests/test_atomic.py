"""Atomic files and directories: complete or absent, umask permissions, no clobbering, stale temporaries."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from pbicrl import _atomic
from pbicrl._atomic import (OutputExistsError, atomic_dir, atomic_path, clean_stale_temporaries, copy_file,
                            read_json, read_toml, temporary_prefix, write_bytes, write_json, write_text)


@pytest.fixture
def umask_027():
    old = os.umask(0o027)
    try:
        yield 0o027
    finally:
        os.umask(old)


def test_umask_is_read_without_changing_it(umask_027):
    assert _atomic.umask() == 0o027
    assert _atomic.umask() == 0o027


def test_files_and_directories_get_the_umasks_permissions(tmp_path, umask_027):
    f = write_text(tmp_path / "a" / "f.txt", "x")
    assert f.read_text() == "x" and f.stat().st_mode & 0o777 == 0o640
    with atomic_dir(tmp_path / "run") as d:
        (d / "g.json").write_text("{}")
    assert (tmp_path / "run").stat().st_mode & 0o777 == 0o750
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a", "run"]  # no temporaries left


def test_a_failed_write_leaves_the_old_content_and_no_temporary(tmp_path):
    target = write_bytes(tmp_path / "t.bin", b"old")
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            tmp.write_bytes(b"half")
            raise RuntimeError("killed half-way")
    assert target.read_bytes() == b"old" and list(tmp_path.iterdir()) == [target]
    with pytest.raises(TypeError):
        write_json(tmp_path / "j.json", {"x": object()})  # not JSON: nothing is created
    assert not (tmp_path / "j.json").exists() and list(tmp_path.iterdir()) == [target]


def test_no_overwrite_refuses_an_existing_file(tmp_path):
    target = write_text(tmp_path / "t.txt", "first")
    with pytest.raises(OutputExistsError, match="path: .*t.txt already exists.*overwrite=True"):
        write_text(target, "second", overwrite=False)
    assert target.read_text() == "first" and len(list(tmp_path.iterdir())) == 1
    assert copy_file(target, tmp_path / "c.txt").read_text() == "first"


def test_replacing_a_directory_keeps_nothing_of_the_old_one(tmp_path):
    with atomic_dir(tmp_path / "run") as d:
        (d / "old.txt").write_text("1")
    with atomic_dir(tmp_path / "run", replace=True) as d:
        (d / "new.txt").write_text("2")
    assert [p.name for p in (tmp_path / "run").iterdir()] == ["new.txt"]
    assert [p.name for p in tmp_path.iterdir()] == ["run"]
    with pytest.raises(OSError):
        with atomic_dir(tmp_path / "run") as d:  # without replace a non-empty target stays
            (d / "x.txt").write_text("3")
    assert [p.name for p in (tmp_path / "run").iterdir()] == ["new.txt"] and len(list(tmp_path.iterdir())) == 1


def test_temporaries_of_dead_writers_are_removed_and_moved_content_restored(tmp_path):
    target = tmp_path / "run"
    proc = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    dead = int(proc.stdout)  # a process id that has ended
    live_tmp = tmp_path / f"{temporary_prefix(target)}abc"  # this process: alive, kept
    live_tmp.mkdir()
    dead_tmp = tmp_path / f".run.tmp-{_atomic.host_tag()}.{dead}.xyz"
    dead_tmp.mkdir()
    old = tmp_path / f".run.old-{_atomic.host_tag()}.{dead}.qrs"
    (old / "old").mkdir(parents=True)
    (old / "old" / "summary.json").write_text("{}")  # died between moving the old run aside and renaming the new
    removed = clean_stale_temporaries(target)
    assert sorted(removed) == sorted([dead_tmp, old])
    assert (target / "summary.json").exists() and live_tmp.exists()


class _Refused(ValueError):
    pass


def test_read_json_and_toml_read_what_the_writers_write(tmp_path):
    write_json(tmp_path / "a.json", {"x": [1, 2.5]})
    assert read_json(tmp_path / "a.json", "truth") == {"x": [1, 2.5]}
    write_text(tmp_path / "a.toml", "[base]\niterations = 10\n")
    assert read_toml(tmp_path / "a.toml", "config") == {"base": {"iterations": 10}}


@pytest.mark.parametrize("reader, kind", [(read_json, "JSON"), (read_toml, "TOML")])
def test_read_json_and_toml_name_the_field_and_the_problem(tmp_path, reader, kind):
    with pytest.raises(FileNotFoundError, match=r"^--groups: .*nope: no such file$"):
        reader(tmp_path / "nope", "--groups")
    with pytest.raises(_Refused, match="^cfg: .*nope: no such file"):  # a caller's own class for a missing file
        reader(tmp_path / "nope", "cfg", missing=_Refused)
    with pytest.raises(_Refused, match=f"is a directory, not a {kind} file"):
        reader(tmp_path, "cfg", error=_Refused)
    bad = tmp_path / "bad"
    bad.write_text("{[ not this")
    with pytest.raises(_Refused, match=f"^cfg: .*bad is not valid {kind} "):
        reader(bad, "cfg", error=_Refused)
    bad.write_bytes(b"\xff\xfe")
    with pytest.raises(ValueError, match=f"is not UTF-8 text \\(not a {kind} file\\)"):
        reader(bad, "cfg")


def test_read_json_refuses_absurd_nesting_with_the_same_message(tmp_path):
    deep = tmp_path / "deep.json"
    deep.write_text("[" * 100_000)
    with pytest.raises(ValueError, match="not valid JSON"):
        read_json(deep, "truth")
