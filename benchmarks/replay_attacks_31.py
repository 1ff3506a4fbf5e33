"""Replay the attacks of issue 31 as a user would type them, and classify what each one did.

Every attack runs the real command line (``python -m pbicrl.cli ...``) in a fresh temporary directory, as a
child process in its own process group, under ``RLIMIT_AS`` (``--memory-gb``, default 4) and a wall-clock
limit (``--timeout``, default 120 s); on timeout the whole group is killed. Before the command runs, the
SHA-256 of every file already in the directory is recorded; afterwards a missing or changed file that the
attack did not declare as pbicrl's own output is data loss. Crafted pickle payloads (``__reduce__`` runs
``touch PWNED``) reveal code execution. The labelling-server attacks start ``pbicrl label ... --port 0`` and
talk HTTP to it over a socket.

Outcome classes (first match wins):

``code execution``  the payload's marker file exists afterwards;
``data loss``       a pre-existing file was deleted or changed;
``runaway``         the timeout or the memory cap was hit (``MemoryError``, killed), an orphaned process kept
                    running, or the server grew by more than 64 MB for a refused body;
``traceback``       ``Traceback`` in stdout, stderr or the server log (or HTTP 500);
``silent accept``   exit 0 (HTTP 2xx) where the attack should have been refused or flagged;
``flagged``         exit 0 with the expected warning text (for attacks where that is the correct outcome);
``clean error``     non-zero exit (HTTP 4xx) whose message names the problem (the expected words);
``unclear error``   non-zero exit without a traceback whose message lacks the expected words (or names a
                    forbidden internal path);
``ok``              a legitimate command that did what it should (controls, and timed runs of item 9).

Usage::

    cd /work/main && nice -n 5 python benchmarks/replay_attacks_31.py --json benchmarks/reports/attacks_31_replay.json
    python benchmarks/replay_attacks_31.py --only 2a,7 --keep     # attacks 2a and every attack of item 7

The table (attack id, issue item, command, outcome, seconds, evidence) goes to stdout, one row as each attack
finishes; ``--json`` also writes every row with the command's exit status and the tail of its stderr.
"""

from __future__ import annotations

import argparse
import base64
import dataclasses
import datetime
import hashlib
import importlib.util
import json
import os
import pickle
import platform
import re
import resource
import shlex
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
import zipfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
PY = sys.executable
MARKER = "PWNED"  # every payload touches <attack dir>/PWNED
GIB = 1 << 30
SERVER_GROWTH_LIMIT_MB = 64.0  # a refused body may cost the server a little, never its size

OUTCOMES = ("code execution", "data loss", "runaway", "traceback", "silent accept", "unclear error", "flagged",
            "clean error", "ok", "skipped", "setup failed")


# ---------------------------------------------------------------------------------------------- running commands
@dataclasses.dataclass
class Proc:
    """What one child process did."""

    argv: list[str]
    returncode: int | None
    stdout: str
    stderr: str
    seconds: float
    timed_out: bool
    maxrss_mb: float
    vm_peak_mb: float  # the largest address space seen while it ran (what RLIMIT_AS limits), sampled
    leftover: list[int]  # processes of its group still alive after it exited (killed by the runner)

    @property
    def memory_capped(self) -> bool:
        text = self.stdout + self.stderr
        return ("MemoryError" in text or "Cannot allocate memory" in text or "bad_alloc" in text
                or "error: out of memory" in text or (self.returncode == -signal.SIGKILL and not self.timed_out))


class Runner:
    """Runs commands as children under the memory cap and timeout of this replay."""

    def __init__(self, timeout: float, memory_bytes: int) -> None:
        self.timeout = timeout
        self.memory_bytes = memory_bytes
        self.env = dict(os.environ, MPLBACKEND="Agg", PYTHONWARNINGS="default", COLUMNS="120")

    def limit(self, memory_bytes: int | None = None) -> Callable[[], None]:
        cap = memory_bytes or self.memory_bytes

        def apply() -> None:
            resource.setrlimit(resource.RLIMIT_AS, (cap, cap))

        return apply

    def popen(self, args: Sequence[str], cwd: Path, *, memory_bytes: int | None = None,
              env: dict[str, str] | None = None) -> subprocess.Popen:
        """``python -m pbicrl.cli ARGS`` started in its own session (process group), pipes for stdout/stderr."""
        # preexec_fn only calls setrlimit (no lock a reader thread could hold), as tests/test_attacks.py does
        return subprocess.Popen([PY, "-m", "pbicrl.cli", *args], cwd=cwd, stdin=subprocess.DEVNULL,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, start_new_session=True,
                                preexec_fn=self.limit(memory_bytes),  # noqa: PLW1509
                                env={**self.env, **(env or {})})

    def run(self, args: Sequence[str], cwd: Path, *, timeout: float | None = None, memory_bytes: int | None = None,
            env: dict[str, str] | None = None) -> Proc:
        """Run to completion (or kill the group at the timeout); per-child peak memory from ``wait4``."""
        limit_s = timeout or self.timeout
        t0 = time.monotonic()
        p = self.popen(args, cwd, memory_bytes=memory_bytes, env=env)
        out: list[bytes] = []
        err: list[bytes] = []
        readers = [threading.Thread(target=lambda s, acc: acc.append(s.read()), args=(s, acc), daemon=True)
                   for s, acc in ((p.stdout, out), (p.stderr, err))]
        for r in readers:
            r.start()
        timed_out = False
        vm_peak = 0.0
        while True:
            pid, status, usage = os.wait4(p.pid, os.WNOHANG)
            if pid:
                break
            vm_peak = max(vm_peak, proc_status_mb(p.pid, "VmPeak"))
            if time.monotonic() - t0 > limit_s:
                timed_out = True
                kill_group(p.pid)
                pid, status, usage = os.wait4(p.pid, 0)
                break
            time.sleep(0.05)
        seconds = time.monotonic() - t0
        p.returncode = os.waitstatus_to_exitcode(status)
        leftover = group_members(p.pid)
        if leftover:
            kill_group(p.pid)
        for r in readers:
            r.join(timeout=10)
        return Proc(argv=list(args), returncode=p.returncode, stdout=b"".join(out).decode(errors="replace"),
                    stderr=b"".join(err).decode(errors="replace"), seconds=seconds, timed_out=timed_out,
                    maxrss_mb=usage.ru_maxrss / 1024.0, vm_peak_mb=vm_peak, leftover=leftover)


