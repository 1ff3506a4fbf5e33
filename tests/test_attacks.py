"""Attacks on a new user's first hour: bad input must end in one clear error that names the problem and the
field, never a traceback, a hang, an out-of-memory kill, silently wrong output, a partial result file or a
lost input; child processes die with their parent.

Every case that could allocate without bound runs in a child process under ``RLIMIT_AS`` (and a timeout), so
that a regression fails this test instead of taking the machine down.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import signal
import subprocess
import sys
import textwrap
import time
import warnings
import zipfile
from pathlib import Path

import numpy as np
import pytest

import pbicrl
from pbicrl.cli import main
from pbicrl.inference.data import (MAX_GROUPS, Dataset, DatasetError, DatasetNotFoundError, clean_stale_temporaries,
                         inspect_npz, list_shipped_datasets, load_dataset, resolve_dataset_path, temporary_prefix)
from pbicrl.inference.synthetic import make_problem

LINUX = sys.platform.startswith("linux")
PY = sys.executable
MEMORY_LIMIT = 1 << 30  # ample for `pbicrl info` (~350 MiB mapped after imports), far below any runaway


# ---------------------------------------------------------------------------------------------- helpers
def _limited(args: list[str], *, limit: int = MEMORY_LIMIT, timeout: float = 90, cwd: Path | None = None,
             env: dict | None = None) -> subprocess.CompletedProcess:
    """``python -m pbicrl.cli ARGS`` (or ``python -c`` with ``args[0] == "-c"``) under RLIMIT_AS."""
    import resource

    def limit_memory() -> None:
        resource.setrlimit(resource.RLIMIT_AS, (limit, limit))

    argv = [PY, *args] if args and args[0] == "-c" else [PY, "-m", "pbicrl.cli", *args]
    return subprocess.run(argv, capture_output=True, text=True, timeout=timeout, preexec_fn=limit_memory,
                          cwd=cwd, env=env)


def _user_error(proc: subprocess.CompletedProcess, *needles: str) -> str:
    """Assert the one-line ``pbicrl: error: ...`` exit (status 2) and return the message."""
    assert proc.returncode == 2, (proc.returncode, proc.stderr[-2000:])
    assert "Traceback" not in proc.stderr and "MemoryError" not in proc.stderr, proc.stderr[-2000:]
    lines = [ln for ln in proc.stderr.splitlines() if ln.startswith("pbicrl: error:")]
    assert len(lines) == 1, proc.stderr
    for n in needles:
        assert n in lines[0], lines[0]
    return lines[0]


def _cli_error(capsys: pytest.CaptureFixture, argv: list[str], *needles: str) -> str:
    rc = main(argv)
    err = capsys.readouterr().err
    assert rc == 2, err
    assert "Traceback" not in err
    for n in needles:
        assert n in err, err
    return err


def _npy_member(shape: tuple[int, ...], descr: str = "<f8", data: bytes = b"") -> bytes:
    buf = io.BytesIO()
    np.lib.format.write_array_header_1_0(buf, {"descr": descr, "fortran_order": False, "shape": shape})
    return buf.getvalue() + data


def _small_npz(path: Path, **override: bytes) -> Path:
    """A dataset archive with some members replaced by raw ``.npy`` bytes."""
    members = {"features": _npy_member((2, 1), data=np.ones(2).tobytes()),
               "offsets": _npy_member((3,), "<i8", np.array([0, 1, 2]).tobytes()),
               "group": _npy_member((2,), "<i8", np.array([1, 2]).tobytes())}
    members.update(override)
    with zipfile.ZipFile(path, "w") as z:
        for name, data in members.items():
            z.writestr(f"{name}.npy", data)
    return path


def _claim_size(path: Path, member: str, size: int) -> None:
    """Forge the central directory so ``member`` claims ``size`` bytes (a zip bomb's honest-looking sizes)."""
    raw = bytearray(path.read_bytes())
    name = member.encode()
    at = raw.find(b"PK\x01\x02")
    while at != -1:
        name_len = int.from_bytes(raw[at + 28:at + 30], "little")
        if raw[at + 46:at + 46 + name_len] == name:
            raw[at + 20:at + 24] = size.to_bytes(4, "little")  # compressed size
            raw[at + 24:at + 28] = size.to_bytes(4, "little")  # uncompressed size
            path.write_bytes(bytes(raw))
            return
        at = raw.find(b"PK\x01\x02", at + 4)
    raise AssertionError(f"{member} not in {path}")


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _children(pid: int) -> list[int]:
    """Live child processes of ``pid`` (from /proc)."""
    out = []
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            text = (d / "stat").read_text()
        except OSError:
            continue
        fields = text[text.rindex(")") + 2:].split()
        if int(fields[1]) == pid and fields[0] not in "ZX":
            out.append(int(d.name))
    return out


def _alive(pid: int) -> bool:
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return text[text.rindex(")") + 2] not in "ZX"


def _wait(predicate, timeout: float, step: float = 0.05) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(step)
    return predicate()


def _reap(pids: list[int]) -> None:
    """Kill what a failing test left running (only processes this test started)."""
    for p in pids:
        if _alive(p):
            try:
                os.kill(p, signal.SIGKILL)
            except ProcessLookupError:
                pass


@pytest.fixture(scope="module")
def demo(tmp_path_factory) -> Path:
    p = tmp_path_factory.mktemp("demo") / "demo.npz"
    make_problem(8, labels="violations", violation_rate=0.4, seed=3).dataset.save(p)
    return p


# ---------------------------------------------------------------------------------------------- 1. shipped data
def test_load_dataset_takes_the_names_of_shipped_datasets(tmp_path, monkeypatch):
    names = list_shipped_datasets()
    assert "point_mass" in names and "example" in names
    shipped = Path(pbicrl.__file__).parent / "data"
    n_pm = Dataset.load(shipped / "point_mass.npz").n_trajectories  # the shipped files get regenerated
    n_ex = Dataset.load(shipped / "example.npz").n_trajectories
    ds = pbicrl.load_dataset("point_mass")
    assert ds.n_trajectories == n_pm and ds.feature_names[0] == "inv_goal_distance"
    assert pbicrl.load_dataset("point_mass.npz").n_trajectories == n_pm
    assert resolve_dataset_path("example") == resolve_dataset_path("example.npz") == shipped / "example.npz"
    with pytest.raises(DatasetNotFoundError, match="no shipped dataset of that name.*point_mass") as err:
        load_dataset("pointmass")
    assert isinstance(err.value, FileNotFoundError) and isinstance(err.value, DatasetError)
    # a file of that name wins; a directory of that name does not hide the shipped dataset
    monkeypatch.chdir(tmp_path)
    (tmp_path / "point_mass").mkdir()
    assert load_dataset("point_mass").n_trajectories == n_pm
    make_problem(4, seed=0).dataset.save(tmp_path / "example.npz")
    assert load_dataset("example.npz").n_trajectories == 12  # the exact file name: the local file
    assert load_dataset("example").n_trajectories == n_ex  # no file "example": the shipped dataset
    with pytest.raises(DatasetNotFoundError):
        load_dataset("sub/point_mass")  # a path with a directory part is a path, never a shipped name


def test_sweep_tasks_use_the_same_lookup(tmp_path):
    from pbicrl.experiments.tasks import Task, TaskError

    t = Task("infer", {"data": "example", "iterations": 100})
    assert t.config["data"] == "example"
    with pytest.raises(TaskError, match="data: nope: no such file.*shipped datasets: ant"):
        Task("infer", {"data": "nope"})


# ---------------------------------------------------------------------------------------------- 2. data files
@pytest.mark.skipif(not LINUX, reason="RLIMIT_AS and /dev/zero")
def test_info_on_a_device_a_fifo_or_a_directory_is_refused_at_once(tmp_path):
    _user_error(_limited(["info", "/dev/zero"], timeout=60), "/dev/zero", "character device", "regular file")
    fifo = tmp_path / "pipe.npz"
    os.mkfifo(fifo)
    _user_error(_limited(["info", str(fifo)], timeout=60), "named pipe")  # a regression hangs: timeout
    _user_error(_limited(["info", str(tmp_path)], timeout=60), "directory")
    empty = tmp_path / "empty.npz"
    empty.write_bytes(b"")
    _user_error(_limited(["info", str(empty)], timeout=60), "empty file")


@pytest.mark.skipif(not LINUX, reason="RLIMIT_AS")
def test_huge_array_headers_are_refused_before_any_allocation(tmp_path):
    lying = _small_npz(tmp_path / "lying.npz", features=_npy_member((10**12, 4)))
    _user_error(_limited(["info", str(lying)]), "field 'features'", "(1000000000000, 4)", "truncated")
    # sizes that look honest (a zip bomb): 1.5 GiB of features under a 1 GiB limit
    bomb = _small_npz(tmp_path / "bomb.npz", features=_npy_member((3 << 25, 2)))
    _claim_size(bomb, "features.npy", (3 << 29) + 4096)
    _user_error(_limited(["info", str(bomb)]), "field 'features'", "can allocate")
    huge_header = tmp_path / "header.npz"
    with zipfile.ZipFile(huge_header, "w") as z:
        z.writestr("features.npy", b"\x93NUMPY\x01\x00" + (65535).to_bytes(2, "little") + b"{" + b" " * 65534)
    _user_error(_limited(["info", str(huge_header)]), "field 'features'", "not a readable array")
    with pytest.raises(DatasetError, match="truncated"):
        inspect_npz(lying)


def test_complex_bytes_and_objects_are_never_silently_converted(tmp_path):
    with pytest.raises(DatasetError, match="features: complex values"):
        Dataset(features=np.ones((2, 1)) + 0.5j, offsets=[0, 1, 2], group=[1, 2])
    with pytest.raises(DatasetError, match="nominal_weights: complex"):
        Dataset(features=np.ones((2, 1)), offsets=[0, 1, 2], group=[1, 2], nominal_weights=[1 + 1j])
    with pytest.raises(DatasetError, match="features: trajectory 0: complex values"):
        Dataset.from_trajectories([np.ones((2, 1), dtype=complex), np.ones((1, 1))], [1, 2])
    p = tmp_path / "c.npz"
    np.savez(p, features=np.ones((2, 1)) + 1j, offsets=[0, 1, 2], group=[1, 2])
    with pytest.raises(DatasetError, match="complex"):
        load_dataset(p)
    q = tmp_path / "b.npz"
    np.savez(q, features=np.ones((2, 2)), offsets=[0, 1, 2], group=[1, 2], feature_names=np.array([b"speed", b"cost"]))
    assert load_dataset(q).feature_names == ("speed", "cost")  # not "b'speed'"
    with pytest.raises(DatasetError, match="feature_names: name 0 .* is not UTF-8"):
        Dataset(features=np.ones((2, 1)), offsets=[0, 1, 2], group=[1, 2], feature_names=[b"\xff"])
    with pytest.raises(DatasetError, match="feature_names: expected a sequence of names, got the single string"):
        Dataset(features=np.ones((2, 3)), offsets=[0, 1, 2], group=[1, 2], feature_names="abc")
    with pytest.raises(DatasetError, match="feature_names: name 1 is int"):
        Dataset(features=np.ones((2, 2)), offsets=[0, 1, 2], group=[1, 2], feature_names=["a", 5])
    r = tmp_path / "o.npz"
    np.savez(r, features=np.ones((2, 1)), offsets=[0, 1, 2], group=[1, 2], feature_names=np.array([{}], dtype=object))
    with pytest.raises(DatasetError, match="pickles"):
        load_dataset(r)
    s = tmp_path / "typo.npz"
    np.savez(s, features=np.ones((2, 1)), offsets=[0, 1, 2], group=[1, 2], feature_name=np.array(["x"]))
    with pytest.warns(pbicrl.errors.PbicrlWarning, match="unknown field.*'feature_name'"):
        load_dataset(s)


def test_thousands_of_single_trajectory_groups_are_refused_with_the_number(tmp_path):
    n = 20_000
    with pytest.raises(DatasetError, match=r"group: 20,000 distinct groups; at most 1,000 .*199,990,000 of them") as err:
        Dataset(features=np.ones((n, 1)), offsets=np.arange(n + 1), group=np.arange(1, n + 1))
    assert "Merge the labels" in str(err.value)
    k = MAX_GROUPS
    ok = Dataset(features=np.ones((k, 1)), offsets=np.arange(k + 1), group=np.arange(1, k + 1))
    assert ok.n_groups == MAX_GROUPS


@pytest.mark.skipif(not LINUX, reason="RLIMIT_AS")
def test_synthetic_refuses_impossible_sizes_at_once(tmp_path):
    t0 = time.monotonic()
    _user_error(_limited(["synthetic", str(tmp_path / "s.npz"), "--per-group", "1000000000000"]), "n_per_group",
                "1,000,000,000,000")
    _user_error(_limited(["synthetic", str(tmp_path / "s.npz"), "--per-group", "3000000"]), "n_per_group",
                "memory", "at most")
    assert time.monotonic() - t0 < 60
    assert not list(tmp_path.iterdir())
    with pytest.raises(ValueError, match="n_per_group: expected a positive integer"):
        make_problem(2.5)


# ---------------------------------------------------------------------------------------------- 3. CSV import
def _write(path: Path, text: str) -> Path:
    path.write_text(text)
    return path


def test_csv_groups_by_name_with_an_explicit_order(tmp_path, capsys):
    from pbicrl.io import TableError, read_csv

    src = _write(tmp_path / "t.csv", "trajectory,group,a\nx,good,1\nx,good,2\ny,very bad,3\nz,bad,4\nw,good,5\n")
    ds = read_csv(src, group_order=["good", "bad", "very bad"])
    assert ds.group.tolist() == [1, 3, 2, 1] and ds.group_names == ("good", "bad", "very bad")
    with pytest.raises(TableError, match="'good' is not a number.*--group-order 'good,very bad,bad'"):
        read_csv(src)
    with pytest.raises(TableError, match=r"row 3 \(line 4\): group 'very bad' is not one of --group-order"):
        read_csv(src, group_order="good,bad")
    with pytest.raises(TableError, match="repeated group name"):
        read_csv(src, group_order="good,bad,good")
    out = tmp_path / "t.npz"
    assert main(["import", "csv", str(src), "--out", str(out), "--group-order", "good,bad,very bad"]) == 0
    back = load_dataset(out)
    assert back.group_names == ("good", "bad", "very bad") and back.group.tolist() == [1, 3, 2, 1]
    assert "'very bad'" in repr(back)
    assert back.subset([0, 1]).group_names == ("good", "very bad")  # the names follow the groups that remain
    with pytest.raises(DatasetError, match="group_names: expected 2 names"):
        Dataset(features=np.ones((2, 1)), offsets=[0, 1, 2], group=[1, 2], group_names=["good"])


def test_csv_delimiter_and_huge_fields_give_clear_errors(tmp_path, capsys):
    src = _write(tmp_path / "t.csv", "trajectory,group,a\nx,1,1\ny,2,2\n")
    _cli_error(capsys, ["import", "csv", str(src), "--out", str(tmp_path / "o.npz"), "--delimiter", ";;"],
               "--delimiter: expected one character", "';;'")
    # 'tab' is a delimiter (this comma-separated file then has a single column)
    _cli_error(capsys, ["import", "csv", str(src), "--out", str(tmp_path / "tab.npz"), "--delimiter", "tab"],
               "--id-col: column(s) ['trajectory'] not found")
    big = _write(tmp_path / "big.csv", "trajectory,group,a\nx,1," + '"' + "9" * 200_000 + "\n")
    _cli_error(capsys, ["import", "csv", str(big), "--out", str(tmp_path / "b.npz")],
               "line 2: a field is longer than 131,072 characters")
    binary = tmp_path / "bin.csv"
    binary.write_bytes(b"trajectory,group,a\nx,1,\xff\n")
    _cli_error(capsys, ["import", "csv", str(binary), "--out", str(tmp_path / "c.npz")], "not UTF-8")
    assert not list(tmp_path.glob("*.npz"))


def test_import_never_overwrites_without_asking_and_never_an_input(tmp_path, capsys):
    src = _write(tmp_path / "t.csv", "trajectory,group,a\nx,1,1\ny,2,2\n")
    (tmp_path / "dir.npz").mkdir()
    _cli_error(capsys, ["import", "csv", str(src), "--out", str(tmp_path / "dir.npz"), "--overwrite"],
               "is a directory")
    assert not any((tmp_path / "dir.npz").iterdir())
    out = tmp_path / "o.npz"
    out.write_bytes(b"precious")
    _cli_error(capsys, ["import", "csv", str(src), "--out", str(out)], "already exists", "--overwrite")
    assert out.read_bytes() == b"precious"
    assert main(["import", "csv", str(src), "--out", str(out), "--overwrite"]) == 0
    assert load_dataset(out).n_trajectories == 2
    capsys.readouterr()
    # a table named like a dataset, and a hard link to it: --overwrite still never replaces the input
    named = _write(tmp_path / "table.npz", src.read_text())
    before = _sha(named)
    _cli_error(capsys, ["import", "csv", str(named), "--out", str(named), "--overwrite"], "is an input")
    os.link(named, tmp_path / "alias.npz")
    _cli_error(capsys, ["import", "csv", str(named), "--out", str(tmp_path / "alias.npz"), "--overwrite"],
               "is an input")
    assert _sha(named) == before
    # the API: no-clobber means no-clobber, even for a file that appears meanwhile
    ds = load_dataset(out)
    with pytest.raises(FileExistsError, match="already exists"):
        ds.save(out, overwrite=False)
    with pytest.raises(DatasetError, match="is a directory"):
        ds.save(tmp_path / "dir.npz")
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


# ---------------------------------------------------------------------------------------------- 4. Minari
@pytest.fixture(scope="module")
def minari_root(tmp_path_factory):
    minari = pytest.importorskip("minari")
    gym = pytest.importorskip("gymnasium")
    from minari.data_collector.episode_buffer import EpisodeBuffer

    root = tmp_path_factory.mktemp("minari")
    rng = np.random.default_rng(0)
    buffers = []
    for i in range(4):
        T = 3 + i
        buffers.append(EpisodeBuffer(id=i, seed=i, observations=rng.normal(size=(T + 1, 2)).astype(np.float32),
                                     actions=rng.normal(size=(T, 1)).astype(np.float32),
                                     rewards=list(rng.normal(size=T)), terminations=[False] * (T - 1) + [True],
                                     truncations=[False] * T, infos={}))
    old = os.environ.get("MINARI_DATASETS_PATH")
    os.environ["MINARI_DATASETS_PATH"] = str(root)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            minari.create_dataset_from_buffers("attack/walk/ranked-v0", buffers,
                                               observation_space=gym.spaces.Box(-np.inf, np.inf, (2,), np.float32),
                                               action_space=gym.spaces.Box(-1, 1, (1,), np.float32),
                                               algorithm_name="random", author="pbicrl tests")
    finally:
        if old is None:
            os.environ.pop("MINARI_DATASETS_PATH", None)
        else:
            os.environ["MINARI_DATASETS_PATH"] = old
    return root


def test_minari_missing_is_reported_with_the_pip_commands_before_user_code_runs(tmp_path, capsys, monkeypatch):
    from pbicrl.envs.minari_io import require_minari

    monkeypatch.setitem(sys.modules, "minari", None)  # as if it were not installed
    with pytest.raises(ImportError) as err:
        require_minari()
    assert 'pip install "minari[hdf5]"' in str(err.value) and 'pip install "minari[create]"' in str(err.value)
    marker = tmp_path / "ran"
    feats = _write(tmp_path / "feats.py", f"open({str(marker)!r}, 'w').close()\ndef f(ep):\n    return [[0.0]]\n")
    _cli_error(capsys, ["import", "minari", "x/y-v0", "--features", f"{feats}:f", "--out", str(tmp_path / "o.npz")],
               'pip install "minari[hdf5]"')
    assert not marker.exists(), "the feature file ran although minari is missing"


def test_minari_import_finds_local_modules_keeps_actions_and_never_says_download(minari_root, tmp_path, capsys,
                                                                                  monkeypatch):
    from pbicrl.io import from_minari

    name = f"attack_feats_{os.getpid()}"
    _write(tmp_path / f"{name}.py", "import numpy as np\n\ndef features(ep):\n"
                                    "    return np.asarray(ep.observations)[:, :1]\n")
    monkeypatch.chdir(tmp_path)
    # sys.path as the `pbicrl` console script has it: without the working directory
    monkeypatch.setattr(sys, "path", [p for p in sys.path if p not in ("", ".", str(tmp_path))])
    groups = _write(tmp_path / "groups.json", json.dumps([1, 2, 1, 2]))
    out = tmp_path / "m.npz"
    rc = main(["import", "minari", "attack/walk/ranked-v0", "--root", str(minari_root), "--features",
               f"{name}:features", "--groups", str(groups), "--out", str(out)])
    assert rc == 0, capsys.readouterr().err
    sys.modules.pop(name, None)
    ds = load_dataset(out)
    assert ds.actions is not None and ds.actions.shape == (ds.features.shape[0], 1)
    assert np.all(ds.actions[ds.offsets[1:] - 1] == 0.0)  # the final observation, after the last action
    direct = from_minari("attack/walk/ranked-v0", lambda ep: np.asarray(ep.observations)[1:, :1], groups=[1, 2, 1, 2],
                         root=minari_root)
    assert np.all(direct.actions != 0.0)  # one feature row per step: actions line up one to one
    err = _cli_error(capsys, ["import", "minari", "attack/nope-v0", "--root", str(minari_root), "--out",
                              str(tmp_path / "n.npz")], "no Minari dataset 'attack/nope-v0'",
                     "attack/walk/ranked-v0")
    assert "download=True" not in err
    _cli_error(capsys, ["import", "minari", "attack/walk/ranked-v0", "--root", str(tmp_path / "typo"), "--out",
                        str(tmp_path / "n.npz")], "root:", "no such directory")
    assert not (tmp_path / "typo").exists()


# ---------------------------------------------------------------------------------------------- 5. processes
_SAMPLE_FOREVER = textwrap.dedent("""
    import sys
    from pbicrl.inference.likelihood import PreferenceLikelihood
    from pbicrl.inference.samplers import sample
    from pbicrl.inference.synthetic import make_problem
    lik = PreferenceLikelihood.from_dataset(make_problem(6, seed=0).dataset)
    sample(lik, n_chains=2, n_jobs=2, n_iterations=10**9, progress=False)
""")


def _start(argv: list[str], **kw) -> subprocess.Popen:
    return subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, **kw)


