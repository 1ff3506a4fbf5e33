"""The labelling web app: a Starlette application over a :class:`~pbicrl.ui.session.LabelSession`.

Routes (JSON unless stated; every error is ``{"error": message}`` with a 4xx status that names the field):

====================================== =====================================================================
``GET /``                               the page (``static/index.html``; ``/static/app.js``, ``/static/app.css``)
``GET /api/state``                      revision, groups, assignments, skips, gap relation, counts
``GET /api/scene``                      how to draw the demonstrations (:func:`pbicrl.ui.scenes.scene_for`)
``GET /api/thumbnails``                 per demonstration, a thinned series for the list's small pictures
``GET /api/demo/{id}``                  one demonstration: series, features (404 for an unknown id)
``POST /api/assign``                    ``{revision, ids, group}``: group 0 = back to unlabelled
``POST /api/skip``                      ``{revision, ids, skipped}``
``POST /api/groups``                    ``{revision, names, source?}``: create, rename, reorder, delete groups
``POST /api/gaps``                      ``{revision, gap_relation}`` (K-1 positive numbers, or null)
``POST /api/infer``                     start inference ``{iterations?, chains?, margins?, seed?, n_suggest?}``
``GET /api/infer``                      its progress and result (P(c=1), selected, intervals, group rewards)
``GET /api/figures/{name}``             a PNG of ``pbicrl plot`` for the last run
====================================== =====================================================================

Each change carries the revision the page last saw; a stale one gets HTTP 409 (another tab changed the
labels), as does an output file changed on disk by another program. Requests must send JSON
(``Content-Type: application/json``) and, when the server listens on a loopback address, name a loopback
host: a web page elsewhere cannot post to the app (no CORS headers either).
"""

from __future__ import annotations

import contextlib
import json
import re
import shutil
import tempfile
from importlib import resources
from pathlib import Path
from typing import Any, AsyncIterator, Awaitable, Callable

from pbicrl.ui import require_ui_extra
from pbicrl.ui.inference import InferenceJob, InferenceSettings, JobBusy, run_dir_for
from pbicrl.ui.scenes import scene_for, thumbnail_payload, trajectory_payload
from pbicrl.ui.session import Conflict, LabelSession, SessionError

__all__ = ["create_app", "LOOPBACK_HOSTS", "MAX_BODY_BYTES"]

LOOPBACK_HOSTS = ("127.0.0.1", "localhost", "[::1]", "::1")
MAX_BODY_BYTES = 1 << 20  # a change is a few hundred bytes; a list of every id of a big pool, a few hundred KiB
_STATIC = {"app.js": "text/javascript; charset=utf-8", "app.css": "text/css; charset=utf-8",
           "index.html": "text/html; charset=utf-8"}
_FIGURE = re.compile(r"^[a-z_]+\.png$")


def _static(name: str) -> bytes:
    return (resources.files("pbicrl.ui") / "static" / name).read_bytes()