def _stat_fields(pid: int) -> list[str] | None:
    """Fields of ``/proc/PID/stat`` after the command name (state is [0], ppid [1], pgrp [2])."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    return text[text.rindex(")") + 2:].split()


def proc_status_mb(pid: int, field: str) -> float:
    """A ``kB`` field of ``/proc/PID/status`` (``VmRSS``, ``VmHWM``, ``VmPeak``) in MB; 0 when unreadable."""
    try:
        for ln in Path(f"/proc/{pid}/status").read_text().splitlines():
            if ln.startswith(field + ":"):
                return int(ln.split()[1]) / 1024.0
    except (OSError, ValueError, IndexError):
        pass
    return 0.0


def alive(pid: int) -> bool:
    f = _stat_fields(pid)
    return f is not None and f[0] not in "ZX"


def group_members(pgid: int) -> list[int]:
    """Live processes whose process group is ``pgid``."""
    found = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            f = _stat_fields(int(d.name))
            if f is not None and int(f[2]) == pgid and f[0] not in "ZX":
                found.append(int(d.name))
    return found


def descendants(pid: int) -> list[int]:
    """Live descendants of ``pid`` (from ``/proc``)."""
    parent_of = {}
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            f = _stat_fields(int(d.name))
            if f is not None and f[0] not in "ZX":
                parent_of[int(d.name)] = int(f[1])
    found, frontier = [], [pid]
    while frontier:
        p = frontier.pop()
        kids = [c for c, pp in parent_of.items() if pp == p]
        found += kids
        frontier += kids
    return found


def kill_group(pgid: int) -> None:
    """SIGKILL a process group this replay started."""
    try:
        os.killpg(pgid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass


# ---------------------------------------------------------------------------------------------- outcomes
@dataclasses.dataclass
class Outcome:
    """One row of the table."""

    id: str
    item: int
    command: str
    outcome: str
    seconds: float
    evidence: str
    returncode: int | None = None
    stderr_tail: str = ""
    details: dict[str, Any] = dataclasses.field(default_factory=dict)


def sha_tree(root: Path) -> dict[str, str]:
    """SHA-256 of every regular file under ``root`` (relative paths), symbolic links not followed."""
    digests = {}
    for p in sorted(root.rglob("*")):
        if p.is_file() and not p.is_symlink():
            digests[str(p.relative_to(root))] = hashlib.sha256(p.read_bytes()).hexdigest()
    return digests


def lost_files(root: Path, before: dict[str, str], may_change: Sequence[str] = ()) -> list[str]:
    """Files of ``before`` that are gone or changed, except those under a ``may_change`` prefix."""
    after = sha_tree(root)
    lost = []
    for name, digest in before.items():
        if any(name == m or name.startswith(m.rstrip("/") + "/") for m in may_change):
            continue
        if name not in after:
            lost.append(f"{name} deleted")
        elif after[name] != digest:
            lost.append(f"{name} changed")
    return lost


def error_line(text: str) -> str:
    """The line that names the problem: ``pbicrl: error: ...`` or ``error: ...``, else the last non-empty line."""
    lines = [ln.strip() for ln in re.split(r"[\r\n]+", text) if ln.strip()]
    for ln in lines:
        if ln.startswith(("pbicrl: error:", "error:")):
            return ln
    return lines[-1] if lines else ""


def short(text: str, n: int = 150) -> str:
    text = " ".join(text.split())
    return text if len(text) <= n else text[:n - 3] + "..."


def has_all(text: str, needles: Sequence[str]) -> list[str]:
    """The needles missing from ``text`` (case-insensitive)."""
    low = text.lower()
    return [n for n in needles if n.lower() not in low]


def classify(proc: Proc, *, expect: str, needles: Sequence[str] = (), forbid: Sequence[str] = (),
             executed: bool = False, lost: Sequence[str] = (), flag: Sequence[str] = ()) -> tuple[str, str]:
    """Outcome class and one line of evidence for a finished command.

    ``expect``: ``refuse`` (must exit non-zero naming ``needles``), ``flag`` (exit 0 with every ``flag`` text on
    stderr, or a clean refusal) or ``ok`` (must exit 0).
    """
    text = proc.stdout + proc.stderr
    line = error_line(proc.stderr)
    if executed:
        return "code execution", f"{MARKER} was created by the payload; rc {proc.returncode}"
    if lost:
        return "data loss", f"{', '.join(lost)}; rc {proc.returncode}"
    if proc.timed_out:
        return "runaway", f"killed at the {proc.seconds:.0f} s timeout; last stderr: {short(line, 90)}"
    if proc.memory_capped:
        return "runaway", f"memory cap hit (rc {proc.returncode}, peak {proc.maxrss_mb:.0f} MB)"
    if proc.leftover:
        return "runaway", f"processes {proc.leftover} of its group outlived it"
    if "Traceback" in text:
        exc = [ln for ln in text.splitlines() if re.match(r"^\w[\w.]*(Error|Exception|Interrupt)\b", ln)]
        return "traceback", f"rc {proc.returncode}: {short(exc[-1] if exc else line, 120)}"
    if proc.returncode == 0:
        if expect == "ok":
            last = [ln.strip() for ln in re.split(r"[\r\n]+", proc.stdout + "\n" + proc.stderr) if ln.strip()]
            return "ok", f"rc 0: {short(last[-1] if last else '', 120)}"
        if expect == "flag" and not has_all(proc.stderr + proc.stdout, flag):
            return "flagged", f"rc 0, warned: {short(_first_with(text, flag[0]) if flag else line, 120)}"
        return "silent accept", f"rc 0 where a refusal was due: {short(line, 110)}"
    missing = has_all(line, needles) if line else list(needles)
    missing = has_all(proc.stderr, missing)  # a multi-line message may name it on a later line
    named_forbidden = [f for f in forbid if f in line]
    if missing or named_forbidden:
        why = (f"lacks {missing}" if missing else "") + (f" names {named_forbidden}" if named_forbidden else "")
        return "unclear error", f"rc {proc.returncode} ({why.strip()}): {short(line, 110)}"
    note = " (a legitimate command was refused)" if expect == "ok" else ""
    return "clean error", f"rc {proc.returncode}: {short(line, 130)}{note}"


def _first_with(text: str, needle: str) -> str:
    for ln in re.split(r"[\r\n]+", text):
        if needle.lower() in ln.lower():
            return ln.strip()
    return ""


# ---------------------------------------------------------------------------------------------- crafted files
class MarkerPayload:
    """Unpickling this runs ``touch MARKER``: proof that a loader executed code from a file."""

    def __init__(self, marker: Path) -> None:
        self.command = f"touch {shlex.quote(str(marker))}"

    def __reduce__(self) -> tuple[Any, tuple[str]]:
        return (os.system, (self.command,))


def torch_payload(path: Path, marker: Path) -> Path:
    """A file as SB3's ``policy.save`` writes it (``torch.save`` of a dict of Python objects), payload inside."""
    import torch

    torch.save({"state_dict": {}, "data": {"net_arch": MarkerPayload(marker)}}, path)
    return path


def sb3_model_zip(path: Path, marker: Path) -> Path:
    """A Stable-Baselines3 model archive whose ``data`` JSON holds cloudpickled (base64) payloads, as
    ``SAC.save`` stores classes and spaces; ``policy.pth`` is a ``torch.save`` payload too."""
    import io

    import torch

    serial = base64.b64encode(pickle.dumps(MarkerPayload(marker))).decode()
    data = {key: {":type:": "<class 'gymnasium.spaces.box.Box'>", ":serialized:": serial}
            for key in ("policy_class", "observation_space", "action_space", "lr_schedule")}
    data["num_timesteps"] = 10
    weights = io.BytesIO()
    torch.save({"actor": MarkerPayload(marker)}, weights)
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr("data", json.dumps(data))
        zf.writestr("policy.pth", weights.getvalue())
        zf.writestr("pytorch_variables.pth", weights.getvalue())
        zf.writestr("_stable_baselines3_version", "2.3.2")
        zf.writestr("system_info.txt", "- OS: Linux\n")
    return path


def save_dataset(ds: Any, path: Path) -> Path:
    return Path(ds.save(path))


# ---------------------------------------------------------------------------------------------- the attacks
@dataclasses.dataclass
class Attack:
    id: str
    item: int
    command: str  # what the user types, in short
    body: Callable[[Context], Outcome | tuple[str, str, Proc | None]]
    needs: tuple[str, ...] = ()  # optional modules; missing: skipped


@dataclasses.dataclass
class Context:
    """What an attack gets: its own directory, the runner, and helpers."""

    dir: Path
    runner: Runner
    attack: Attack
    details: dict[str, Any] = dataclasses.field(default_factory=dict)

    @property
    def marker(self) -> Path:
        return self.dir / MARKER

    def setup(self, *args: str, timeout: float = 300) -> Proc:
        """A pbicrl command that prepares the attack; it must succeed."""
        proc = self.runner.run(list(args), self.dir, timeout=timeout)
        if proc.returncode != 0:
            raise SetupError(f"setup `pbicrl {' '.join(args)}` failed (rc {proc.returncode}): "
                             f"{short(error_line(proc.stderr), 200)}")
        return proc

    def cli(self, *args: str, expect: str = "refuse", needles: Sequence[str] = (), forbid: Sequence[str] = (),
            flag: Sequence[str] = (), may_change: Sequence[str] = (), timeout: float | None = None,
            memory_bytes: int | None = None, env: dict[str, str] | None = None) -> tuple[str, str, Proc]:
        """Run the attack's command with the snapshot, marker and classification around it."""
        before = sha_tree(self.dir)
        proc = self.runner.run(list(args), self.dir, timeout=timeout, memory_bytes=memory_bytes, env=env)
        lost = lost_files(self.dir, before, may_change)
        outcome, evidence = classify(proc, expect=expect, needles=needles, forbid=forbid, flag=flag,
                                     executed=self.marker.exists(), lost=lost)
        return outcome, evidence, proc

    def run_made(self, name: str = "run", data: str = "example", *extra: str) -> Path:
        """A short run of ``pbicrl infer`` into ``name``."""
        self.setup("infer", data, "--out", name, "--iterations", "2000", "--chains", "1", "--no-progress", *extra)
        return self.dir / name

    def example_copy(self, name: str = "data.npz") -> Path:
        from pbicrl.inference.data import resolve_dataset_path

        dst = self.dir / name
        dst.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(resolve_dataset_path("example"), dst)
        return dst