@pytest.mark.skipif(not LINUX, reason="/proc and PR_SET_PDEATHSIG")
@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM])
def test_chain_workers_die_with_their_parent(sig):
    proc = _start([PY, "-c", _SAMPLE_FOREVER])
    kids: list[int] = []
    try:
        assert _wait(lambda: len(_children(proc.pid)) >= 2, 120), proc.stderr.read() if proc.poll() is not None else ""
        kids = _children(proc.pid)
        os.kill(proc.pid, sig)
        proc.wait(timeout=20)
        assert _wait(lambda: not any(_alive(k) for k in kids), 10), "chain workers outlived their parent"
    finally:
        proc.kill()
        _reap(kids)


@pytest.mark.skipif(not LINUX, reason="/proc")
def test_ctrl_c_stops_inference_at_once(tmp_path, demo, with_default_sigint):
    out = tmp_path / "run"
    proc = _start(with_default_sigint([PY, "-m", "pbicrl.cli", "infer", str(demo), "--out", str(out), "--iterations",
                                       "1000000000", "--chains", "2", "--jobs", "2", "--no-progress"]))
    kids: list[int] = []
    try:
        assert _wait(lambda: len(_children(proc.pid)) >= 2, 120)
        time.sleep(0.5)  # the chains are running compiled code now
        kids = _children(proc.pid)
        t0 = time.monotonic()
        os.kill(proc.pid, signal.SIGINT)  # the parent alone, as `kill -INT` does
        _, err = proc.communicate(timeout=30)
        # generous for a loaded machine; the chains themselves would run for hours
        assert time.monotonic() - t0 < 20.0, "waited for the chains instead of stopping them"
        assert proc.returncode == 130 and "interrupted" in err and "Traceback" not in err, err
        assert _wait(lambda: not any(_alive(k) for k in kids), 5)
        assert not out.exists() and not [p for p in tmp_path.iterdir() if p.name.startswith(".")]
    finally:
        proc.kill()
        _reap(kids)


