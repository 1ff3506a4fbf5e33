"""Rank demonstrations in the browser: ``pbicrl label DATA.npz --out LABELLED.npz`` (optional extra ``ui``).

The labelling state (:class:`~pbicrl.ui.session.LabelSession`) and the pictures' geometry
(:mod:`pbicrl.ui.scenes`) need only NumPy; the web server (:mod:`pbicrl.ui.server`) needs Starlette and
uvicorn: ``pip install "pbicrl[ui]"``. Nothing here imports them until a server is built.
"""

from __future__ import annotations

from pbicrl.ui.session import Conflict, LabelSession, SessionError

__all__ = ["LabelSession", "SessionError", "Conflict", "require_ui_extra"]


def require_ui_extra() -> None:
    """Import Starlette and uvicorn, or raise an :class:`ImportError` naming the extra to install."""
    try:
        import starlette  # noqa: F401
        import uvicorn  # noqa: F401
    except ImportError as exc:
        raise ImportError(f'pbicrl label needs the ui extra ({exc.name} is missing): pip install "pbicrl[ui]"') \
            from None