class SetupError(RuntimeError):
    """An attack could not be prepared (reported as ``setup failed``)."""


QUICK = ("--iterations", "2000", "--chains", "1", "--no-progress")


def simple(*args: str, **kw: Any) -> Callable[[Context], tuple[str, str, Proc]]:
    """An attack that is one command in a directory prepared by ``kw['prepare']`` (optional)."""
    prepare = kw.pop("prepare", None)

    def body(ctx: Context) -> tuple[str, str, Proc]:
        if prepare is not None:
            prepare(ctx)
        return ctx.cli(*args, **kw)

    return body


# ----- item 1: code execution -----------------------------------------------------------------------------------
def _crafted_checkpoint(ctx: Context, legacy_buffer: bool) -> None:
    ck = ctx.dir / "DIR" / "checkpoint"
    ck.mkdir(parents=True)
    sb3_model_zip(ck / "model.zip", ctx.marker)
    (ck / "state.json").write_text('{"num_timesteps": 10}')
    if legacy_buffer:
        (ck / "replay_buffer.pkl").write_bytes(pickle.dumps(MarkerPayload(ctx.marker)))
    else:
        np.savez(ck / "replay_buffer.npz", observations=np.zeros((1, 1, 2)))


def _evil_policy(ctx: Context) -> None:
    torch_payload(ctx.dir / "evil.zip", ctx.marker)


def _evil_sb3(ctx: Context) -> None:
    sb3_model_zip(ctx.dir / "evil_sb3.zip", ctx.marker)


def _relabel_source(ctx: Context) -> None:
    src = ctx.dir / "nominal_run"
    (src / "checkpoint").mkdir(parents=True)
    sb3_model_zip(src / "final_model.zip", ctx.marker)
    np.savez(src / "checkpoint" / "replay_buffer.npz", observations=np.zeros((4, 1, 2)),
             next_observations=np.zeros((4, 1, 2)), actions=np.zeros((4, 1, 2)), dones=np.zeros((4, 1)))
    (src / "checkpoint" / "replay_buffer.pkl").write_bytes(pickle.dumps(MarkerPayload(ctx.marker)))


def _feature_file(ctx: Context) -> None:
    (ctx.dir / "f.py").write_text(f"open({str(ctx.marker)!r}, 'w').close()\n\ndef f(episode):\n    return [[0.0]]\n")
    (ctx.dir / "minari_root").mkdir()


TRAIN = ("envs", "train", "--env", "point_mass", "--reward", "nominal", "--steps", "100", "--out", "DIR", "--quiet")
DEMOS = ("envs", "demos", "--env", "point_mass", "-n", "1", "--max-episodes", "2", "--out", "d.npz")
RL = ("torch", "stable_baselines3", "gymnasium")
WALL_QUICK = ("-n", "1", "--steps", "20", "--max-attempts-factor", "2")  # a few seconds of rollouts at most


# ----- item 2: --overwrite -----------------------------------------------------------------------------------------
def _run_with_data_inside(ctx: Context) -> None:
    ctx.run_made("runA")
    ctx.example_copy("runA/data.npz")


def _run_with_config_inside(ctx: Context) -> None:
    ctx.run_made("runB")
    (ctx.dir / "runB" / "cfg.toml").write_text("iterations = 2000\nchains = 1\n")


def _tune_dir_with_data_inside(ctx: Context) -> None:
    ctx.setup("tune-margins", "example", "--relation", "1,1", "--grid", "0,1", "--out", "runC", "--iterations",
              "1000", "--no-progress")
    ctx.example_copy("runC/data.npz")


def _train_safe_dir(ctx: Context) -> None:
    ctx.setup("train-safe", "--env", "point_mass", "--steps", "200", "--cost", "true", "--out", "SAFE", "--quiet",
              "--eval-episodes", "1")


def _thesis_dir(ctx: Context) -> None:
    run = ctx.run_made("made")
    thesis = ctx.dir / "thesis"
    thesis.mkdir()
    for name in ("summary.json", "chains.npz"):
        shutil.copyfile(run / name, thesis / name)  # a folder of the user's: a run's files and a thesis
    (thesis / "thesis.tex").write_text("\\chapter{Results}\n")
    shutil.rmtree(run)


def _own_run(ctx: Context) -> None:
    ctx.run_made("runA")


# ----- item 3: export over the dataset -----------------------------------------------------------------------------
def _run_of_local_data(ctx: Context) -> None:
    ctx.example_copy("DATA.npz")
    ctx.run_made("RUN", "DATA.npz")


# ----- item 4: writers -------------------------------------------------------------------------------------------
def _labelling_pool(ctx: Context) -> None:
    """A labelling file: 60 labelled, 60 unlabelled, 10 of them skipped (export keeps the 60 labelled ones)."""
    from pbicrl.inference.data import load_dataset

    ds = load_dataset("example").subset(np.arange(120))
    group = ds.group.copy()
    group[1::2] = 0
    skipped = np.zeros(ds.n_trajectories, dtype=bool)
    skipped[1:21:2] = True
    pool = dataclasses.replace(ds, group=group, allow_unlabelled=True, skipped=skipped)
    save_dataset(pool, ctx.dir / "POOL.npz")
    (ctx.dir / "notes.npz").write_text("my notes, not a dataset\n")


def _precious(*names: str, content: str = "precious, not pbicrl's\n") -> Callable[[Context], None]:
    def prepare(ctx: Context) -> None:
        for n in names:
            (ctx.dir / n).parent.mkdir(parents=True, exist_ok=True)
            (ctx.dir / n).write_text(content)

    return prepare


def _copied_policy(ctx: Context) -> None:
    """The shipped Ant policies, copied: what a user's own demonstrators look like."""
    for name, role in (("p.zip", "good"), ("g.zip", "good"), ("good.npz", "good"), ("v.zip", "violating")):
        shutil.copyfile(_shipped_policy(f"ant_{role}"), ctx.dir / name)


def _plot_over_figure(ctx: Context) -> None:
    ctx.run_made("RUN")
    (ctx.dir / "DIR").mkdir()
    (ctx.dir / "DIR" / "trace.png").write_bytes(b"my own figure, not pbicrl's")


# ----- item 7: NaN chains ----------------------------------------------------------------------------------------
def _nan_run(ctx: Context) -> None:
    ctx.example_copy("data.npz")
    run = ctx.run_made("run", "data.npz")
    with np.load(run / "chains.npz") as z:
        arrays = {k: z[k] for k in z.files}
    arrays["penalty_weights"] = np.full_like(arrays["penalty_weights"], np.nan)
    np.savez(run / "chains.npz", **arrays)


# ----- item 8: sweep ---------------------------------------------------------------------------------------------
def _explode(ctx: Context) -> None:
    grid = "\n".join(f"k{i} = [{', '.join(str(v) for v in range(60))}]" for i in range(8))
    (ctx.dir / "explode.toml").write_text(f'[base]\nkind = "infer"\ndata = "example"\n\n[grid]\n{grid}\n')


# ----- item 10 ---------------------------------------------------------------------------------------------------
LONG_NAME = "a" * 300 + ".npz"


def _wrong_width(ctx: Context) -> None:
    from pbicrl.inference.data import Dataset, load_dataset

    pm = load_dataset("point_mass")
    save_dataset(Dataset(features=pm.features[:, :3], offsets=pm.offsets, group=pm.group), ctx.dir / "WRONG_WIDTH.npz")


def _malformed_policies(ctx: Context) -> None:
    from pbicrl.cli.navigation import DATA_DIR

    (ctx.dir / "junk.zip").write_bytes(b"junk")
    (ctx.dir / "cut.zip").write_bytes((DATA_DIR / "policies" / "point_mass_good.zip").read_bytes()[:50_000])


def _malformed_checkpoint(ctx: Context) -> None:
    ck = ctx.dir / "DIR" / "checkpoint"
    ck.mkdir(parents=True)
    (ck / "model.zip").write_bytes(b"junk")
    np.savez(ck / "replay_buffer.npz", x=np.zeros(1))
    (ck / "state.json").write_text("{bad")


def _ball_config(ctx: Context) -> None:
    (ctx.dir / "c.toml").write_text('[[constraints]]\nfamily = "ball"\nname = "disc"\ndims = [0, 1]\n'
                                    'bounds = [["x", 1], [0, 1], [0, 1]]\n')