@pytest.mark.skipif(not LINUX, reason="/proc and PR_SET_PDEATHSIG")
@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM])
def test_sweep_workers_die_with_their_parent(tmp_path, sig):
    cfg = _write(tmp_path / "s.toml", "[base]\nkind = 'selftest'\nsleep = 60\n[grid]\nvalue = [0, 1]\n")
    root = tmp_path / "out"
    proc = _start([PY, "-m", "pbicrl.cli", "sweep", str(cfg), "--out", str(root), "--workers", "2", "--no-progress"])
    kids: list[int] = []
    try:
        assert _wait(lambda: root.is_dir() and len(list(root.glob(".tmp-*"))) >= 2, 120)
        kids = _children(proc.pid)
        assert len(kids) >= 2
        os.kill(proc.pid, sig)
        _, err = proc.communicate(timeout=20)
        assert _wait(lambda: not any(_alive(k) for k in kids), 10), "sweep workers outlived their parent"
        if sig == signal.SIGTERM:  # a graceful stop, as on Ctrl-C
            assert proc.returncode == 130 and "run the same command to resume" in err, err
            assert json.loads((root / "sweep.json").read_text())["interrupted"]
            assert not list(root.glob(".tmp-*"))
        from pbicrl.experiments.tasks import clean_stale_temp_dirs

        clean_stale_temp_dirs(root)
        assert not list(root.glob(".tmp-*"))  # nothing a later run cannot clean
    finally:
        proc.kill()
        _reap(kids)