def create_app(session: LabelSession, *, host: str = "127.0.0.1") -> Any:
    """The Starlette app for ``session``.

    Parameters
    ----------
    session : LabelSession
    host : str
        Address the server listens on. For a loopback address, requests must name a loopback host (or
        ``testserver``, Starlette's test client), which keeps other web pages (DNS rebinding) out.
    """
    require_ui_extra()
    from starlette.applications import Starlette
    from starlette.concurrency import run_in_threadpool
    from starlette.middleware import Middleware
    from starlette.middleware.trustedhost import TrustedHostMiddleware
    from starlette.requests import Request
    from starlette.responses import JSONResponse, Response
    from starlette.routing import Route

    job = InferenceJob()
    scene = scene_for(session.base, session.env_id)
    cache: dict[str, Any] = {}

    def error(status: int, message: str) -> JSONResponse:
        return JSONResponse({"error": message}, status_code=status)

    async def body_of(request: Request) -> Any:
        ctype = request.headers.get("content-type", "").split(";")[0].strip().lower()
        if ctype != "application/json":
            raise _HttpError(415, "body: send JSON (Content-Type: application/json)")
        declared = request.headers.get("content-length", "")
        if declared.isdigit() and int(declared) > MAX_BODY_BYTES:
            raise _HttpError(413, f"body: {int(declared):,} bytes, at most {MAX_BODY_BYTES:,}")
        raw = await request.body()
        if len(raw) > MAX_BODY_BYTES:
            raise _HttpError(413, f"body: {len(raw):,} bytes, at most {MAX_BODY_BYTES:,}")
        try:
            body = json.loads(raw.decode("utf-8"))
        except (UnicodeDecodeError, ValueError) as exc:
            raise _HttpError(400, f"body: not valid JSON ({str(exc).splitlines()[0]})") from None
        if not isinstance(body, dict):
            raise _HttpError(400, "body: expected a JSON object")
        return body

    def change(fn: Callable[[dict[str, Any]], dict[str, Any]]) -> Callable[[Request], Awaitable[Response]]:
        async def endpoint(request: Request) -> Response:
            try:
                body = await body_of(request)
                if "revision" not in body:
                    return error(400, "revision: missing (the revision of the state the change was made on)")
                return JSONResponse(await run_in_threadpool(fn, body))  # the save writes a file
            except _HttpError as exc:
                return error(exc.status, exc.message)
            except Conflict as exc:
                return error(409, str(exc))
            except (SessionError, ValueError) as exc:  # ValueError: a dataset check the session did not foresee
                return error(422, str(exc))
            except OSError as exc:  # the disk: full, read-only, permissions
                return error(507 if getattr(exc, "errno", None) == 28 else 500,
                             f"out: could not save {session.out} ({exc.strerror or exc})")
        return endpoint

    def _need(body: dict[str, Any], key: str) -> Any:
        if key not in body:
            raise SessionError(f"{key}: missing")
        return body[key]

    async def page(request: Request) -> Response:
        return Response(_static("index.html"), media_type=_STATIC["index.html"],
                        headers={"Cache-Control": "no-store"})

    async def static(request: Request) -> Response:
        name = request.path_params["name"]
        if name not in _STATIC or name == "index.html":
            return error(404, f"static: no file {name!r}")
        return Response(_static(name), media_type=_STATIC[name], headers={"Cache-Control": "no-store"})

    async def state(request: Request) -> Response:
        return JSONResponse(session.state())

    async def get_scene(request: Request) -> Response:
        return JSONResponse(scene)

    async def thumbnails(request: Request) -> Response:
        if "thumbs" not in cache:
            cache["thumbs"] = thumbnail_payload(session.base, scene)
        return JSONResponse({"series": cache["thumbs"]})

    async def demo(request: Request) -> Response:
        raw = request.path_params["id"]
        if not re.fullmatch(r"\d{1,9}", raw) or int(raw) >= session.n:
            return error(404, f"id: unknown trajectory {raw!r}; ids are 0 to {session.n - 1}")
        return JSONResponse(trajectory_payload(session.base, scene, int(raw)))

    def do_assign(body: dict[str, Any]) -> dict[str, Any]:
        return session.assign(body["revision"], _need(body, "ids"), _need(body, "group"))

    def do_skip(body: dict[str, Any]) -> dict[str, Any]:
        return session.skip(body["revision"], _need(body, "ids"), body.get("skipped", True))

    def do_groups(body: dict[str, Any]) -> dict[str, Any]:
        return session.set_groups(body["revision"], _need(body, "names"), body.get("source"))

    def do_gaps(body: dict[str, Any]) -> dict[str, Any]:
        return session.set_gap_relation(body["revision"], _need(body, "gap_relation"))

    async def infer_start(request: Request) -> Response:
        try:
            body = await body_of(request)
            settings = InferenceSettings.from_json(body)
        except _HttpError as exc:
            return error(exc.status, exc.message)
        except ValueError as exc:
            return error(422, str(exc))
        ds = session.dataset()
        if ds.n_groups < 2:
            return error(422, f"group: inference needs at least two non-empty groups; {int((ds.group > 0).sum())} "
                              f"labelled trajectories in {ds.n_groups} group(s)")
        if settings.margins is not None and len(settings.margins) != ds.n_groups - 1:
            return error(422, f"margins: {ds.n_groups} non-empty groups need {ds.n_groups - 1} gaps, "
                              f"got {len(settings.margins)}")
        tmp = Path(tempfile.mkdtemp(prefix="pbicrl-label-"))
        snap = tmp / "labelling.npz"
        ds.save(snap, compress=False)
        try:
            job.start(snap, run_dir_for(session.out), settings, session.revision)
        except JobBusy as exc:
            shutil.rmtree(tmp, ignore_errors=True)
            return error(409, str(exc))
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise
        cache["tmp"] = tmp
        return JSONResponse(job.snapshot(), status_code=202)

    async def infer_status(request: Request) -> Response:
        snap = job.snapshot()
        if snap["status"] in ("done", "error") and "tmp" in cache:
            shutil.rmtree(cache.pop("tmp"), ignore_errors=True)
        return JSONResponse(snap)

    async def figure(request: Request) -> Response:
        name = request.path_params["name"]
        res = job.snapshot().get("result") or {}
        if not _FIGURE.fullmatch(name) or name not in (res.get("figures") or []):
            return error(404, f"figure: no figure {name!r} for the last run")
        path = Path(res["run_dir"]) / "plots" / name
        if not path.is_file():
            return error(404, f"figure: {name} is gone from {path.parent}")
        return Response(path.read_bytes(), media_type="image/png", headers={"Cache-Control": "no-store"})

    async def not_found(request: Request, exc: Exception) -> Response:
        return error(404, f"path: no such page or API route {request.url.path!r}")

    async def not_allowed(request: Request, exc: Exception) -> Response:
        return error(405, f"method: {request.method} is not allowed on {request.url.path}")

    routes = [
        Route("/", page), Route("/static/{name}", static),
        Route("/api/state", state), Route("/api/scene", get_scene), Route("/api/thumbnails", thumbnails),
        Route("/api/demo/{id}", demo),
        Route("/api/assign", change(do_assign), methods=["POST"]),
        Route("/api/skip", change(do_skip), methods=["POST"]),
        Route("/api/groups", change(do_groups), methods=["POST"]),
        Route("/api/gaps", change(do_gaps), methods=["POST"]),
        Route("/api/infer", infer_start, methods=["POST"]), Route("/api/infer", infer_status, methods=["GET"]),
        Route("/api/figures/{name}", figure),
    ]
    middleware = []
    if host in LOOPBACK_HOSTS:
        middleware.append(Middleware(TrustedHostMiddleware, allowed_hosts=["127.0.0.1", "localhost", "[::1]", "::1",
                                                                          "testserver"]))
    @contextlib.asynccontextmanager
    async def lifespan(app: Any) -> AsyncIterator[None]:
        yield
        job.stop()  # no inference child outlives the server
        if "tmp" in cache:
            shutil.rmtree(cache.pop("tmp"), ignore_errors=True)

    app = Starlette(routes=routes, middleware=middleware, exception_handlers={404: not_found, 405: not_allowed},
                    lifespan=lifespan)
    app.state.session = session
    app.state.job = job
    return app


class _HttpError(Exception):
    def __init__(self, status: int, message: str) -> None:
        super().__init__(message)
        self.status, self.message = status, message