# ----- item 9: identify with many features ------------------------------------------------------------------------
def _bench_module() -> Any:
    spec = importlib.util.spec_from_file_location("bench_identify_features",
                                                  REPO / "benchmarks" / "bench_identify_features.py")
    mod = importlib.util.module_from_spec(spec)  # type: ignore[arg-type]
    spec.loader.exec_module(mod)  # type: ignore[union-attr]
    return mod


PROGRESS = re.compile(r"identify:|\d+/\d+ \[|\bit/s\b|\bs/it\b")


def identify_scale(d: int, kind: str, timeout: float, fallback_gb: float = 8.0) -> Callable[[Context], Outcome]:
    """``pbicrl identify`` on ``make_dataset(d, kind=kind)`` of ``benchmarks/bench_identify_features.py``: seconds,
    whether a progress line appeared, peak memory. A run that hits the memory cap is run again under
    ``fallback_gb`` so that its time is known (the row stays a runaway)."""

    def body(ctx: Context) -> Outcome:
        ds = _bench_module().make_dataset(d, kind=kind)
        path = save_dataset(ds, ctx.dir / f"features_{d}_{kind}.npz")
        outcome, evidence, proc = ctx.cli("identify", path.name, expect="ok", timeout=timeout)
        first = ""
        if proc.memory_capped and fallback_gb:
            said = error_line(proc.stderr).split("error:", 1)[-1].strip()
            first = (f"hit the {ctx.runner.memory_bytes / GIB:g} GB address-space cap after {proc.seconds:.0f} s "
                     f"('{short(said, 40)}', address space {proc.vm_peak_mb:.0f} MB, resident "
                     f"{proc.maxrss_mb:.0f} MB); under {fallback_gb:g} GB: ")
            ctx.details["capped_run"] = {"seconds": proc.seconds, "vm_peak_mb": proc.vm_peak_mb,
                                         "peak_rss_mb": proc.maxrss_mb, "stderr_tail": proc.stderr[-500:]}
            _, evidence, proc = ctx.cli("identify", path.name, expect="ok", timeout=timeout,
                                        memory_bytes=int(fallback_gb * GIB))
        progress = bool(PROGRESS.search(proc.stderr))
        if proc.returncode == 0 and not proc.timed_out:
            if not first:
                outcome = "runaway" if proc.seconds > 120 else "ok"
            evidence = (f"{first}{proc.seconds:.1f} s, {'progress shown' if progress else 'no progress line'}"
                        f"{' (ran > 3 s)' if proc.seconds > 3 else ''}, resident {proc.maxrss_mb:.0f} MB, "
                        f"address space {proc.vm_peak_mb:.0f} MB" + (": over 120 s" if proc.seconds > 120 else ""))
            if proc.seconds > 120:
                outcome = "runaway"
        elif first:
            outcome, evidence = "runaway", first + evidence
        return Outcome(ctx.attack.id, ctx.attack.item, ctx.attack.command, outcome, proc.seconds, evidence,
                       proc.returncode, proc.stderr[-1500:],
                       {"features": d, "kind": kind, "progress_line": progress, "peak_rss_mb": proc.maxrss_mb,
                        "vm_peak_mb": proc.vm_peak_mb, **ctx.details})

    return body


# ---------------------------------------------------------------------------------------------- labelling server
class LabelServer:
    """``pbicrl label POOL --out labelled.npz --port 0 --no-browser [...]`` as a child, addressed over HTTP."""

    def __init__(self, ctx: Context, *extra: str, pool: str = "pool.npz", out: str = "labelled.npz") -> None:
        self.ctx = ctx
        self.args = ["label", pool, "--out", out, "--port", "0", "--no-browser", *extra]
        self.proc: subprocess.Popen | None = None
        self.log: list[str] = []
        self.port = 0

    def __enter__(self) -> LabelServer:  # noqa: PYI034  (not subclassed)
        self.proc = self.ctx.runner.popen(self.args, self.ctx.dir)
        ready = threading.Event()

        def drain(stream: Any) -> None:
            for raw in iter(stream.readline, b""):
                line = raw.decode(errors="replace")
                self.log.append(line)
                m = re.search(r"open http://\S+?:(\d+)/", line)
                if m:
                    self.port = int(m.group(1))
                    ready.set()

        for s in (self.proc.stdout, self.proc.stderr):
            threading.Thread(target=drain, args=(s,), daemon=True).start()
        deadline = time.monotonic() + 90
        while not ready.is_set():
            if self.proc.poll() is not None or time.monotonic() > deadline:
                raise SetupError(f"the labelling server did not start: {short(''.join(self.log), 300)}")
            time.sleep(0.1)
        time.sleep(0.5)  # uvicorn binds right after the line
        return self

    def __exit__(self, *exc: object) -> None:
        if self.proc is not None and self.proc.poll() is None:
            try:
                os.killpg(self.proc.pid, signal.SIGTERM)
                self.proc.wait(timeout=10)
            except (subprocess.TimeoutExpired, ProcessLookupError):
                pass
        if self.proc is not None:
            kill_group(self.proc.pid)
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                pass

    @property
    def pid(self) -> int:
        assert self.proc is not None
        return self.proc.pid

    def text(self) -> str:
        return "".join(self.log)

    def rss_mb(self, field: str = "VmRSS") -> float:
        return proc_status_mb(self.pid, field)

    def request(self, method: str, path: str, body: bytes | str | dict | None = None, *, host: str | None = None,
                headers: dict[str, str] | None = None, timeout: float = 60) -> tuple[int, Any]:
        """One HTTP/1.1 request on a new connection; returns the status and the parsed JSON (or text)."""
        import http.client

        conn = http.client.HTTPConnection("127.0.0.1", self.port, timeout=timeout)
        try:
            raw = json.dumps(body) if isinstance(body, dict) else body
            hdrs = {"Host": host or f"127.0.0.1:{self.port}", **(headers or {})}
            if raw is not None:
                hdrs.setdefault("Content-Type", "application/json")
            conn.request(method, path, body=raw.encode() if isinstance(raw, str) else raw, headers=hdrs)
            resp = conn.getresponse()
            data = resp.read().decode(errors="replace")
            try:
                return resp.status, json.loads(data)
            except ValueError:
                return resp.status, data
        finally:
            conn.close()

    def revision(self) -> int:
        status, state = self.request("GET", "/api/state")
        if status != 200:
            raise SetupError(f"GET /api/state: {status} {short(str(state), 200)}")
        return int(state["revision"])

    def label_three_groups(self) -> int:
        """ids 0-9 -> group 1, 10-19 -> 2, 20-29 -> 3; returns the revision."""
        rev = self.revision()
        for g in (1, 2, 3):
            status, st = self.request("POST", "/api/assign", {"revision": rev, "ids": list(range(10 * (g - 1), 10 * g)),
                                                               "group": g})
            if status != 200:
                raise SetupError(f"POST /api/assign: {status} {short(str(st), 200)}")
            rev = int(st["revision"])
        return rev

    def wait_inference(self, timeout: float = 240) -> dict[str, Any]:
        deadline = time.monotonic() + timeout
        while True:
            status, job = self.request("GET", "/api/infer")
            if status != 200 or job.get("status") != "running" or time.monotonic() > deadline:
                return job if isinstance(job, dict) else {"status": f"HTTP {status}"}
            time.sleep(0.5)


def _pool(ctx: Context) -> None:
    ctx.setup("pool", "point_mass", "--n", "30", "--out", "pool.npz")


def http_outcome(ctx: Context, server: LabelServer, status: int, reply: Any, *, needles: Sequence[str],
                 seconds: float, extra_ok: bool = True, extra_evidence: str = "") -> Outcome:
    """Class of an HTTP attack: 4xx naming the problem is a clean error; 2xx a silent accept; 5xx or a
    traceback in the log a traceback."""
    message = reply.get("error", "") if isinstance(reply, dict) else str(reply)
    log = server.text()
    if ctx.marker.exists():
        outcome, ev = "code execution", f"{MARKER} created"
    elif "Traceback" in log or status >= 500:
        exc = [ln for ln in log.splitlines() if re.match(r"^\w[\w.]*(Error|Exception)\b", ln)]
        outcome, ev = "traceback", f"HTTP {status}; log: {short(exc[-1] if exc else log[-200:], 110)}"
    elif 200 <= status < 300 or not extra_ok:
        shown = json.dumps(reply) if isinstance(reply, dict) else str(reply)
        outcome, ev = "silent accept", f"HTTP {status}: {short(shown, 110)}"
    elif has_all(message, needles):
        outcome, ev = "unclear error", f"HTTP {status} lacks {has_all(message, needles)}: {short(message, 100)}"
    else:
        outcome, ev = "clean error", f"HTTP {status}: {short(message, 120)}"
    return Outcome(ctx.attack.id, ctx.attack.item, ctx.attack.command, outcome, seconds,
                   ev + (f"; {extra_evidence}" if extra_evidence else ""), status, short(log[-1500:], 1500))


