"""The viewer's web server: one static page and a small HTTP API (docs/viewer.md documents
it).

=========================  ===============================================================
``GET /``                  the page (``static/index.html``)
``GET /api/state``         scene, method and current values, in the shape ``/api/update`` takes
``POST /api/update``       a partial state; 422 with the reason (state unchanged) if invalid
``POST /api/paint``        a brush stroke into the volume (volume method; Sun §6.2.1)
``POST /api/reset``        undo the painting
``GET /api/frame.png``     the image after every change made so far (waits for it)
``GET /api/frame.json``    how that image was made: per-stage ms, the stages that reran, fps
``WS /api/stream``         every frame: a JSON message, then the image as a binary message
=========================  ===============================================================

Only the viewer's own page drives it (:mod:`.guard`): a token per server in the URL it prints,
``Host`` and ``Origin`` of this server only, JSON bodies of at most 1 MB; errors are one short
line that never repeats the request, and never a traceback.
"""

from __future__ import annotations

import asyncio
import json
from importlib.resources import files

from fastapi import FastAPI, Request, WebSocket, WebSocketDisconnect
from fastapi.responses import FileResponse, JSONResponse, Response
from fastapi.staticfiles import StaticFiles

from .. import METHODS
from ..core.errors import ParameterError, PhotonmapError
from .guard import Guard, allowed_hosts, new_token
from .methods import ADAPTERS
from .state import READ_ONLY
from .volume_adapter import check_stroke
from .worker import RenderWorker

STATIC = files("photonmap.viewer") / "static"
MAX_DEPTH = 32  # nesting of a request's JSON (the state document needs 4)
MAX_DETAIL = 300  # characters of an error's detail


class Viewer:
    """A scene rendered by one method, its render thread and its state document."""

    def __init__(self, scene, method: str, overrides=None, size=None, frames=None, name=None,
                 preview_scale: int = 4, settle: float = 0.25):  # fmt: skip
        if method not in ADAPTERS:
            raise ParameterError(
                f"unknown method {method!r}; the viewer offers {', '.join(ADAPTERS)}"
            )
        extra = {}
        if frames is not None:
            if "volume" not in METHODS[method].pipeline.edits:
                raise ParameterError("a volume sequence (--volumes) needs the volume method")
            extra["frames"] = frames
        self.adapter = ADAPTERS[method](method, scene, overrides, size, **extra)
        self.scene = name or str(scene)
        self.method = method
        self.token = new_token()  # required by the API and the stream (.guard)
        self.worker = RenderWorker(self.adapter, preview_scale, settle)

    def state(self) -> dict:
        """The state document (:mod:`.state`) with the read-only facts around it."""
        values = self.worker.target_state()
        out = {"scene": self.scene, "method": self.method, "methods": list(ADAPTERS),
               "stages": list(self.adapter.stages), **values}  # fmt: skip
        if "volume" in self.adapter.pipe.edits:  # the volume grids: painted or played
            out["frames"] = self.adapter.frame_count
            out["brush_fields"] = ["sigma_s", "n"]
        return out

    def update(self, update) -> int:
        """Check ``update`` (read-only keys may only repeat their values) and hand it to the
        render thread; returns the state version it makes."""
        if isinstance(update, dict):
            facts = self.state()
            for key in READ_ONLY:
                if key in update and update[key] != facts.get(key):
                    raise ParameterError(
                        f"{key} is read-only ({facts.get(key)!r}): start another `photonmap view`"
                    )
        return self.worker.update(update)[1]

    def close(self) -> None:
        """Stop the render thread and let go of the pipeline and its scene. FastAPI keeps the
        routes of every application it has served in a cache of its own, and those routes hold
        this viewer: a closed viewer holding its scene would keep the scene's BSDFs, shapes and
        emitters in Dr.Jit's registry, where every later symbolic call in the process traces
        them too (a new kernel, and tracing that grows with each viewer ever opened)."""
        if self.worker.stop():
            self.adapter = self.worker.adapter = None


