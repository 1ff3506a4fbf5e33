"""What every long training run does the same way, one session at a time: ICL (:mod:`pbicrl.baselines.icl`),
``train-safe`` (:mod:`pbicrl.experiments.safe_rl`) and the SAC demonstrators (:mod:`pbicrl.demonstrators.sac`).

* :class:`StopSignals` - SIGTERM and SIGINT note a stop request, so the run writes its checkpoint and stops;
* :class:`SessionClock` - after each update: the periodic checkpoint, and the end of a session of limited length;
* :func:`progress_logger` - timestamped lines appended to the run's ``progress.log`` (and echoed to stderr);
* :func:`library_versions` - versions of Python and the libraries a run depends on, for its ``budget.json``.
* :func:`load_safely` - ``torch.load(weights_only=True)`` of a checkpoint, with one message for every failure.

Standard library only, so importing it needs no optional extra (:func:`load_safely` imports torch when called).
"""

from __future__ import annotations

import platform
import signal
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

__all__ = ["StopSignals", "SessionClock", "library_versions", "progress_logger", "load_safely"]


class StopSignals:
    """While installed, SIGTERM and SIGINT set :attr:`requested` instead of ending the process.

    The run polls :attr:`requested` between updates, checkpoints and stops; :meth:`restore` puts the previous
    handlers back. Outside the main thread (where handlers cannot be set) nothing is installed, and Ctrl-C
    raises where it lands.
    """

    def __init__(self) -> None:
        self.requested = False
        self._old: dict[int, Any] = {}

    def install(self) -> StopSignals:
        """Install the handlers; returns ``self``."""
        try:
            for sig in (signal.SIGTERM, signal.SIGINT):
                self._old[sig] = signal.signal(sig, self._handler)
        except ValueError:  # not the main thread
            self._old = {}
        return self

    def _handler(self, signum: int, frame: Any) -> None:
        self.requested = True

    def request(self) -> None:
        """Ask the run to stop at its next check (as a signal would)."""
        self.requested = True

    def restore(self) -> None:
        """Put the handlers that were there before :meth:`install` back."""
        for sig, handler in self._old.items():
            signal.signal(sig, handler)
        self._old = {}


class SessionClock:
    """What a long run checks after each update: write the checkpoint every ``every`` steps (``save("running")``),
    and ask ``stop`` to end the session once it has run ``max_session_steps`` steps (``None``: no limit).

    Parameters
    ----------
    save : callable
        ``save(status)`` writes the checkpoint and the run's status.
    stop : StopSignals
        Where a stop is requested (also by SIGTERM/SIGINT).
    steps : int
        Environment steps done when the session starts (a resumed run starts where it stopped).
    every : int
        Steps between checkpoints.
    max_session_steps : int, optional
    """

    def __init__(self, save: Callable[[str], None], stop: StopSignals, steps: int, every: int,
                 max_session_steps: int | None = None) -> None:
        self.save, self.stop, self.every, self.max_session_steps = save, stop, int(every), max_session_steps
        self.start = self.last = int(steps)

    def tick(self, steps: int) -> bool:
        """After an update that brought the run to ``steps``; returns whether it goes on (no stop requested)."""
        if steps - self.last >= self.every:
            self.save("running")
            self.last = steps
        if self.max_session_steps is not None and steps - self.start >= int(self.max_session_steps):
            self.stop.request()
        return not self.stop.requested


def progress_logger(path: Path, *, echo: bool) -> Callable[[str], None]:
    """A ``log(message)`` that appends ``<UTC time> <message>`` to ``path`` and, with ``echo``, prints it to
    stderr.

    The file is opened per line, so a killed run leaves every line it logged and a resumed one appends.
    """

    def log(msg: str) -> None:
        line = f"{time.strftime('%Y-%m-%dT%H:%M:%SZ', time.gmtime())} {msg}"
        with open(path, "a") as fh:
            fh.write(line + "\n")
        if echo:
            print(line, file=sys.stderr, flush=True)

    return log


def library_versions(modules: Sequence[str] = ("numpy", "torch", "gymnasium", "mujoco"), *,
                     note_failures: bool = False) -> dict[str, str]:
    """Versions of Python and of ``modules``, for a run's ``budget.json``.

    Parameters
    ----------
    modules : sequence of str
        Modules to report (imported if they are not yet).
    note_failures : bool
        A module that cannot be imported or has no ``__version__`` is reported as ``"unknown (<error type>)"``
        with ``True``, left out with ``False``. Either way version reporting never fails a run.
    """
    out = {"python": platform.python_version()}
    for mod in modules:
        try:
            out[mod] = __import__(mod).__version__
        except Exception as exc:  # noqa: BLE001 - version reporting must never fail a run
            if note_failures:
                out[mod] = f"unknown ({type(exc).__name__})"
    return out


def load_safely(path: Path, what: str, hint: str, *, safe_globals: Sequence[Any] = ()) -> Any:
    """``torch.load(path, weights_only=True)``: tensors and plain values only (plus ``safe_globals``), so that a
    file put into a run directory by someone else cannot run code.

    Raises
    ------
    ValueError
        ``"{what}: {path} cannot be loaded safely (<error>); {hint}"`` when the file is damaged or holds anything
        else (torch's own advice to pass ``weights_only=False`` is left out of the message).
    """
    import pickle

    import torch

    ctx = getattr(torch.serialization, "safe_globals", None)
    try:
        if safe_globals and ctx is not None:
            with ctx(list(safe_globals)):
                return torch.load(path, weights_only=True, map_location="cpu")
        return torch.load(path, weights_only=True, map_location="cpu")  # older torch: tensors and plain values
    except (pickle.UnpicklingError, RuntimeError, EOFError, ValueError, TypeError, AttributeError, OSError) as exc:
        lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()] or [type(exc).__name__]
        # torch's own text suggests weights_only=False, exactly what must not be done with a file of unknown origin
        first = next((ln for ln in lines if "global" in ln.lower() and "weights_only" not in ln), lines[0])
        raise ValueError(f"{what}: {path} cannot be loaded safely ({type(exc).__name__}: {first[:200]}); "
                         f"{hint}") from None