def server_request_attack(method: str, path: str, body: Callable[[int], bytes | str | dict] | None, *,
                          needles: Sequence[str], host: str | None = None, headers: dict[str, str] | None = None,
                          server_args: Sequence[str] = (), must_not_write: bool = True) -> Callable[[Context], Outcome]:
    """One malformed or foreign request to a fresh server; the labelled output must not be written."""

    def attack(ctx: Context) -> Outcome:
        _pool(ctx)
        with LabelServer(ctx, *server_args) as srv:
            rev = srv.revision()
            t0 = time.monotonic()
            status, reply = srv.request(method, path, None if body is None else body(rev), host=host, headers=headers)
            seconds = time.monotonic() - t0
            time.sleep(0.3)  # let the log catch up
            wrote = (ctx.dir / "labelled.npz").exists()
            alive_after = srv.proc is not None and srv.proc.poll() is None
            extra = ("labelled.npz written" if wrote and must_not_write else "") + \
                    ("" if alive_after else "; the server died")
            return http_outcome(ctx, srv, status, reply, needles=needles, seconds=seconds,
                                extra_ok=not (wrote and must_not_write) and alive_after,
                                extra_evidence=extra.strip("; "))

    return attack


def chunked_body_attack(ctx: Context) -> Outcome:
    """210 MB of chunked body to ``POST /api/assign``: the server must refuse it early without buffering it."""
    _pool(ctx)
    total = 210 * 1000 * 1000
    with LabelServer(ctx) as srv:
        srv.revision()
        rss0 = srv.rss_mb()
        t0 = time.monotonic()
        s = socket.create_connection(("127.0.0.1", srv.port), timeout=15)
        sent = 0
        try:
            s.sendall(f"POST /api/assign HTTP/1.1\r\nHost: 127.0.0.1:{srv.port}\r\nContent-Type: application/json\r\n"
                      "Transfer-Encoding: chunked\r\n\r\n".encode())
            chunk = b" " * 65536
            frame = f"{len(chunk):x}\r\n".encode() + chunk + b"\r\n"
            while sent < total:
                s.sendall(frame)
                sent += len(chunk)
            s.sendall(b"0\r\n\r\n")
        except (BrokenPipeError, ConnectionResetError, TimeoutError):
            pass
        reply = b""
        try:
            s.settimeout(30)
            while b"\r\n\r\n" not in reply or len(reply) < 20:
                part = s.recv(65536)
                if not part:
                    break
                reply += part
            head, _, rest = reply.partition(b"\r\n\r\n")
            m = re.match(rb"HTTP/1\.[01] (\d+)", head)
            status = int(m.group(1)) if m else 0
            try:
                body: Any = json.loads(rest.decode(errors="replace"))
            except ValueError:
                body = rest.decode(errors="replace")[:200]
        except OSError:  # reset, timeout
            status, body = 0, "connection closed without a response"
        finally:
            s.close()
        seconds = time.monotonic() - t0
        time.sleep(0.5)
        growth = srv.rss_mb("VmHWM") - rss0
        ev = f"{sent / 1e6:.0f} MB of body sent, server peak memory +{growth:.0f} MB"
        out = http_outcome(ctx, srv, status or 413, body, needles=["body"], seconds=seconds, extra_evidence=ev)
        if status == 0:
            out.outcome, out.evidence = ("clean error" if growth < SERVER_GROWTH_LIMIT_MB else "runaway",
                                         f"no HTTP response (connection closed); {ev}")
        elif growth >= SERVER_GROWTH_LIMIT_MB and out.outcome in ("clean error", "unclear error"):
            out.outcome = "runaway"
        out.details = {"bytes_sent": sent, "server_growth_mb": growth, "status": status}
        return out


def public_host_attack(ctx: Context) -> Outcome:
    """``--host 0.0.0.0 --allow-host lab.example``: a foreign Host must be refused (and the allowed one served)."""
    _pool(ctx)
    with LabelServer(ctx, "--host", "0.0.0.0", "--allow-host", "lab.example") as srv:
        good, _ = srv.request("GET", "/api/state", host="lab.example")
        t0 = time.monotonic()
        status, reply = srv.request("GET", "/api/state", host="evil.example")
        loop, _ = srv.request("GET", "/api/state", host="127.0.0.1")
        out = http_outcome(ctx, srv, status, reply, needles=["host"], seconds=time.monotonic() - t0,
                           extra_evidence=f"Host lab.example -> {good}, Host 127.0.0.1 -> {loop}")
        if out.outcome == "unclear error" and status == 400:  # Starlette's TrustedHostMiddleware answers in text
            out.outcome = "clean error"
        return out


def page_run_dir_attack(ctx: Context) -> Outcome:
    """Inference from the page into ``labelled.run/`` that holds the user's ``notes.txt`` besides an earlier
    page run: the notes must survive."""
    _pool(ctx)
    with LabelServer(ctx) as srv:
        srv.label_three_groups()
        status, _ = srv.request("POST", "/api/infer", {"iterations": 1000, "chains": 1, "figures": False})
        first = srv.wait_inference()
        if status != 202 or first.get("status") != "done":
            raise SetupError(f"first page inference: HTTP {status}, {short(str(first.get('message')), 200)}")
        run = ctx.dir / "labelled.run"
        (run / "notes.txt").write_text("my notes about this run\n")
        before = sha_tree(ctx.dir)
        t0 = time.monotonic()
        status, reply = srv.request("POST", "/api/infer", {"iterations": 1000, "chains": 1, "figures": False})
        if status == 202:
            job = srv.wait_inference()
        else:  # refused up front: the reply is the outcome
            job = {"status": "error" if status >= 400 else "done",
                   "message": reply.get("error", "") if isinstance(reply, dict) else str(reply)}
        seconds = time.monotonic() - t0
        lost = [x for x in lost_files(ctx.dir, before) if x.startswith("labelled.run/notes.txt")]
        message = str(job.get("message") or "")
        if lost:
            outcome, ev = "data loss", f"{', '.join(lost)} (job {job.get('status')})"
        elif "Traceback" in srv.text():
            outcome, ev = "traceback", short(srv.text()[-200:], 120)
        elif job.get("status") == "error" and "notes.txt" in message:
            outcome, ev = "clean error", f"job error: {short(message, 120)}"
        elif job.get("status") == "error":
            outcome, ev = "unclear error", f"job error without naming notes.txt: {short(message, 110)}"
        else:
            where = (job.get("result") or {}).get("run_dir")
            outcome, ev = "ok", f"job {job.get('status')}, notes.txt kept; run at {where}"
        return Outcome(ctx.attack.id, ctx.attack.item, ctx.attack.command, outcome, seconds, ev, status,
                       short(srv.text()[-1500:], 1500), {"job": {k: job.get(k) for k in ("status", "message")}})


