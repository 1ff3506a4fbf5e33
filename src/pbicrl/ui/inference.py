"""Inference started from the labelling page: a short chain in a child process, with progress.

The child (``spawn``: the server's threads are not forked) runs :func:`pbicrl.infer` on the labelled
trajectories, saves the run next to the labels (``<out stem>.run/``, with the labelled data as
``data.npz`` so that ``pbicrl suggest`` and ``pbicrl plot`` find it), draws the figures of ``pbicrl plot``
when matplotlib is installed, ranks the unlabelled trajectories (:func:`pbicrl.analysis.suggest.suggest`) and sends
back a summary (:func:`summarise`). Progress comes from the sampler's progress bar, which the child replaces
with one that reports to the parent (``pbicrl.infer`` has no progress callback of its own).
"""

from __future__ import annotations

import multiprocessing as mp
import os
import queue
import threading
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["InferenceJob", "InferenceSettings", "JobBusy", "summarise", "run_dir_for"]

_MAX_ITERATIONS = 2_000_000
_MAX_CHAINS = 8


class JobBusy(RuntimeError):
    """An inference is already running for this session."""


def run_dir_for(out: Path) -> Path:
    """Where the page's inference runs go: ``LABELLED.run/`` beside ``LABELLED.npz``."""
    return out.with_name(out.stem + ".run")


@dataclass(frozen=True)
class InferenceSettings:
    """What the page may choose: iterations and chains per run, margins (K-1 gaps), seed, suggestions, and
    whether to draw the figures of ``pbicrl plot`` (the slowest step of a short run)."""

    iterations: int = 20_000
    chains: int = 2
    margins: tuple[float, ...] | None = None
    seed: int = 0
    n_suggest: int = 5
    figures: bool = True

    @classmethod
    def from_json(cls, body: Any) -> "InferenceSettings":
        """Validate the JSON body of ``POST /api/infer``; errors name the field."""
        if body is None:
            body = {}
        if not isinstance(body, dict):
            raise ValueError("body: expected a JSON object such as {\"iterations\": 20000, \"chains\": 2}")
        unknown = sorted(set(body) - {"iterations", "chains", "margins", "seed", "n_suggest", "figures", "revision"})
        if unknown:
            raise ValueError(f"{unknown[0]}: unknown setting; settings are iterations, chains, margins, seed, "
                             "n_suggest, figures")
        figures = body.get("figures", True)
        if not isinstance(figures, bool):
            raise ValueError(f"figures: expected true or false, got {figures!r}")

        def integer(name: str, lo: int, hi: int, default: int) -> int:
            v = body.get(name, default)
            if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
                raise ValueError(f"{name}: expected an integer from {lo:,} to {hi:,}, got {v!r}")
            return v

        margins = body.get("margins")
        if margins is not None:
            if not isinstance(margins, list) or not all(
                    isinstance(m, (int, float)) and not isinstance(m, bool) and np.isfinite(m) and m >= 0
                    for m in margins):
                raise ValueError(f"margins: expected a list of K-1 non-negative numbers, got {margins!r}")
            margins = tuple(float(m) for m in margins)
        return cls(integer("iterations", 1_000, _MAX_ITERATIONS, cls.iterations),
                   integer("chains", 1, _MAX_CHAINS, cls.chains), margins,
                   integer("seed", 0, 2**31 - 1, cls.seed), integer("n_suggest", 1, 100, cls.n_suggest), figures)


class _Reporter:
    """Stands in for the sampler's tqdm bar in the child: sends the fraction done to the parent."""

    def __init__(self, total: int, q: Any) -> None:
        self.total, self.done, self.q, self._last = max(int(total), 1), 0, q, 0.0

    def update(self, n: int = 1) -> None:
        self.done += int(n)
        now = time.monotonic()
        if now - self._last > 0.2 or self.done >= self.total:
            self._last = now
            self.q.put(("progress", min(self.done / self.total, 1.0), "sampling"))

    def close(self) -> None:
        pass


def summarise(run: Any, labelled: Any) -> dict[str, Any]:
    """P(c=1), the selected set, penalty intervals given c = 1 and the reward distribution per group.

    Rewards are the length-normalised returns :math:`\\bar\\phi_i^\\top (w_n + \\hat e)` of the labelled
    trajectories under the selected-set estimate :math:`\\hat e` (selected features at their conditional
    posterior medians, :meth:`~pbicrl.inference.results.DrawsView.point_estimate`).
    """
    cond = run.conditional_summary()
    pc = run.p_constraint
    feats = []
    for j, name in enumerate(run.feature_names):
        def num(x: float) -> float | None:
            return float(x) if np.isfinite(x) else None
        feats.append({"name": name, "p_constraint": float(pc[j]), "selected": bool(name in run.selected()),
                      "median": num(cond["median"][j]), "low": num(cond["low"][j]), "high": num(cond["high"][j])})
    eff, _ = run.point_estimate("selected")
    settings = run.settings
    wn = settings.get("nominal_weights")
    wn = np.zeros(len(run.feature_names)) if wn is None else np.asarray(wn, dtype=np.float64)
    r = labelled.mean_features @ (wn + np.nan_to_num(np.asarray(eff, dtype=np.float64)[: wn.size]))
    groups = []
    for k in labelled.group_labels.tolist():
        x = r[labelled.group == k]
        q = np.quantile(x, [0.0, 0.1, 0.25, 0.5, 0.75, 0.9, 1.0])
        groups.append({"label": int(k), "name": labelled.group_name(k), "n": int(x.size),
                       "quantiles": [float(v) for v in q], "mean": float(x.mean())})
    return {"features": feats, "selected": run.selected(), "groups": groups,
            "n_draws": int(run.n_chains * run.n_draws), "warnings": list(run.summary.get("warnings", []))
            if hasattr(run, "summary") else []}


