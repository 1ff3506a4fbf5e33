"""SIGTERM and SIGINT during a long run: note the request, let the run write its checkpoint, then stop."""

from __future__ import annotations

import signal
from typing import Any

__all__ = ["StopSignals"]


class StopSignals:
    """While installed, SIGTERM and SIGINT set :attr:`requested` instead of ending the process.

    The run polls :attr:`requested` between updates, checkpoints and stops; :meth:`restore` puts the previous
    handlers back. Outside the main thread (where handlers cannot be set) nothing is installed.
    """

    def __init__(self) -> None:
        self.requested = False
        self._old: dict[int, Any] = {}

    def install(self) -> "StopSignals":
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