def sigkill_label_attack(ctx: Context) -> Outcome:
    """SIGKILL of ``pbicrl label`` while its inference child samples: the child (and its resource tracker)
    must die with it, and no ``pbicrl-label-<pid>-*`` folder may stay behind."""
    _pool(ctx)
    tmp_root = Path(tempfile.gettempdir())
    with LabelServer(ctx) as srv:
        srv.label_three_groups()
        status, reply = srv.request("POST", "/api/infer", {"iterations": 2_000_000, "chains": 1, "figures": False})
        if status != 202:
            raise SetupError(f"POST /api/infer: {status} {short(str(reply), 200)}")
        deadline = time.monotonic() + 90
        while time.monotonic() < deadline:
            _, job = srv.request("GET", "/api/infer")
            if job.get("phase") == "sampling" and job.get("progress", 0) > 0:
                break
            if job.get("status") != "running":
                raise SetupError(f"inference ended before the kill: {job.get('status')} {job.get('message')}")
            time.sleep(0.3)
        kids = descendants(srv.pid)
        server_pid = srv.pid
        t0 = time.monotonic()
        os.kill(server_pid, signal.SIGKILL)  # the attack: only the server itself
        srv.proc.wait(timeout=10)  # type: ignore[union-attr]
        while time.monotonic() - t0 < 20 and any(alive(k) for k in kids):
            time.sleep(0.2)
        seconds = time.monotonic() - t0
        survivors = [k for k in kids if alive(k)]
        cpu = {}
        for k in survivors:
            f = _stat_fields(k)
            if f is not None:
                cpu[k] = {"ppid": int(f[1]), "state": f[0]}
        folders = sorted(str(p) for p in tmp_root.glob(f"pbicrl-label-{server_pid}-*"))
        for k in survivors:
            try:
                os.kill(k, signal.SIGKILL)
            except ProcessLookupError:
                pass
        if survivors:
            outcome = "runaway"
            ev = f"{len(survivors)} of {len(kids)} children alive 20 s after the kill: {cpu}"
        else:
            outcome = "ok"
            ev = f"all {len(kids)} children ({', '.join(map(str, kids))}) gone {seconds:.1f} s after the kill"
        ev += f"; {len(folders)} pbicrl-label-{server_pid}-* folder(s) left" if folders else "; no snapshot folder left"
        for f in folders:
            shutil.rmtree(f, ignore_errors=True)
        return Outcome(ctx.attack.id, ctx.attack.item, ctx.attack.command, outcome, seconds, ev, -9, "",
                       {"children": kids, "survivors": survivors, "folders": folders})