def _child(labelling_path: str, run_dir: str, settings: InferenceSettings, q: Any, parent: int | None = None) -> None:
    """Body of the child process (module level: ``spawn`` pickles it by name).

    It ends with its parent, however the parent ends (``SIGKILL`` included), and removes the snapshot folder
    it was given once it has read the snapshot, so a killed server leaves neither a process nor a folder.
    """
    from pbicrl.inference.samplers.driver import die_with_parent

    die_with_parent(parent)
    try:
        import warnings

        from pbicrl import infer
        from pbicrl.inference.data import load_dataset
        from pbicrl.errors import PbicrlWarning
        from pbicrl.runs import load_run
        from pbicrl.inference.samplers import driver

        warnings.simplefilter("ignore", PbicrlWarning)  # they are in summary.json; the page shows them
        if hasattr(driver, "progress_bar"):
            driver.progress_bar = lambda total, enabled: _Reporter(total, q)  # this process only
        q.put(("progress", 0.0, "preparing"))
        full = load_dataset(labelling_path, allow_unlabelled=True)
        snapshot_dir = Path(labelling_path).parent
        if snapshot_dir.name.startswith("pbicrl-label-"):  # the server's private copy: read, no longer needed
            import shutil

            shutil.rmtree(snapshot_dir, ignore_errors=True)
        labelled = full.labelled()
        rd = Path(run_dir)
        post = infer(labelled, iterations=settings.iterations, chains=settings.chains, jobs=1,
                     seed=settings.seed, margins=None if settings.margins is None else list(settings.margins),
                     progress=True)
        data_path = rd / "data.npz"
        post.extra.setdefault("data", {})["path"] = str(data_path)
        # replaces only a run directory this page (or pbicrl) wrote and that holds nothing else
        post.save(rd, overwrite=True)
        labelled.save(data_path)
        from pbicrl._atomic import mark_output

        mark_output(rd, "run", ["data.npz"])
        run = load_run(rd)
        result = summarise(run, labelled)
        result["run_dir"] = str(rd)
        figures: list[str] = []
        if settings.figures:
            q.put(("progress", 1.0, "figures"))
            try:
                from pbicrl.analysis.plots import plot_run

                figures = [p.name for p in plot_run(run, rd / "plots", dataset=labelled)]
                mark_output(rd, "run", ["plots"])
            except ImportError as exc:
                result["figures_note"] = f"no figures: {exc}"
        result["figures"] = figures
        q.put(("progress", 1.0, "suggesting"))
        try:
            from pbicrl.analysis.suggest import suggest

            if np.any((full.group == 0) & ~full.skipped):
                result["suggestions"] = suggest(run, labelled, full, settings.n_suggest).to_dict()
        except ValueError as exc:
            result["suggestions_note"] = str(exc)
        q.put(("done", result))
    except BaseException as exc:  # everything goes back to the page as a message
        msg = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        q.put(("error", msg, traceback.format_exc(limit=5)))


@dataclass
class InferenceJob:
    """One inference at a time for a labelling session (state read by ``GET /api/infer``)."""

    status: str = "idle"  # idle | running | done | error
    progress: float = 0.0
    phase: str = ""
    message: str = ""
    result: dict[str, Any] | None = None
    revision: int | None = None
    started: float | None = None
    _proc: Any = field(default=None, repr=False)
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def snapshot(self) -> dict[str, Any]:
        with self._lock:
            return {"status": self.status, "progress": self.progress, "phase": self.phase, "message": self.message,
                    "result": self.result, "revision": self.revision,
                    "elapsed_s": None if self.started is None else round(time.monotonic() - self.started, 1)}

    def start(self, labelling_path: Path, run_dir: Path, settings: InferenceSettings, revision: int) -> None:
        """Start the child; a second start while one runs is a :class:`JobBusy`."""
        with self._lock:
            if self.status == "running":
                raise JobBusy("inference: one is already running; wait for it to finish")
            ctx = mp.get_context("spawn")
            q = ctx.Queue()
            proc = ctx.Process(target=_child, args=(str(labelling_path), str(run_dir), settings, q, os.getpid()),
                               daemon=True)
            proc.start()
            self.status, self.progress, self.phase, self.message, self.result = "running", 0.0, "starting", "", None
            self.revision, self.started, self._proc = revision, time.monotonic(), proc
        threading.Thread(target=self._watch, args=(proc, q), daemon=True).start()

    def _watch(self, proc: Any, q: Any) -> None:
        while True:
            try:
                msg = q.get(timeout=0.5)
            except queue.Empty:
                if not proc.is_alive():
                    with self._lock:
                        if self.status == "running":
                            self.status = "error"
                            self.message = f"inference: the worker process ended (exit code {proc.exitcode})"
                    return
                continue
            with self._lock:
                if msg[0] == "progress":
                    self.progress, self.phase = float(msg[1]), str(msg[2])
                elif msg[0] == "done":
                    self.status, self.progress, self.phase, self.result = "done", 1.0, "done", msg[1]
                elif msg[0] == "error":
                    self.status, self.message = "error", str(msg[1])
            if msg[0] in ("done", "error"):
                proc.join(timeout=5)
                return

    def stop(self) -> None:
        """End a running child (server shutdown)."""
        with self._lock:
            proc = self._proc
        if proc is not None and proc.is_alive():
            proc.terminate()
            proc.join(timeout=5)