_KILLED_WRITER = textwrap.dedent("""
    import os, signal, sys, tempfile
    from pathlib import Path
    from pbicrl.inference.data import temporary_prefix
    out = Path(sys.argv[1])
    new = Path(tempfile.mkdtemp(prefix=temporary_prefix(out, "tmp"), dir=out.parent))
    (new / "summary.json").write_text("new")
    old = Path(tempfile.mkdtemp(prefix=temporary_prefix(out, "old"), dir=out.parent))
    os.replace(out, old / "old")
    os.kill(os.getpid(), signal.SIGKILL)  # between moving the old run aside and putting the new one in place
""")


def test_temporaries_of_killed_writers_are_cleaned_and_nothing_is_lost(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    (out / "summary.json").write_text("old")
    proc = subprocess.run([PY, "-c", _KILLED_WRITER, str(out)], timeout=60)
    assert proc.returncode == -signal.SIGKILL
    assert not out.exists() and len(list(tmp_path.glob(".run.*"))) == 2
    removed = clean_stale_temporaries(out)
    assert len(removed) == 2 and not list(tmp_path.glob(".run.*"))
    assert (out / "summary.json").read_text() == "old"  # the previous run is back, not lost
    # a running writer's temporaries (this process) are left alone
    mine = Path(__import__("tempfile").mkdtemp(prefix=temporary_prefix(out), dir=tmp_path))
    assert clean_stale_temporaries(out) == [] and mine.exists()


_KILLED_RUN_DIR = textwrap.dedent("""
    import os, signal, sys
    import numpy as np
    from pbicrl.io import runs as results
    real = np.savez_compressed
    def die(*a, **k):
        real(*a, **k)
        os.kill(os.getpid(), signal.SIGKILL)
    np.savez_compressed = die
    results.write_run_dir(sys.argv[1], {"summary.json": {"new": 1}}, {"chains.npz": {"x": np.ones(3)}},
                          overwrite=True)
""")


def test_a_run_dir_writer_killed_mid_write_leaves_only_cleanable_temporaries(tmp_path):
    out = tmp_path / "run"
    out.mkdir()
    (out / "summary.json").write_text("{}")
    proc = subprocess.run([PY, "-c", _KILLED_RUN_DIR, str(out)], timeout=60)
    assert proc.returncode == -signal.SIGKILL
    left = list(tmp_path.glob(".run.*"))
    assert left, "expected the killed writer's temporary"
    clean_stale_temporaries(out, legacy_age_s=0)  # names without a pid: only age tells (results.py, see report)
    # left: only the killed writer's claim file, which locks nothing once its process is gone
    assert [p.name for p in tmp_path.glob(".run.*")] == [".run.lock"] and (out / "summary.json").exists()
    from pbicrl.io import runs as results
    results.write_run_dir(out, {"summary.json": {"later": 1}}, {}, overwrite=True)  # a later run takes it over
    assert not list(tmp_path.glob(".run.*")) and json.loads((out / "summary.json").read_text()) == {"later": 1}


# ---------------------------------------------------------------------------------------------- 6. compiling
def test_a_cold_numba_cache_is_detected_and_announced(tmp_path, capsys, monkeypatch):
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    code = "from pbicrl.inference.samplers.driver import sampler_needs_compiling as f; print(f())"
    cold = subprocess.run([PY, "-c", code], capture_output=True, text=True, timeout=120, env=env)
    assert cold.stdout.strip() == "True", cold.stderr
    from pbicrl.inference.likelihood import PreferenceLikelihood
    from pbicrl.inference.samplers import driver

    lik = PreferenceLikelihood.from_dataset(make_problem(5, seed=1).dataset)
    driver.sample(lik, n_chains=1, n_jobs=1, n_iterations=50, progress=False)
    assert driver.sampler_needs_compiling() is False  # compiled (and cached) now
    monkeypatch.setattr(driver, "sampler_needs_compiling", lambda: True)
    driver.sample(lik, n_chains=1, n_jobs=1, n_iterations=50, progress=True)
    assert "compiling the sampler (first run only" in capsys.readouterr().err
    driver.sample(lik, n_chains=1, n_jobs=1, n_iterations=50, progress=False)
    assert "compiling" not in capsys.readouterr().err  # quiet when asked to be


# ---------------------------------------------------------------------------------------------- 7. names
def test_sample_keeps_the_feature_names():
    from pbicrl.inference.likelihood import PreferenceLikelihood
    from pbicrl.inference.samplers import sample

    ds = make_problem(5, seed=2).dataset
    lik = PreferenceLikelihood.from_dataset(ds)
    post = sample(lik, n_chains=1, n_jobs=1, n_iterations=100, progress=False, feature_names=ds.feature_names)
    assert post.feature_names == ds.feature_names
    with pytest.raises(ValueError, match="feature_names: expected 4 names"):
        sample(lik, n_chains=1, n_jobs=1, n_iterations=100, progress=False, feature_names=["a"])
    with pytest.raises(ValueError, match="feature_names: expected a sequence of names"):
        sample(lik, n_chains=1, n_jobs=1, n_iterations=100, progress=False, feature_names="abcd")
    object.__setattr__(lik, "feature_names", ds.feature_names)  # what a likelihood that carries names gives
    assert sample(lik, n_chains=1, n_jobs=1, n_iterations=100, progress=False).feature_names == ds.feature_names


# ---------------------------------------------------------------------------------------------- 8. ICL
def test_icl_checkpoints_load_without_running_code(tmp_path):
    torch = pytest.importorskip("torch")
    from pbicrl.baselines.icl import _load_checkpoint, _torch_save

    marker = tmp_path / "pwned"

    class Evil:
        def __reduce__(self):
            return (os.system, (f"touch {marker}",))

    evil = tmp_path / "checkpoint.pt"
    torch.save({"state": Evil()}, evil)
    with pytest.raises(ValueError, match="cannot be loaded safely.*Delete it"):
        _load_checkpoint(evil)
    assert not marker.exists()
    state = {"state": {"history": [{"cmse": np.float64(0.5), "n": np.int64(2)}], "t": torch.ones(2)},
             "config": {"rounds": 2}, "seed": 0}
    legacy = tmp_path / "legacy.pt"
    torch.save(state, legacy)  # numpy scalars, as checkpoints written before held them
    assert float(_load_checkpoint(legacy)["state"]["history"][0]["cmse"]) == 0.5
    fresh = tmp_path / "fresh.pt"
    _torch_save(state, fresh)
    plain = torch.load(fresh, weights_only=True)  # no extra globals needed
    assert plain["state"]["history"][0] == {"cmse": 0.5, "n": 2}
    (tmp_path / "empty.pt").write_bytes(b"")
    with pytest.raises(ValueError, match="empty.pt cannot be loaded safely"):
        _load_checkpoint(tmp_path / "empty.pt")


# ---------------------------------------------------------------------------------------------- 9. MuJoCo
def test_mujoco_writes_no_log_into_the_working_directory(tmp_path):
    pytest.importorskip("mujoco")
    pytest.importorskip("gymnasium")
    code = textwrap.dedent("""
        import warnings, gymnasium as gym, mujoco
        from pbicrl.envs._mujoco_compat import MujocoWarning, quiet_mujoco_warnings
        assert quiet_mujoco_warnings() and quiet_mujoco_warnings()
        for _ in range(2):
            env = gym.make("HalfCheetah-v5"); env.reset(seed=0); env.close()
        m = mujoco.MjModel.from_xml_string("<mujoco><worldbody><body><geom size='.1'/><joint type='free'/>"
                                           "</body></worldbody></mujoco>")
        d = mujoco.MjData(m); d.qpos[:] = float("nan")
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            mujoco.mj_step(m, d)
        assert any(issubclass(w.category, MujocoWarning) for w in caught), "other warnings must still surface"
    """)
    proc = subprocess.run([PY, "-c", code], capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "settotalmass" not in proc.stdout + proc.stderr
    assert not (tmp_path / "MUJOCO_LOG.TXT").exists()


# ---------------------------------------------------------------------------------------------- 10. cache versions
def test_runs_cached_under_old_defaults_or_versions_are_not_reused(tmp_path, demo, monkeypatch, capsys):
    from pbicrl.experiments import tasks
    from pbicrl.experiments.sweep import run_tasks
    from pbicrl.experiments.tasks import CACHE_VERSION, RESULT_FILE, Task, find_done, stale_reason

    cfg = {"data": str(demo), "iterations": 200, "chains": 1}
    task = Task("infer", cfg)
    res = run_tasks([task], tmp_path, "serial", progress=False, manifest=False)
    assert res.records[0].status == "ran"
    done = find_done(task, tmp_path)
    rec = json.loads((done / RESULT_FILE).read_text())
    assert rec["cache_version"] == CACHE_VERSION and rec["config"]["prior"] == task.config["prior"]
    again = run_tasks([Task("infer", cfg)], tmp_path, "serial", progress=False, manifest=False)
    assert again.records[0].status == "cached"

    # the default prior changes: same hash (defaults are left out of it), but the cached run is not reused
    from pbicrl.experiments import kinds

    fields = kinds._infer_fields()
    monkeypatch.setattr(kinds, "_infer_fields", lambda: fields | {"prior": "other-prior"})
    changed = Task("infer", cfg)
    assert changed.config_hash == task.config_hash and changed.config["prior"] == "other-prior"
    assert find_done(changed, tmp_path) is None
    assert "prior" in stale_reason(changed, rec)
    monkeypatch.undo()

    # a run recorded by a cache version whose numbers may differ is never reused, even under the same hash
    # (version 2 only renamed settings: its runs are adopted, see tests/experiments/test_tasks.py)
    rec_old = dict(rec, cache_version=1)
    (done / RESULT_FILE).write_text(json.dumps(rec_old))
    assert find_done(task, tmp_path) is None
    res = run_tasks([task], tmp_path, "serial", progress=True, manifest=False)
    assert res.records[0].status == "ran" and "cached result not reused" in capsys.readouterr().err
    assert json.loads((done / RESULT_FILE).read_text())["cache_version"] == CACHE_VERSION
    # and the version is part of the hash
    monkeypatch.setattr(tasks, "CACHE_VERSION", CACHE_VERSION + 1)
    assert Task("infer", cfg).config_hash != task.config_hash


# ---------------------------------------------------------------------------------------------- 11. run directories
@pytest.fixture(scope="module")
def run_dir(tmp_path_factory, demo):
    out = tmp_path_factory.mktemp("runs") / "run"
    post = pbicrl.infer(load_dataset(demo), n_iterations=400, n_chains=2, n_jobs=1, seed=0, progress=False)
    post.save(out)
    return out


def _copy_run(run_dir: Path, dst: Path, **files: bytes) -> Path:
    dst.mkdir()
    for name in ("summary.json", "chains.npz"):
        (dst / name).write_bytes(files.get(name.replace(".", "_"), (run_dir / name).read_bytes()))
    return dst


@pytest.mark.parametrize("summary, message", [
    (b"[]", "expected a JSON object"),
    (b'{"settings": 5}', "'settings' should be a JSON object"),
    (b'{"feature_names": [1, 2]}', "'feature_names' should be a list of strings"),
    (b'{"seed": "zero"}', "'seed' should be a JSON integer"),
    (b'{"extra": {"data": 7}}', "'extra.data' should be an object"),
    (b"\xff\xfe{}", "not UTF-8"),
    (b"{" * 100_000, "not valid JSON"),
    (b"", "not valid JSON"),
])
def test_malformed_summaries_give_clear_errors(run_dir, tmp_path, capsys, summary, message):
    bad = _copy_run(run_dir, tmp_path / "bad", summary_json=summary)
    _cli_error(capsys, ["diagnose", str(bad)], "summary.json", message)


@pytest.mark.skipif(not LINUX, reason="RLIMIT_AS")
def test_broken_chains_files_give_clear_errors(run_dir, tmp_path):
    empty = _copy_run(run_dir, tmp_path / "empty", chains_npz=b"")
    _user_error(_limited(["diagnose", str(empty)]), "chains.npz", "empty file")
    huge = tmp_path / "h.npz"
    _small_npz(huge, indicators=_npy_member((10**6, 10**6, 4), "|i1"))
    lying = _copy_run(run_dir, tmp_path / "lying", chains_npz=huge.read_bytes())
    _user_error(_limited(["diagnose", str(lying)]), "chains.npz", "field 'indicators'", "truncated")
    header = tmp_path / "hh.npz"
    with zipfile.ZipFile(header, "w") as z:
        z.writestr("indicators.npy", b"\x93NUMPY\x01\x00" + (65535).to_bytes(2, "little") + b"{" + b" " * 65534)
    big_header = _copy_run(run_dir, tmp_path / "header", chains_npz=header.read_bytes())
    _user_error(_limited(["export", str(big_header)]), "chains.npz", "not a readable array")


def test_outputs_never_replace_the_run(run_dir, tmp_path, capsys):
    run = _copy_run(run_dir, tmp_path / "run")
    before = {p.name: _sha(p) for p in run.iterdir()}
    for target in ("chains.npz", "summary.json"):
        _cli_error(capsys, ["export", str(run), "--netcdf", str(run / target), "--overwrite"], "--netcdf",
                   "is an input")
    _cli_error(capsys, ["export", str(run), "--netcdf", str(run), "--overwrite"], "is a directory")
    assert {p.name: _sha(p) for p in run.iterdir()} == before
    assert main(["diagnose", str(run)]) == 0


def test_plot_truth_with_an_unknown_name_is_an_error(run_dir, tmp_path, capsys):
    pytest.importorskip("matplotlib")
    run = _copy_run(run_dir, tmp_path / "run")
    _cli_error(capsys, ["plot", str(run), "--truth", "zzz=1"], "--truth", "'zzz'")
    assert not (run / "plots").exists()


# ---------------------------------------------------------------------------------------------- 12. concurrent runs, permissions
def _claim_in_child(out: Path) -> subprocess.Popen:
    """Another process that claims ``out`` (as a running ``pbicrl infer`` does) and holds it until killed."""
    code = ("import sys; from pbicrl.io.runs import claim_out_dir; "
            f"claim_out_dir({str(out)!r}); print('claimed', flush=True); sys.stdin.read()")
    proc = subprocess.Popen([PY, "-c", code], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    assert proc.stdout is not None and proc.stdout.readline().strip() == "claimed"
    return proc


@pytest.mark.skipif(not LINUX, reason="flock")
def test_a_second_run_to_the_same_out_is_refused_before_sampling(run_dir, demo, tmp_path, capsys):
    from pbicrl.io.runs import OutputBusyError

    out = tmp_path / "run"
    holder = _claim_in_child(out)
    try:
        t0 = time.monotonic()
        _cli_error(capsys, ["infer", str(demo), "--out", str(out), "--iterations", "2000000", "--no-progress"],
                   "being written by another pbicrl process", f"pid {holder.pid}")
        assert time.monotonic() - t0 < 30  # refused up front, not after two million iterations
        assert not out.exists()
        post = pbicrl.load_run(run_dir, issue_warnings=False)
        with pytest.raises(OutputBusyError, match="another pbicrl process"):
            post.save(out)
        assert not out.exists() and (tmp_path / ".run.lock").exists()
    finally:
        holder.kill()
        holder.wait()
    # a killed holder leaves its lock file, which stops nobody; a finished write removes it
    assert main(["infer", str(demo), "--out", str(out), "--iterations", "300", "--chains", "1", "--no-progress"]) == 0
    capsys.readouterr()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]
    assert pbicrl.load_run(out, issue_warnings=False).n_chains == 1


@pytest.mark.skipif(not LINUX, reason="flock")
def test_two_concurrent_infer_processes_to_one_out(demo, tmp_path):
    out = tmp_path / "run"
    argv = [PY, "-m", "pbicrl.cli", "infer", str(demo), "--out", str(out), "--iterations", "3000", "--chains", "1",
            "--no-progress"]
    procs = [subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for _ in range(2)]
    try:
        results = [(p.wait(timeout=300), p.stderr.read()) for p in procs]  # type: ignore[union-attr]
    finally:
        _reap([p.pid for p in procs])
    codes = sorted(rc for rc, _ in results)
    assert codes == [0, 2], results
    err = next(e for rc, e in results if rc == 2)
    assert "Traceback" not in err
    assert "being written by another pbicrl process" in err or "already exists" in err, err
    post = pbicrl.load_run(out, issue_warnings=False)  # the winner's complete output
    assert post.n_chains == 1 and post.n_draws > 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run"]


@pytest.mark.parametrize("mask, dir_mode, file_mode", [(0o022, 0o755, 0o644), (0o027, 0o750, 0o640),
                                                       (0o002, 0o775, 0o664)])
def test_run_directories_honour_the_umask(run_dir, tmp_path, mask, dir_mode, file_mode):
    import stat

    post = pbicrl.load_run(run_dir, issue_warnings=False)
    old = os.umask(mask)
    try:
        out = post.save(tmp_path / "run")
    finally:
        os.umask(old)
    assert stat.S_IMODE(out.stat().st_mode) == dir_mode
    for f in ("summary.json", "chains.npz"):
        assert stat.S_IMODE((out / f).stat().st_mode) == file_mode