# ---------------------------------------------------------------------------------------------- the list
def attacks(identify_timeout_dense: float) -> list[Attack]:
    A = Attack
    NAN = {"needles": ["penalty_weights", "NaN"], "prepare": _nan_run}
    return [
        # 1. code execution from files a user opens
        A("1a", 1, "envs train --env point_mass --reward nominal --steps 100 --out DIR (crafted checkpoint/model.zip)",
          simple(*TRAIN, needles=["pickle"], prepare=lambda c: _crafted_checkpoint(c, legacy_buffer=False)), RL),
        A("1b", 1, "envs train ... --out DIR (crafted model.zip + replay_buffer.pkl)",
          simple(*TRAIN, needles=["pickle"], prepare=lambda c: _crafted_checkpoint(c, legacy_buffer=True)), RL),
        A("1c", 1, "envs demos --good-policy evil.zip (torch.save payload)",
          simple(*DEMOS, "--good-policy", "evil.zip", needles=["evil.zip", "pickle"], prepare=_evil_policy), RL),
        A("1d", 1, "envs demos --good-policy evil_sb3.zip (SB3 model zip, cloudpickle)",
          simple(*DEMOS, "--good-policy", "evil_sb3.zip", needles=["evil_sb3.zip", "pickle"], prepare=_evil_sb3), RL),
        A("1e", 1, "envs demos --violating-policy evil.zip",
          simple(*DEMOS, "--violating-policy", "evil.zip", needles=["evil.zip", "pickle"], prepare=_evil_policy), RL),
        A("1f", 1, "envs train --reward true --out new --init-from evil.zip",
          simple("envs", "train", "--env", "point_mass", "--reward", "true", "--steps", "100", "--out", "new",
                 "--quiet", "--init-from", "evil.zip", needles=["pickle"], prepare=_evil_policy), RL),
        A("1g", 1, "envs train --reward true --out new --init-from evil_sb3.zip",
          simple("envs", "train", "--env", "point_mass", "--reward", "true", "--steps", "100", "--out", "new",
                 "--quiet", "--init-from", "evil_sb3.zip", needles=["pickle"], prepare=_evil_sb3), RL),
        A("1h", 1, "envs train --reward true --out new --relabel-from nominal_run (crafted final_model.zip)",
          simple("envs", "train", "--env", "point_mass", "--reward", "true", "--steps", "100", "--out", "new",
                 "--quiet", "--relabel-from", "nominal_run", needles=["pickle"], prepare=_relabel_source), RL),
        A("1i", 1, "import minari nope/nothing-v0 --features f.py:f --out o.npz (f.py touches PWNED on import)",
          simple("import", "minari", "nope/nothing-v0", "--features", "f.py:f", "--out", "o.npz",
                 needles=["nope/nothing-v0"], prepare=_feature_file,
                 env={"MINARI_DATASETS_PATH": "minari_root"}), ("minari",)),
        # 2. --overwrite
        A("2a", 2, "infer runA/data.npz --out runA --overwrite",
          simple("infer", "runA/data.npz", "--out", "runA", "--overwrite", *QUICK, needles=["input", "data.npz"],
                 prepare=_run_with_data_inside)),
        A("2b", 2, "infer example --config runB/cfg.toml --out runB --overwrite",
          simple("infer", "example", "--config", "runB/cfg.toml", "--out", "runB", "--overwrite", "--no-progress",
                 needles=["cfg.toml"], prepare=_run_with_config_inside)),
        A("2c", 2, "tune-margins runC/data.npz --relation 1,1 --out runC --overwrite",
          simple("tune-margins", "runC/data.npz", "--relation", "1,1", "--grid", "0,1", "--out", "runC", "--overwrite",
                 "--iterations", "1000", "--no-progress", needles=["input"], prepare=_tune_dir_with_data_inside)),
        A("2d", 2, "infer example --out SAFE --overwrite (SAFE written by train-safe)",
          simple("infer", "example", "--out", "SAFE", "--overwrite", *QUICK, needles=["SAFE"],
                 prepare=_train_safe_dir), ("torch",)),
        A("2e", 2, "infer example --out thesis --overwrite (summary.json + thesis.tex)",
          simple("infer", "example", "--out", "thesis", "--overwrite", *QUICK, needles=["thesis.tex"],
                 prepare=_thesis_dir)),
        A("2f", 2, "infer example --out runA --overwrite (control: runA is pbicrl's own run)",
          simple("infer", "example", "--out", "runA", "--overwrite", *QUICK, expect="ok", may_change=["runA"],
                 prepare=_own_run)),
        # 3. export over the dataset
        A("3a", 3, "export RUN --netcdf DATA.npz --overwrite (the run's recorded dataset)",
          simple("export", "RUN", "--netcdf", "DATA.npz", "--overwrite", needles=["input"],
                 prepare=_run_of_local_data), ("arviz",)),
        A("3b", 3, "export RUN --netcdf DATA.npz --data DATA.npz --overwrite",
          simple("export", "RUN", "--netcdf", "DATA.npz", "--data", "DATA.npz", "--overwrite", needles=["input"],
                 prepare=_run_of_local_data), ("arviz",)),
        # 4. writers
        A("4a", 4, "label POOL.npz --export POOL.npz",
          simple("label", "POOL.npz", "--export", "POOL.npz", needles=["input"], prepare=_labelling_pool)),
        A("4b", 4, "label POOL.npz --export POOL.npz --overwrite",
          simple("label", "POOL.npz", "--export", "POOL.npz", "--overwrite", needles=["input"],
                 prepare=_labelling_pool)),
        A("4c", 4, "label POOL.npz --export notes.npz (a text file)",
          simple("label", "POOL.npz", "--export", "notes.npz", needles=["--overwrite"], prepare=_labelling_pool)),
        A("4d", 4, "label POOL.npz --export notes.npz --overwrite (control)",
          simple("label", "POOL.npz", "--export", "notes.npz", "--overwrite", expect="ok", may_change=["notes.npz"],
                 prepare=_labelling_pool)),
        A("4e", 4, "envs grid --out grid.npz (existing file)",
          simple("envs", "grid", "--out", "grid.npz", needles=["--overwrite"], prepare=_precious("grid.npz")),
          ("gymnasium",)),
        A("4f", 4, "envs demos --env point_mass ... --out d.npz (existing d.npz)",
          simple(*DEMOS, needles=["d.npz", "--overwrite"], prepare=_precious("d.npz")), RL),
        A("4g", 4, "envs demos --env point_mass ... --out d.npz (existing d.json beside it)",
          simple(*DEMOS, needles=["d.json"], prepare=_precious("d.json")), RL),
        A("4h", 4, "envs minari-to-npz --id x/y-v0 --out out.npz (existing file)",
          simple("envs", "minari-to-npz", "--id", "x/y-v0", "--out", "out.npz", needles=["--overwrite"],
                 prepare=_precious("out.npz")), ("minari",)),
        A("4i", 4, "envs demos-wall --env ant --good-policy good.npz --violating-policy v.zip --out good.npz "
                   "--overwrite",
          simple("envs", "demos-wall", "--env", "ant", "--good-policy", "good.npz", "--violating-policy", "v.zip",
                 "--out", "good.npz", "--overwrite", *WALL_QUICK, needles=["input"], prepare=_copied_policy),
          ("gymnasium", "mujoco")),
        A("4j", 4, "envs demos-wall --env ant ... --out v.zip --report g.zip --overwrite (the policies)",
          simple("envs", "demos-wall", "--env", "ant", "--good-policy", "g.zip", "--violating-policy", "v.zip",
                 "--out", "v.zip", "--report", "g.zip", "--overwrite", needles=["input"], prepare=_copied_policy),
          ("gymnasium", "mujoco")),
        A("4k", 4, "envs demos-wall --env ant (shipped policies) --out wall.npz (existing file)",
          simple("envs", "demos-wall", "--env", "ant", "--good-policy", str(_shipped_policy("ant_good")),
                 "--violating-policy", str(_shipped_policy("ant_violating")), "-n", "1", "--out", "wall.npz",
                 needles=["--overwrite"], prepare=_precious("wall.npz")), ("gymnasium", "mujoco")),
        A("4l", 4, "plot RUN --out DIR (DIR/trace.png is the user's)",
          simple("plot", "RUN", "--out", "DIR", needles=["trace.png"], prepare=_plot_over_figure), ("matplotlib",)),
        A("4m", 4, "page inference into labelled.run/ holding the user's notes.txt",
          page_run_dir_attack, ("starlette", "uvicorn")),
        # 5. processes
        A("5", 5, "kill -9 `pbicrl label` while its page inference samples",
          sigkill_label_attack, ("starlette", "uvicorn")),
        # 6. labelling server
        A("6a", 6, "POST /api/assign with a 210 MB chunked body",
          chunked_body_attack, ("starlette", "uvicorn")),
        A("6b", 6, "POST /api/assign with a body nested 50,000 [ deep",
          server_request_attack("POST", "/api/assign", lambda r: "[" * 50_000 + "]" * 50_000, needles=["nested"]),
          ("starlette", "uvicorn")),
        A("6c", 6, "POST /api/gaps gap_relation [10**30] (above int64)",
          server_request_attack("POST", "/api/gaps", lambda r: f'{{"revision": {r}, "gap_relation": [{10**30}, 1]}}',
                                needles=["out of range"]), ("starlette", "uvicorn")),
        A("6d", 6, "POST /api/infer margins [10**30, 1] (above int64)",
          server_request_attack("POST", "/api/infer", lambda r: f'{{"margins": [{10**30}, 1]}}',
                                needles=["out of range"]), ("starlette", "uvicorn")),
        A("6e", 6, "POST /api/assign with Origin: http://evil.example",
          server_request_attack("POST", "/api/assign", lambda r: {"revision": r, "ids": [0], "group": 1},
                                headers={"Origin": "http://evil.example"}, needles=["origin"]),
          ("starlette", "uvicorn")),
        A("6f", 6, "GET /api/state with Host: testserver",
          server_request_attack("GET", "/api/state", None, host="testserver", needles=[]), ("starlette", "uvicorn")),
        A("6g", 6, "label pool.npz --out o.npz --host 0.0.0.0 (no --allow-host)",
          simple("label", "pool.npz", "--out", "o.npz", "--host", "0.0.0.0", "--no-browser", needles=["--allow-host"],
                 prepare=_pool), ("starlette", "uvicorn")),
        A("6h", 6, "label ... --host 0.0.0.0 --allow-host lab.example; GET with Host: evil.example",
          public_host_attack, ("starlette", "uvicorn")),
        # 7. results that are not results
        A("7a", 7, "plot run --out figs (NaN penalty_weights)", simple("plot", "run", "--out", "figs", **NAN),
          ("matplotlib",)),
        A("7b", 7, "diagnose run (NaN chains)", simple("diagnose", "run", **NAN)),
        A("7c", 7, "export run --netcdf p.nc (NaN chains)", simple("export", "run", "--netcdf", "p.nc", **NAN),
          ("arviz",)),
        A("7d", 7, "suggest run --pool data.npz (NaN chains)", simple("suggest", "run", "--pool", "data.npz", **NAN)),
        A("7e", 7, "check run --data data.npz (NaN chains)", simple("check", "run", "--data", "data.npz", **NAN)),
        A("7f", 7, "infer example --thin 1000000000", simple("infer", "example", "--out", "r", *QUICK, "--thin",
                                                             "1000000000", needles=["draw"])),
        A("7g", 7, "infer example --iterations 1", simple("infer", "example", "--out", "r", "--chains", "1",
                                                          "--no-progress", "--iterations", "1", needles=["draw"])),
        A("7h", 7, "identify point_mass --beta 1e308", simple("identify", "point_mass", "--beta", "1e308",
                                                              needles=["beta"])),
        A("7i", 7, "infer example --beta 1e308", simple("infer", "example", "--out", "r", *QUICK, "--beta", "1e308",
                                                        needles=["beta"])),
        A("7j", 7, "infer example --beta 1e-300", simple("infer", "example", "--out", "r", *QUICK, "--beta", "1e-300",
                                                         needles=["beta"])),
        A("7k", 7, "infer example --margins 0,1e308", simple("infer", "example", "--out", "r", *QUICK, "--margins",
                                                             "0,1e308", needles=["margins"])),
        A("7l", 7, "identify point_mass --margins 0,1e308", simple("identify", "point_mass", "--margins", "0,1e308",
                                                                   needles=["margins"])),
        # 8. sweep size
        A("8", 8, "sweep explode.toml --dry-run (60^8 grid)",
          simple("sweep", "explode.toml", "--dry-run", needles=["167,961,600,000,000"], prepare=_explode)),
        # 9. identify with many features
        A("9a", 9, "identify features_100_cells.npz", identify_scale(100, "cells", 120)),
        A("9b", 9, "identify features_1000_cells.npz", identify_scale(1000, "cells", 120)),
        A("9c", 9, "identify features_10000_cells.npz", identify_scale(10000, "cells", 120)),
        A("9d", 9, "identify features_100_noise.npz", identify_scale(100, "noise", 120)),
        A("9e", 9, "identify features_1000_noise.npz", identify_scale(1000, "noise", 120)),
        A("9f", 9, "identify features_10000_noise.npz (dense)", identify_scale(10000, "noise", identify_timeout_dense)),
        # 10. tracebacks, silent ignores, unclear errors
        A("10a", 10, "info aaa...(300).npz", simple("info", LONG_NAME, needles=["cannot be looked up"])),
        A("10b", 10, "infer aaa...(300).npz --out o", simple("infer", LONG_NAME, "--out", "o", *QUICK,
                                                              needles=["cannot be looked up"])),
        A("10c", 10, "identify aaa...(300).npz", simple("identify", LONG_NAME, needles=["cannot be looked up"])),
        A("10d", 10, "reproduce point-mass --data point_mass=WRONG_WIDTH.npz --out r",
          simple("reproduce", "point-mass", "--data", "point_mass=WRONG_WIDTH.npz", "--out", "r",
                 needles=["point_mass", "features"], prepare=_wrong_width)),
        A("10e", 10, "envs demos --good-policy junk.zip (not a zip)",
          simple(*DEMOS, "--good-policy", "junk.zip", needles=["junk.zip", "not a zip"], prepare=_malformed_policies),
          RL),
        A("10f", 10, "envs demos --good-policy cut.zip (truncated policy)",
          simple(*DEMOS, "--good-policy", "cut.zip", needles=["cut.zip"], prepare=_malformed_policies), RL),
        A("10g", 10, "envs train --out DIR (junk checkpoint/model.zip, state.json '{bad')",
          simple(*TRAIN, needles=["state.json"], prepare=_malformed_checkpoint), RL),
        A("10h", 10, "envs train --reward true --init-from junk.zip",
          simple("envs", "train", "--env", "point_mass", "--reward", "true", "--steps", "100", "--out", "new",
                 "--quiet", "--init-from", "junk.zip", needles=["junk.zip"], prepare=_malformed_policies), RL),
        A("10i", 10, "reproduce point-mass --data nope=data.npz --out r",
          simple("reproduce", "point-mass", "--data", "nope=data.npz", "--out", "r", needles=["nope"],
                 prepare=lambda c: c.example_copy("data.npz"))),
        A("10j", 10, "tune-margins example --relation 1,1 --grid '' --out t",
          simple("tune-margins", "example", "--relation", "1,1", "--grid", "", "--out", "t", needles=["--grid"])),
        A("10k", 10, "infer example --out /sys/pbicrl_replay_run (unwritable parent)",
          simple("infer", "example", "--out", "/sys/pbicrl_replay_run", *QUICK, needles=["/sys/pbicrl_replay_run"],
                 forbid=[".lock", ".tmp-"])),
        A("10l", 10, "tune-margins example --relation 1,1 --out /sys/pbicrl_replay_t (unwritable parent)",
          simple("tune-margins", "example", "--relation", "1,1", "--grid", "0,1", "--out", "/sys/pbicrl_replay_t",
                 needles=["/sys/pbicrl_replay_t"], forbid=[".lock", ".tmp-"])),
        A("10n", 10, "envs demos-wall --env ant --good-policy p.zip --violating-policy p.zip --out p.zip --overwrite",
          simple("envs", "demos-wall", "--env", "ant", "--good-policy", "p.zip", "--violating-policy", "p.zip",
                 "--out", "p.zip", "--overwrite", *WALL_QUICK, needles=["violating"], prepare=_copied_policy),
          ("gymnasium", "mujoco")),
        A("10m", 10, "infer example --config c.toml (ball bounds [['x', 1], ...])",
          simple("infer", "example", "--config", "c.toml", "--out", "o", *QUICK, needles=["disc", "bounds"],
                 prepare=_ball_config)),
    ]