def short(text: str, limit: int = MAX_DETAIL) -> str:
    """``text`` cut to ``limit`` characters (an error never echoes a whole request)."""
    text = str(text)
    return text if len(text) <= limit else text[: limit - 1] + "…"


def _unprocessable(exc: Exception) -> JSONResponse:
    return JSONResponse({"detail": short(exc)}, status_code=422)


def _depth(value) -> int:
    """The nesting depth of decoded JSON (without recursion)."""
    deepest, todo = 0, [(value, 1)]
    while todo:
        item, depth = todo.pop()
        if isinstance(item, dict | list):
            deepest = max(deepest, depth)
            if depth <= MAX_DEPTH:
                todo.extend((v, depth + 1) for v in (item.values() if isinstance(item, dict)
                                                     else item))  # fmt: skip
    return deepest


async def _json(request: Request):
    try:
        value = json.loads(await request.body())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ParameterError(f"the body is not valid JSON: {short(exc, 80)}") from None
    except RecursionError:
        raise ParameterError(f"the JSON body is nested more than {MAX_DEPTH} deep") from None
    if _depth(value) > MAX_DEPTH:
        raise ParameterError(f"the JSON body is nested more than {MAX_DEPTH} deep")
    return value


def create_app(viewer: Viewer, host: str = "127.0.0.1", port: int | None = None):
    """The application serving ``viewer`` (an ASGI app): the FastAPI routes behind the guard of
    :mod:`.guard` — ``viewer.token`` required, ``Host``/``Origin`` of ``host`` (and ``port``,
    when given) only."""
    app = FastAPI(title="photonmap view", docs_url=None, redoc_url=None, openapi_url=None)
    app.mount("/static", StaticFiles(directory=str(STATIC)), name="static")

    @app.exception_handler(PhotonmapError)
    async def photonmap_error(request, exc):
        return _unprocessable(exc)

    _page_and_edit_routes(app, viewer)
    _frame_routes(app, viewer)

    @app.websocket("/api/stream")
    async def stream(ws: WebSocket):
        await _stream(ws, viewer)

    return Guard(app, viewer.token, allowed_hosts(host), port)


def _page_and_edit_routes(app: FastAPI, viewer: Viewer) -> None:
    """``GET /`` (the page; its token becomes a cookie), ``GET /api/state`` and the edits:
    ``POST /api/update``, and painting and its reset where the method edits the volume."""

    @app.get("/")
    def index(request: Request):
        page = FileResponse(str(STATIC / "index.html"))
        token = request.query_params.get("token")
        if token == viewer.token:  # the page's own requests then carry it as a cookie
            page.set_cookie("photonmap_token", token, httponly=True, samesite="strict")
        return page

    @app.get("/api/state")
    def get_state():
        return viewer.state()

    @app.post("/api/update")
    async def post_update(request: Request):
        version = viewer.update(await _json(request))
        return {"version": version, "state": viewer.state()}

    def paintable(what: str) -> None:
        if "volume" not in viewer.adapter.pipe.edits:
            raise ParameterError(f"{what} needs the volume method, not {viewer.method}")

    @app.post("/api/paint")
    async def post_paint(request: Request):
        paintable("painting")
        stroke = check_stroke(await _json(request))
        return {"version": viewer.worker.act(lambda: viewer.adapter.paint(stroke))}

    @app.post("/api/reset")
    def post_reset():
        paintable("reset undoes painting, which")
        return {"version": viewer.worker.act(viewer.adapter.reset_volume)}


def _frame_routes(app: FastAPI, viewer: Viewer) -> None:
    """``GET /api/frame.png`` and ``/api/frame.json``: the next frame (504 after ``timeout``)."""

    def next_frame(timeout: float):
        try:
            return viewer.worker.wait_frame(timeout=timeout)
        except TimeoutError as exc:
            return JSONResponse({"detail": str(exc)}, status_code=504)

    @app.get("/api/frame.png")
    def get_frame_png(timeout: float = 300.0):
        frame = next_frame(timeout)
        if isinstance(frame, JSONResponse):
            return frame
        headers = {"X-Frame-Version": str(frame.version)}
        if frame.error:  # the last update was undone: the pipeline refused it
            headers["X-Frame-Error"] = frame.error.encode("ascii", "replace").decode()
        return Response(frame.png, media_type="image/png", headers=headers)

    @app.get("/api/frame.json")
    def get_frame_json(timeout: float = 300.0):
        frame = next_frame(timeout)
        return frame if isinstance(frame, JSONResponse) else frame.meta()


