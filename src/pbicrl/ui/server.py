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
(``Content-Type: application/json``) of at most :data:`MAX_BODY_BYTES` (counted while it streams in, chunked
or not), nested at most :data:`MAX_DEPTH` deep, with integers of at most 2**53 in magnitude and no NaN or
Infinity (400 otherwise). Every request must name an allowed host (the loopback names when the server listens
on a loopback address; otherwise exactly the ``--allow-host`` names), and a request that changes anything and
carries an ``Origin`` must come from the served address itself: a web page elsewhere cannot post to the app
(no CORS headers either).
"""

from __future__ import annotations

import contextlib
import json
import os
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

__all__ = ["create_app", "LOOPBACK_HOSTS", "MAX_BODY_BYTES", "MAX_DEPTH", "check_json"]

LOOPBACK_HOSTS = ("127.0.0.1", "localhost", "[::1]", "::1")
MAX_BODY_BYTES = 1 << 20  # a change is a few hundred bytes; a list of every id of a big pool, a few hundred KiB
MAX_DEPTH = 32  # the deepest request is an object holding a list of lists
_MAX_INT = 1 << 53  # what the page's JavaScript numbers hold exactly
_SAFE_METHODS = ("GET", "HEAD", "OPTIONS")


def check_json(value: Any, where: str = "body") -> None:
    """Refuse a parsed JSON body nested deeper than :data:`MAX_DEPTH` or holding an integer beyond 2**53.

    Raises
    ------
    ValueError
        Naming the place (``body.margins[1]``).
    """
    stack: list[tuple[Any, str, int]] = [(value, where, 0)]
    while stack:
        v, at, depth = stack.pop()
        if depth > MAX_DEPTH:
            raise ValueError(f"{where}: nested more than {MAX_DEPTH} deep")
        if isinstance(v, dict):
            stack.extend((x, f"{at}.{k}", depth + 1) for k, x in v.items())
        elif isinstance(v, list):
            stack.extend((x, f"{at}[{i}]", depth + 1) for i, x in enumerate(v))
        elif isinstance(v, int) and not isinstance(v, bool) and abs(v) > _MAX_INT:
            raise ValueError(f"{at}: integer {str(v)[:20]}{'...' if len(str(v)) > 20 else ''} is out of range "
                             f"(at most 2**53 in magnitude)")


def _no_constant(name: str) -> Any:
    raise ValueError(f"{name} is not a number JSON allows")


class _SameOrigin:
    """ASGI middleware: a request that changes state and names an ``Origin`` must name the served address.

    The ``Host`` header is checked first (``TrustedHostMiddleware``), so ``http://<Host>`` is the address the
    page was served from; a browser sends ``Origin`` with every ``POST``, so a page elsewhere is refused.
    """

    def __init__(self, app: Any) -> None:
        self.app = app

    async def __call__(self, scope: Any, receive: Any, send: Any) -> None:
        if scope["type"] == "http" and scope.get("method", "GET") not in _SAFE_METHODS:
            headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope.get("headers", [])}
            origin = headers.get("origin")
            if origin is not None and origin not in (f"http://{headers.get('host', '')}",
                                                     f"https://{headers.get('host', '')}"):
                from starlette.responses import JSONResponse

                shown = origin if len(origin) <= 100 else origin[:100] + "..."
                await JSONResponse({"error": f"origin: requests from {shown!r} are refused; use the page this "
                                             "server serves"}, status_code=403)(scope, receive, send)
                return
        await self.app(scope, receive, send)
_STATIC = {"app.js": "text/javascript; charset=utf-8", "app.css": "text/css; charset=utf-8",
           "index.html": "text/html; charset=utf-8"}
_FIGURE = re.compile(r"^[a-z_]+\.png$")


def _static(name: str) -> bytes:
    return (resources.files("pbicrl.ui") / "static" / name).read_bytes()


def create_app(session: LabelSession, *, host: str = "127.0.0.1", allow_hosts: Any = ()) -> Any:
    """The Starlette app for ``session``.

    Parameters
    ----------
    session : LabelSession
    host : str
        Address the server listens on. For a loopback address, requests must name a loopback host (which
        keeps other web pages out: DNS rebinding) or one of ``allow_hosts``.
    allow_hosts : sequence of str
        Host names requests may name (``--allow-host``); required when ``host`` is not a loopback address,
        where they are the only names accepted.

    Raises
    ------
    ValueError
        ``host`` is not a loopback address and ``allow_hosts`` is empty.
    """
    require_ui_extra()
    from starlette.applications import Starlette
    from starlette.concurrency import run_in_threadpool
    from starlette.middleware import Middleware
    from starlette.middleware.trustedhost import TrustedHostMiddleware
    from starlette.requests import Request
    from starlette.responses import JSONResponse, Response
    from starlette.routing import Route

    _clean_stale_snapshots()
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
        chunks, size = [], 0
        async for chunk in request.stream():  # counted as it arrives: a chunked body declares no length
            size += len(chunk)
            if size > MAX_BODY_BYTES:
                raise _HttpError(413, f"body: more than {MAX_BODY_BYTES:,} bytes")
            chunks.append(chunk)
        raw = b"".join(chunks)
        try:
            body = json.loads(raw.decode("utf-8"), parse_constant=_no_constant)
        except RecursionError:
            raise _HttpError(400, f"body: nested more than {MAX_DEPTH} deep") from None
        except (UnicodeDecodeError, ValueError) as exc:
            raise _HttpError(400, f"body: not valid JSON ({str(exc).splitlines()[0]})") from None
        if not isinstance(body, dict):
            raise _HttpError(400, "body: expected a JSON object")
        try:
            check_json(body)
        except ValueError as exc:
            raise _HttpError(400, str(exc)) from None
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
        tmp = Path(tempfile.mkdtemp(prefix=f"{_TMP_PREFIX}{os.getpid()}-"))
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
    extra = [str(h).strip() for h in allow_hosts if str(h).strip()]
    if host in LOOPBACK_HOSTS:
        allowed = [*LOOPBACK_HOSTS, *extra]
    elif extra:
        allowed = extra
    else:
        raise ValueError(f"allow_host: listening on {host!r} (not this machine only) needs the host names clients "
                         "will use, e.g. --allow-host myhost.lan (anyone reaching them can change the labels)")
    middleware = [Middleware(TrustedHostMiddleware, allowed_hosts=allowed), Middleware(_SameOrigin)]
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


_TMP_PREFIX = "pbicrl-label-"


def _clean_stale_snapshots() -> None:
    """Remove the snapshot folders (``pbicrl-label-<pid>-*``) of labelling servers that were killed."""
    from pbicrl._atomic import pid_alive

    root = Path(tempfile.gettempdir())
    try:
        entries = list(root.glob(f"{_TMP_PREFIX}*-*"))
    except OSError:
        return
    for d in entries:
        pid = d.name[len(_TMP_PREFIX):].split("-", 1)[0]
        if pid.isdigit() and int(pid) != os.getpid() and not pid_alive(int(pid)) and d.is_dir() \
                and not d.is_symlink() and d.stat().st_uid == os.getuid():
            shutil.rmtree(d, ignore_errors=True)


class _HttpError(Exception):
    def __init__(self, status: int, message: str) -> None:
        super().__init__(message)
        self.status, self.message = status, message
