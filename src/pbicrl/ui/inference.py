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
_PAGE_MAX_TIME = 120.0  # seconds a run until converged may take from the page before it reports NOT CONVERGED


class JobBusy(RuntimeError):
    """An inference is already running for this session."""


def run_dir_for(out: Path) -> Path:
    """Where the page's inference runs go: ``LABELLED.run/`` beside ``LABELLED.npz``."""
    return out.with_name(out.stem + ".run")


@dataclass(frozen=True)
class InferenceSettings:
    """What the page may choose: iterations and chains per run, margins (K-1 gaps), seed, suggestions, and
    whether to draw the figures of ``pbicrl plot`` (the slowest step of a short run)."""

    iterations: int | str = "auto"
    chains: int = 4
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
        its = body.get("iterations", cls.iterations)
        return cls(its if its == "auto" else integer("iterations", 1_000, _MAX_ITERATIONS, cls.iterations),
                   integer("chains", 1, _MAX_CHAINS, cls.chains), margins,
                   integer("seed", 0, 2**31 - 1, cls.seed), integer("n_suggest", 1, 100, cls.n_suggest), figures)


class _Reporter:
    """Stands in for the sampler's tqdm bar in the child: sends the fraction done to the parent."""

    def __init__(self, total: int | None, q: Any) -> None:
        # total None: a run until converged; progress is then the smallest ESS over its target
        self.total = None if total is None else max(int(total), 1)
        self.done, self.q, self._last, self._frac = 0, q, 0.0, 0.0
        self._text = "sampling until converged (warm-up)" if total is None else "sampling"

    def update(self, n: int = 1) -> None:
        self.done += int(n)
        now = time.monotonic()
        if self.total is None:
            if now - self._last > 0.5:
                self._last = now
                self.q.put(("progress", self._frac, self._text))
            return
        if now - self._last > 0.2 or self.done >= self.total:
            self._last = now
            self.q.put(("progress", min(self.done / self.total, 1.0), "sampling"))

    def set_convergence(self, min_ess: float, target: float, max_rhat: float, elapsed: float) -> None:
        self._frac = min(0.99, min_ess / target) if min_ess == min_ess else 0.0
        self._text = (f"sampling until converged: smallest ESS {min_ess:.0f} of {target:g}, largest R-hat "
                      f"{max_rhat:.3f}, {elapsed:.0f} s")
        self.q.put(("progress", self._frac, self._text))

    def close(self) -> None:
        pass


def summarise(run: Any, labelled: Any) -> dict[str, Any]:
    """P(c=1), the selected set, penalty intervals given c = 1 and the reward distribution per group.

    P(c=1) and the selection only for a sampler whose indicators are posterior probabilities (``pbicrl``);
    otherwise each feature carries what its column is (``frequency_on`` and ``map_indicator``, or
    ``in_model``), ``selected`` is ``None`` and ``indicator_label`` names the column
    (:data:`pbicrl.inference.draws.INDICATOR_MEANINGS`).

    Rewards are the length-normalised returns :math:`\\bar\\phi_i^\\top (w_n + \\hat e)` of the labelled
    trajectories under the selected-set estimate :math:`\\hat e` (selected features at their conditional
    posterior medians, :meth:`~pbicrl.inference.draws.DrawsView.point_estimate`).
    """
    from pbicrl.inference.draws import INDICATOR_LABELS

    cond = run.conditional_summary()
    pc = run.p_constraint
    meaning = run.indicator_meaning
    model = run.in_model()
    chosen = run.selected()
    feats = []
    for j, name in enumerate(run.feature_names):
        def num(x: float) -> float | None:
            return float(x) if np.isfinite(x) else None
        if meaning == "posterior":  # P(c=1) and a selection only where they are posterior probabilities
            ind: dict[str, Any] = {"p_constraint": float(pc[j]), "selected": bool(name in chosen)}
        elif meaning == "chain_frequency":
            ind = {"frequency_on": float(pc[j]), "map_indicator": bool(run.map_indicators[j])}
        else:
            ind = {"in_model": bool(model[j])}
        feats.append({"name": name, **ind,
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
    summary = getattr(run, "summary", None) or {}
    summary = summary() if callable(summary) else summary  # a RunRecord's dict or a Posterior's method
    conv = (summary.get("extra") or {}).get("convergence")
    return {"features": feats, "selected": chosen if meaning == "posterior" else None,
            "indicator_meaning": meaning, "indicator_label": INDICATOR_LABELS[meaning], "groups": groups,
            "n_draws": int(run.n_chains * run.n_draws), "warnings": list(summary.get("warnings", [])),
            # None: a fixed-length run (no stopping rule); False: shown as NOT CONVERGED above the results
            "converged": None if not isinstance(conv, dict) else bool(conv.get("converged")),
            "convergence": None if not isinstance(conv, dict) else
            {k: conv.get(k) for k in ("min_ess", "max_rhat", "failing", "wall_s", "iterations_run", "target_ess",
                                      "target_rhat")}}


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
        from pbicrl.io.runs import read_run
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
        post = infer(labelled, iterations=settings.iterations, chains=settings.chains, jobs=1, max_time=_PAGE_MAX_TIME,
                     seed=settings.seed, margins=None if settings.margins is None else list(settings.margins),
                     progress=True)
        data_path = rd / "data.npz"
        post.extra.setdefault("data", {})["path"] = str(data_path)
        # replaces only a run directory this page (or pbicrl) wrote and that holds nothing else
        post.save(rd, overwrite=True)
        labelled.save(data_path)
        from pbicrl._atomic import mark_output

        mark_output(rd, "run", ["data.npz"])
        run = read_run(rd)
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
    finished: float | None = None
    settings: InferenceSettings | None = None
    _proc: Any = field(default=None, repr=False)
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def snapshot(self) -> dict[str, Any]:
        """The job as ``GET /api/infer`` sends it; ``elapsed_s`` stops when the run ends, ``settings`` are the
        ones that produced the result shown (None before the first run)."""
        with self._lock:
            end = self.finished if self.finished is not None else time.monotonic()
            s = self.settings
            return {"status": self.status, "progress": self.progress, "phase": self.phase, "message": self.message,
                    "result": self.result, "revision": self.revision,
                    "elapsed_s": None if self.started is None else round(end - self.started, 1),
                    "settings": None if s is None else {
                        "iterations": s.iterations, "chains": s.chains,
                        "margins": None if s.margins is None else list(s.margins), "seed": s.seed,
                        "n_suggest": s.n_suggest, "figures": s.figures}}

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
            self.revision, self.started, self.finished, self._proc = revision, time.monotonic(), None, proc
            self.settings = settings
        threading.Thread(target=self._watch, args=(proc, q), daemon=True).start()

    def _watch(self, proc: Any, q: Any) -> None:
        while True:
            try:
                msg = q.get(timeout=0.5)
            except queue.Empty:
                if not proc.is_alive():
                    with self._lock:
                        if self.status == "running":
                            self.status, self.finished = "error", time.monotonic()
                            self.message = f"inference: the worker process ended (exit code {proc.exitcode})"
                    return
                continue
            with self._lock:
                if msg[0] == "progress":
                    self.progress, self.phase = float(msg[1]), str(msg[2])
                elif msg[0] == "done":
                    self.status, self.progress, self.phase, self.result = "done", 1.0, "done", msg[1]
                    self.finished = time.monotonic()
                elif msg[0] == "error":
                    self.status, self.message, self.finished = "error", str(msg[1]), time.monotonic()
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