def _shipped_policy(name: str) -> Path:
    return REPO / "src" / "pbicrl" / "data" / "policies" / f"{name}.zip"


# ---------------------------------------------------------------------------------------------- payload control
_UNSAFE_LOADS = """
import json, os, pickle, runpy, sys
marker, results = sys.argv[1], {}
def attempt(name, load):
    try:
        load()
    except BaseException:
        pass
    results[name] = os.path.exists(marker)
    if os.path.exists(marker):
        os.remove(marker)
def sb3():
    from stable_baselines3 import SAC
    SAC.load("evil_sb3.zip")
import torch
attempt("torch.load(weights_only=False) of evil.zip", lambda: torch.load("evil.zip", weights_only=False))
attempt("SAC.load of evil_sb3.zip", sb3)
attempt("pickle.load of replay_buffer.pkl", lambda: pickle.load(open("replay_buffer.pkl", "rb")))
attempt("running f.py", lambda: runpy.run_path("f.py"))
print(json.dumps(results))
"""


def payload_control(runner: Runner) -> dict[str, bool]:
    """The crafted files do run their payload when loaded the unsafe way (else a clean row would prove nothing)."""
    d = Path(tempfile.mkdtemp(prefix="replay31-control-"))
    try:
        marker = d / MARKER
        torch_payload(d / "evil.zip", marker)
        sb3_model_zip(d / "evil_sb3.zip", marker)
        (d / "replay_buffer.pkl").write_bytes(pickle.dumps(MarkerPayload(marker)))
        (d / "f.py").write_text(f"open({str(marker)!r}, 'w').close()\n")
        proc = subprocess.run([PY, "-c", _UNSAFE_LOADS, str(marker)], cwd=d, capture_output=True, text=True,
                              timeout=runner.timeout, preexec_fn=runner.limit(), env=runner.env, check=False)
        lines = proc.stdout.strip().splitlines()
        return json.loads(lines[-1]) if proc.returncode == 0 and lines else {"error": short(proc.stderr, 200)}
    finally:
        shutil.rmtree(d, ignore_errors=True)


# ---------------------------------------------------------------------------------------------- driver
def run_attack(attack: Attack, runner: Runner, keep: bool) -> Outcome:
    missing = [m for m in attack.needs if importlib.util.find_spec(m) is None]
    if missing:
        return Outcome(attack.id, attack.item, attack.command, f"skipped (missing extra {missing[0]})", 0.0, "")
    d = Path(tempfile.mkdtemp(prefix=f"replay31-{attack.id}-"))
    ctx = Context(d, runner, attack)
    t0 = time.monotonic()
    try:
        res = attack.body(ctx)
        if isinstance(res, Outcome):
            out = res
        else:
            outcome, evidence, proc = res
            if attack.id in ("10d",):  # the issue asks for the time to the refusal
                evidence = f"{proc.seconds:.1f} s; {evidence}"
            out = Outcome(attack.id, attack.item, attack.command, outcome, proc.seconds, evidence, proc.returncode,
                          proc.stderr[-1500:], {"peak_rss_mb": proc.maxrss_mb})
    except SetupError as exc:
        out = Outcome(attack.id, attack.item, attack.command, "setup failed", time.monotonic() - t0, str(exc))
    except Exception as exc:  # noqa: BLE001  (a bug of this script: reported, the replay goes on)
        out = Outcome(attack.id, attack.item, attack.command, "setup failed", time.monotonic() - t0,
                      f"replay error {type(exc).__name__}: {short(str(exc), 200)}")
    finally:
        if keep:
            out_dir = str(d)
        else:
            shutil.rmtree(d, ignore_errors=True)
            out_dir = None
    out.details["dir"] = out_dir
    return out


def print_row(o: Outcome) -> None:
    print(f"{o.id:<4} {o.item:>2}  {short(o.command, 62):<62} {o.outcome:<14} {o.seconds:7.1f}  {o.evidence}",
          flush=True)


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--json", type=Path, help="write every row (and the totals) to this file")
    ap.add_argument("--only", help="comma-separated attack ids or item numbers (e.g. 2a,7)")
    ap.add_argument("--timeout", type=float, default=120.0, help="seconds per command (default 120)")
    ap.add_argument("--dense-timeout", type=float, default=300.0,
                    help="seconds for identify on 10,000 dense features (default 300)")
    ap.add_argument("--memory-gb", type=float, default=4.0, help="RLIMIT_AS of every child (default 4)")
    ap.add_argument("--keep", action="store_true", help="keep the attack directories (printed in the JSON)")
    args = ap.parse_args(argv)

    runner = Runner(args.timeout, int(args.memory_gb * GIB))
    chosen = attacks(args.dense_timeout)
    if args.only:
        keys = {k.strip() for k in args.only.split(",") if k.strip()}
        chosen = [a for a in chosen if a.id in keys or str(a.item) in keys]
    t_start = time.monotonic()
    control: dict[str, Any] = {}
    if any(a.item == 1 for a in chosen) and all(importlib.util.find_spec(m) for m in RL):
        control = payload_control(runner)
        print("payload control (each must be True: the payload runs when the file is loaded unsafely): "
              + ", ".join(f"{k}: {v}" for k, v in control.items()), flush=True)
    print(f"{'id':<4} {'it':>2}  {'command':<62} {'outcome':<14} {'seconds':>7}  evidence", flush=True)
    rows = []
    for a in chosen:
        o = run_attack(a, runner, args.keep)
        print_row(o)
        rows.append(o)
    totals: dict[str, int] = {}
    for o in rows:
        totals[o.outcome] = totals.get(o.outcome, 0) + 1
    total_s = time.monotonic() - t_start
    print(f"\n{len(rows)} attacks in {total_s:.0f} s: " + ", ".join(f"{n} {k}" for k, n in
                                                              sorted(totals.items(), key=lambda kv: -kv[1])))
    if args.json:
        commit = subprocess.run(["git", "-C", str(REPO), "rev-parse", "HEAD"], capture_output=True, text=True,
                                check=False).stdout
        meta = {"commit": commit.strip(), "date": datetime.datetime.now().isoformat(timespec="seconds"),
                "python": platform.python_version(), "cpus": os.cpu_count(), "load_average_end": os.getloadavg(),
                "timeout_s": args.timeout, "memory_gb": args.memory_gb, "seconds": total_s,
                "payload_control": control}
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"meta": meta, "totals": totals,
                                         "rows": [dataclasses.asdict(o) for o in rows]}, indent=2, default=str))
    return 0


if __name__ == "__main__":
    sys.exit(main())