async def _stream(ws: WebSocket, viewer: Viewer) -> None:
    """``/api/stream``: each new frame's metadata and JPEG as the render thread finishes it
    (the newest only: a slow client skips frames, never queues them), and each error."""
    await ws.accept()
    loop = asyncio.get_running_loop()
    wake = asyncio.Event()
    latest: list = []
    errors: list = []

    def listener(message, frame):
        (latest if frame is not None else errors).append((message, frame))
        del latest[:-1]
        loop.call_soon_threadsafe(wake.set)

    frame = viewer.worker.frame
    if frame is not None:
        latest.append((frame.meta(), frame))
        wake.set()
    closed = []

    async def watch():  # the page sends nothing; this notices when it goes away
        try:
            while True:
                await ws.receive_text()
        except WebSocketDisconnect:
            closed.append(True)
            wake.set()

    watcher = asyncio.create_task(watch())
    viewer.worker.subscribe(listener)
    try:
        while True:
            await wake.wait()
            wake.clear()
            if closed:
                break
            while errors:
                await ws.send_json(errors.pop(0)[0])
            if latest:
                message, frame = latest.pop()
                await ws.send_json(message)
                await ws.send_bytes(frame.data)
    except (WebSocketDisconnect, RuntimeError):
        pass
    finally:
        viewer.worker.unsubscribe(listener)
        watcher.cancel()


class Background:
    """The viewer served by uvicorn on a thread (scripts, tests, notebooks): ``url`` (the
    server), ``page_url`` (the page, with the token), ``headers`` (the token for scripts),
    ``stop()``.

    >>> with Background(Viewer("cornell_ispm", "screen")) as bg:
    ...     httpx.get(bg.url + "api/state", headers=bg.headers)
    """

    def __init__(self, viewer: Viewer, host: str = "127.0.0.1", port: int = 0,
                 timeout: float = 60.0):  # fmt: skip
        import socket
        import threading
        import time

        import uvicorn

        if port == 0:  # a free port of this machine
            with socket.socket() as s:
                s.bind((host, 0))
                port = s.getsockname()[1]
        self.viewer = viewer
        self.url = f"http://{host}:{port}/"
        self.page_url = f"{self.url}?token={viewer.token}"
        self.headers = {"X-Photonmap-Token": viewer.token}
        config = uvicorn.Config(create_app(viewer, host, port), host=host, port=port,
                                log_level="warning")  # fmt: skip
        self._server = uvicorn.Server(config)
        self._thread = threading.Thread(target=self._server.run, daemon=True)
        self._thread.start()
        deadline = time.monotonic() + timeout
        while not self._server.started:
            if not self._thread.is_alive() or time.monotonic() > deadline:
                raise PhotonmapError(f"the viewer's server did not start on {self.url}")
            time.sleep(0.02)

    def stop(self) -> None:
        """Stop the server and the viewer's render thread."""
        self._server.should_exit = True
        self._thread.join(timeout=30)
        self.viewer.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.stop()


def page_url(viewer: Viewer, host: str = "127.0.0.1", port: int = 8000) -> str:
    """The URL of the viewer's page, with its token."""
    name = f"[{host}]" if ":" in host else host
    return f"http://{name}:{port}/?token={viewer.token}"


def serve(viewer: Viewer, host: str = "127.0.0.1", port: int = 8000, open_browser: bool = True):
    """Run the server until interrupted; open the page (:func:`page_url`) in the default browser
    once it is up."""
    import threading
    import webbrowser

    import uvicorn

    if open_browser:
        threading.Timer(1.0, webbrowser.open, args=(page_url(viewer, host, port),)).start()
    try:
        uvicorn.run(create_app(viewer, host, port), host=host, port=port, log_level="warning")
    finally:
        viewer.close()
