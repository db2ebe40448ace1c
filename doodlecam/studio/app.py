"""The studio's web application: a FastAPI app over one Session, plus the static page.

Safety (docs/studio.md): a local web server is reachable from every page the
user visits, so every /api request needs the access token printed at start;
the server answers only to its own host names (no DNS rebinding) and to
same-origin requests; a request with a body must say it is JSON (or a file
upload), never a type a cross-site form can send without a preflight; paths
in requests resolve inside the folders the user chose or are refused; an
export never replaces a file the studio did not write unless the user says
so; a failing request answers one line (JSON ``error``) and the server
carries on.
"""

from __future__ import annotations

import asyncio
import json
import secrets
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fastapi import FastAPI, Request
from fastapi.concurrency import run_in_threadpool
from fastapi.responses import FileResponse, JSONResponse, Response, StreamingResponse
from fastapi.staticfiles import StaticFiles

from doodlecam.errors import DoodleError, InputError, OutputError
from doodlecam.studio import motion as studio_motion
from doodlecam.studio import ebb as studio_ebb
from doodlecam.studio import grbl as studio_grbl
from doodlecam.studio.sending import ACTIVE, Sender
from doodlecam.studio.session import Session, StaleEdit

STATIC = Path(__file__).parent / "static"
TOKEN_HEADER = "x-doodlecam-token"
TARGETS = ("target must be 'simulator' or HOST:PORT (PLC), 'grbl-simulator' or serial:PORT (GRBL), "
           "'ebb-simulator' or ebb:PORT (AxiDraw's EiBotBoard)")


# the host names a loopback studio answers to; any other Host header is a DNS-rebinding attempt
LOOPBACK_HOSTS = ("127.0.0.1", "localhost", "::1")
# the content types a cross-site page may POST without a CORS preflight: never accepted with a body
SIMPLE_TYPES = ("", "text/plain", "application/x-www-form-urlencoded", "multipart/form-data")


@dataclass
class StudioConfig:
    token: str = field(default_factory=lambda: secrets.token_urlsafe(24))
    require_token: bool = True  # kept for callers: the token is needed on every /api request whatever the address
    folders: tuple[Path, ...] = ()  # the only places files are read from or written to by path
    hosts: tuple[str, ...] = ()  # host names the studio answers to besides the loopback ones (the bound address)


def host_name(header: str) -> str:
    """The host name of a Host (or Origin authority) header, without port or IPv6 brackets, lower case."""
    h = header.strip().lower()
    if h.startswith("["):
        return h[1:h.find("]")] if "]" in h else h
    return h.rsplit(":", 1)[0] if h.count(":") == 1 else h


def refusal(request: Request, config: StudioConfig) -> str | None:
    """Why a request must be refused (a one-line answer), or None: the studio's own host only,
    same-origin only, the token on every /api request, and no body a cross-site form could send."""
    host = request.headers.get("host", "")
    if host_name(host) not in LOOPBACK_HOSTS + tuple(h.lower() for h in config.hosts):
        return (f"this studio answers only to its own address, not to host '{host[:60]}'; "
                "open the URL it printed at start")
    if not request.url.path.startswith("/api/"):
        return None
    origin = request.headers.get("origin")
    if origin is not None and origin.rstrip("/").lower() != f"{request.url.scheme}://{host}".lower():
        return "cross-origin requests are refused; use the studio's own page (the URL it printed at start)"
    if request.headers.get("sec-fetch-site") in ("cross-site", "same-site"):
        return "cross-site requests are refused; use the studio's own page (the URL it printed at start)"
    given = request.headers.get(TOKEN_HEADER) or ""
    if not given and request.method == "GET":  # EventSource and downloads cannot set headers
        given = request.query_params.get("token") or ""
    if not secrets.compare_digest(given.encode(), config.token.encode()):
        return ("this request needs the access token the studio printed at start "
                "(open the printed URL, or add ?token=...)")
    if request.method not in ("GET", "HEAD", "OPTIONS"):
        kind = request.headers.get("content-type", "").split(";")[0].strip().lower()
        if kind in SIMPLE_TYPES:
            return ("send the request as JSON (content-type application/json) or a file upload "
                    "(application/octet-stream); form and text bodies are refused")
    return None


def inside(folders: tuple[Path, ...], text: Any, what: str = "path") -> Path:
    """``text`` resolved (symlinks followed) inside one of ``folders``, else an InputError.
    Relative paths are taken from the first folder."""
    if not folders:
        raise InputError("the studio was started without folders; start it with --folder DIR to read or write files there")
    if not isinstance(text, str) or not text or "\x00" in text:
        raise InputError(f"{what} must be a path inside {folders[0]}")
    p = Path(text)
    p = (p if p.is_absolute() else folders[0] / p).resolve()
    for f in folders:
        root = f.resolve()
        if p == root or root in p.parents:
            return p
    raise InputError(f"{text}: outside the folders the studio may use ({', '.join(map(str, folders))})")


def _json(doc: Any) -> Response:
    """A large JSON answer (views, figures, timelines): json.dumps at C speed instead of
    FastAPI's per-value encoder, which costs tens of ms on a job's thousands of points."""
    return Response(json.dumps(doc, separators=(",", ":")), media_type="application/json")


def _run_queue_wait() -> float | None:
    """Seconds this thread has spent runnable but waiting for a CPU (Linux schedstat), else None.
    Wall time minus CPU time minus this is time spent asleep (a lock, the GIL, I/O)."""
    try:
        with open("/proc/thread-self/schedstat", "rb") as f:
            return int(f.read().split()[1]) / 1e9
    except (OSError, ValueError, IndexError):
        return None


def _spent(name: str, w0: float, c0: float, q0: float | None) -> str:
    """A Server-Timing header's parts since (wall, thread CPU, run-queue wait) ``w0, c0, q0``: where a
    request's time went, for the page's and the benchmarks' measurements."""
    out = f"{name};dur={(time.perf_counter() - w0) * 1e3:.1f}, cpu;dur={(time.thread_time() - c0) * 1e3:.1f}"
    q1 = _run_queue_wait()
    return out + (f", runqueue;dur={(q1 - q0) * 1e3:.1f}" if q0 is not None and q1 is not None else "")


def _error(status: int, message: str) -> JSONResponse:
    return JSONResponse({"error": message}, status_code=status)


class Conflict(OutputError):
    """A request that would replace something the user did not ask to replace: the page asks first."""


def create_app(session: Session, config: StudioConfig | None = None) -> FastAPI:
    config = config or StudioConfig()
    app = FastAPI(title="doodlecam studio", docs_url=None, redoc_url=None, openapi_url=None)
    app.state.session, app.state.config, app.state.sender = session, config, Sender()
    app.state.opened = None  # the input file opened by path, if any
    app.state.written = set()  # files this studio wrote: an export may replace these without asking
    sender: Sender = app.state.sender
    app.router.add_event_handler("shutdown", sender.close)

    @app.middleware("http")
    async def guard(request: Request, call_next):
        why = refusal(request, config)
        if why is not None:
            return _error(403, why)
        try:
            return await call_next(request)
        except Exception as e:  # a request never kills the server: one line back
            return _error(500, f"internal error: {type(e).__name__}: {e}")

    @app.exception_handler(DoodleError)
    async def doodle_error(request: Request, e: DoodleError):
        if isinstance(e, Conflict):  # the page asks the user, then repeats the request with its answer
            return JSONResponse({"error": str(e), "confirm": True}, status_code=409)
        if isinstance(e, StaleEdit):  # the page reloads the job it shows
            return JSONResponse({"error": str(e), "stale": True}, status_code=409)
        return _error(400, str(e))

    async def body(request: Request) -> bytes:
        """The request body, refused beyond the session's upload limit before it is all read."""
        limit = session.max_upload
        size = request.headers.get("content-length")
        if size and size.isdigit() and int(size) > limit:
            raise InputError(f"the upload is {int(size) / 1e6:.1f} MB, larger than the studio's limit of "
                             f"{limit / 1e6:.0f} MB; start it with a larger --max-upload")
        chunks, n = [], 0
        async for chunk in request.stream():
            n += len(chunk)
            if n > limit:
                raise InputError(f"the upload is larger than the studio's limit of {limit / 1e6:.0f} MB; "
                                 "start it with a larger --max-upload")
            chunks.append(chunk)
        return b"".join(chunks)

    async def payload(request: Request) -> dict:
        kind = request.headers.get("content-type", "").split(";")[0].strip().lower()
        if kind != "application/json":
            raise InputError("send the request body as JSON (content-type application/json)")
        try:
            doc = json.loads(await body(request) or b"{}")
        except (UnicodeDecodeError, json.JSONDecodeError):
            raise InputError("the request body is not JSON") from None
        if not isinstance(doc, dict):
            raise InputError("the request body must be a JSON object")
        return doc

    def options_param(text: str | None) -> dict:
        if not text:
            return {}
        try:
            opts = json.loads(text)
        except json.JSONDecodeError:
            raise InputError("tracer options must be a JSON object") from None
        if not isinstance(opts, dict):
            raise InputError("tracer options must be a JSON object")
        return opts

    # ------------------------------------------------------------ pages

    @app.get("/")
    def index():
        return FileResponse(STATIC / "index.html", headers={"Cache-Control": "no-store"})

    @app.get("/favicon.ico")
    def favicon():
        return Response(status_code=204)

    app.mount("/static", StaticFiles(directory=STATIC), name="static")

    # ------------------------------------------------------------ job

    @app.get("/api/state")
    def state():
        m = session.machine
        # the page offers the targets that drive this machine: an AxiDraw's EiBotBoard, else a PLC or GRBL
        targets = ["ebb-simulator", "ebb-serial"] if studio_ebb.wants_ebb(m) else \
            ["simulator", "host", "grbl-simulator", "serial"]
        loaded = session.job is not None or session.preview is not None  # a preview: planned in the background
        return {"machine": m.name, "targets": targets, "loaded": loaded,
                "summary": session.summary() if loaded else None,
                "folders": [str(f) for f in config.folders], "send": sender.snapshot()[1]}

    @app.get("/api/tracers")
    def tracers():
        return session.tracers()

    @app.get("/api/posts")
    def posts():
        from doodlecam import registry

        return sorted(i.name for i in registry.discover(session.settings.plugin_dirs) if i.kind == "postprocessor")

    @app.post("/api/load")
    async def load(request: Request, name: str = "", tracer: str | None = None, options: str | None = None):
        data = await body(request)

        def run():
            w0, c0, q0 = time.perf_counter(), time.thread_time(), _run_queue_wait()
            r = JSONResponse(session.load(name, data, tracer or None, options_param(options)))
            r.headers["Server-Timing"] = _spent("load", w0, c0, q0)
            return r

        return await run_in_threadpool(run)

    @app.post("/api/open")
    async def open_path(request: Request):
        doc = await payload(request)
        p = inside(config.folders, doc.get("path"))
        if not p.is_file():
            raise InputError(f"{p}: no such file; check the path")
        if p.stat().st_size > session.max_upload:
            raise InputError(f"{p}: larger than the studio's limit of {session.max_upload / 1e6:.0f} MB")
        summary = await run_in_threadpool(session.load, p.name, p.read_bytes(), doc.get("tracer"), doc.get("options") or {})
        app.state.opened = p  # never to be overwritten by an export
        return summary

    @app.post("/api/trace")
    async def retrace(request: Request):
        doc = await payload(request)
        opts = doc.get("options") or {}
        if not isinstance(opts, dict):
            raise InputError("tracer options must be a JSON object")
        return await run_in_threadpool(session.retrace, doc.get("tracer") or None, opts)

    @app.get("/api/view")
    def view(flat: bool = False):
        w0, c0, q0 = time.perf_counter(), time.thread_time(), _run_queue_wait()
        r = _json(session.view(flat))
        r.headers["Server-Timing"] = _spent("view", w0, c0, q0)
        return r

    @app.get("/api/stroke/{i}")
    def stroke(i: str):
        return _json(session.stroke(i))

    @app.post("/api/edit")
    async def edit(request: Request):
        doc = await payload(request)
        op = doc.pop("op", None)
        i = doc.pop("stroke", None)
        patch = doc.pop("reply", None) == "patch"
        if "job" not in doc or "version" not in doc:
            raise InputError("an edit names the job and version it was made on ('job', 'version' from the summary)")
        job_id, version = doc.pop("job"), doc.pop("version")
        allowed = {"control", "point", "to", "tolerance"}
        extra = set(doc) - allowed
        if extra:
            raise InputError(f"unknown edit field '{sorted(extra)[0]}'; use op, stroke, control, point, to, tolerance, reply, "
                             "job, version")

        def run():
            w0, c0, q0 = time.perf_counter(), time.thread_time(), _run_queue_wait()
            with session.lock:  # the edit and what it changed, with no other request in between
                w1 = time.perf_counter()
                session.expect(job_id, version)
                summary = session.edit(str(op), i, **doc)
                # reply=patch: what changed, in the same answer (the page's re-plan after a drag)
                r = _json(session.patch() if patch and session.last_changed else summary)
            # where the time went: waiting for the session, then the edit (wall, this thread's CPU and its
            # time runnable but waiting for a core)
            r.headers["Server-Timing"] = f"lock;dur={(w1 - w0) * 1e3:.1f}, " + _spent("edit", w1, c0, q0)
            return r

        return await run_in_threadpool(run)

    async def step(request: Request, which: str):
        doc = await payload(request)

        def run():
            with session.lock:
                if "version" in doc:  # the page says which version it undoes; another tab's change is not undone
                    session.expect(doc.get("job"), doc["version"])
                return getattr(session, which)()

        return await run_in_threadpool(run)

    @app.post("/api/undo")
    async def undo(request: Request):
        return await step(request, "undo")

    @app.post("/api/redo")
    async def redo(request: Request):
        return await step(request, "redo")

    @app.get("/api/timeline")
    def timeline(layers: str | None = None):
        """The executed motion (of ``layers``, a JSON list of names, when given: what a one-layer send draws)."""
        if layers is None:
            return _json(session.timeline())
        try:
            names = json.loads(layers)
        except json.JSONDecodeError:
            raise InputError("layers must be a JSON list of layer names, e.g. [\"red\"]") from None
        return _json(session.timeline(names))

    @app.get("/api/export/{post}")
    def export(post: str):
        name, data = session.export(post)
        return Response(data, media_type="application/octet-stream",
                        headers={"Content-Disposition": f'attachment; filename="{name}"'})

    @app.post("/api/export")
    async def export_to(request: Request):
        from doodlecam.pipeline import write_outputs

        doc = await payload(request)
        if not isinstance(doc.get("folder"), str) or not doc["folder"].strip():
            raise InputError(f"choose the folder to export into (a folder inside {config.folders[0]})"
                             if config.folders else "the studio was started without folders; start it with --folder DIR")
        folder = inside(config.folders, doc["folder"], "folder")
        posts = doc.get("posts") or []
        if not isinstance(posts, list) or not posts or not all(isinstance(p, str) for p in posts):
            raise InputError("posts must be a list of post names, e.g. [\"gcode\"]")
        overwrite = doc.get("overwrite") is True  # the user confirmed replacing files the studio did not write

        def run():
            stem = Path(session.name).stem or "job"
            outs = session.posts(tuple(posts))
            opened = app.state.opened
            targets = [(folder / f"{stem}{ext}").resolve() for _, ext, _ in outs]
            for t in targets:
                if opened is not None and t == opened:
                    raise OutputError(f"{t} is the file the job was opened from; export into another folder")
            foreign = [t for t in targets if t.exists() and t not in app.state.written]
            if foreign and not overwrite:
                raise Conflict(f"{foreign[0]} exists and was not written by the studio; "
                               "confirm to replace it, or choose another folder")
            written = write_outputs(folder, stem, outs)
            app.state.written.update(p.resolve() for p in written)
            return written

        return {"written": [str(p) for p in await run_in_threadpool(run)]}

    @app.get("/api/job")
    def save_job():
        doc = session.save()
        name = (Path(session.name).stem or "job") + ".job.json"
        return Response(json.dumps(doc), media_type="application/json",
                        headers={"Content-Disposition": f'attachment; filename="{name}"'})

    @app.post("/api/job")
    async def open_job(request: Request, name: str = "job.json"):
        data = await body(request)
        return await run_in_threadpool(session.open_job, data, name)

    # ------------------------------------------------------------ motion design (MOTDES)

    @app.get("/api/motion/designs")
    def motion_designs():
        return studio_motion.designs(config.folders)

    @app.post("/api/motion/open")
    async def motion_open(request: Request):
        p = inside(config.folders, (await payload(request)).get("path"))
        if not p.is_file():
            raise InputError(f"{p}: no such file; check the path")
        doc = studio_motion.read(p)
        return _json({"doc": doc, "result": await run_in_threadpool(studio_motion.solve, doc, p.name), "name": p.name})

    @app.post("/api/motion/solve")
    async def motion_solve(request: Request):
        doc = await payload(request)
        return _json(await run_in_threadpool(studio_motion.solve, doc.get("doc"), str(doc.get("name") or "design")))

    @app.post("/api/motion/table")
    async def motion_table(request: Request):
        doc = await payload(request)
        name = Path(str(doc.get("name") or "design")).stem
        data = await run_in_threadpool(studio_motion.table_csv, doc.get("doc"), name)
        return Response(data, media_type="text/csv", headers={"Content-Disposition": f'attachment; filename="{name}.csv"'})

    # ------------------------------------------------------------ send

    @app.get("/api/send")
    def send_state():
        return sender.snapshot()[1]

    @app.post("/api/send")
    async def send(request: Request):
        doc = await payload(request)
        target = doc.get("target") or "simulator"
        if not isinstance(target, str):
            raise InputError(TARGETS)
        grbl = target == studio_grbl.EMULATOR or target.startswith(studio_grbl.SERIAL_PREFIX)

        def start():
            begin()  # raises when the send cannot start
            return sender.note(layers=doc.get("layers"))

        def begin():
            layers = doc.get("layers")  # plot one layer (or a few): only their strokes are sent
            if studio_ebb.is_ebb(target):  # an AxiDraw: the ebb post's command stream (it refuses other machines)
                _, data = session.export("ebb", layers)
                return sender.start_ebb(data, session.machine, target, doc.get("speed"),
                                        restart=doc.get("restart") is True, plugin_dirs=session.settings.plugin_dirs)
            if grbl:
                _, data = session.export("gcode", layers)
                return sender.start_grbl(data, session.machine, target, doc.get("speed"),
                                         restart=doc.get("restart") is True, plugin_dirs=session.settings.plugin_dirs)
            _, data = session.export("plc", layers)
            return sender.start(data, session.machine, target, doc.get("speed"), again=doc.get("again") is True,
                                restart=doc.get("restart") is True)

        return await run_in_threadpool(start)

    @app.post("/api/send/abandon")
    async def send_abandon(request: Request):
        target = (await payload(request)).get("target") or "simulator"
        if not isinstance(target, str):
            raise InputError(TARGETS)
        grbl = target == studio_grbl.EMULATOR or target.startswith(studio_grbl.SERIAL_PREFIX)
        data = b"" if studio_ebb.is_ebb(target) else session.export("gcode" if grbl else "plc")[1]
        return await run_in_threadpool(sender.abandon, target, data, session.machine)

    @app.post("/api/send/stop")
    def send_stop():
        return sender.stop()

    @app.post("/api/send/control")
    async def send_control(request: Request):
        action = (await payload(request)).get("action")
        if not isinstance(action, str):
            raise InputError("action must be pause, hold, resume, stop, continue, feed+, feed- or feed=")
        return sender.control(action)

    # ------------------------------------------------------------ GRBL machine control

    @app.post("/api/machine")
    async def machine_control(request: Request):
        """One of ``doodlecam machine``'s commands on a GRBL or EiBotBoard target (token-protected like sends)."""
        from doodlecam.link.grbl.timing import grbl_settings_for

        doc = await payload(request)
        action = doc.pop("action", None)
        target = doc.pop("target", studio_grbl.EMULATOR)
        if isinstance(target, str) and studio_ebb.is_ebb(target):  # an AxiDraw: the EiBotBoard's manual controls
            port, label = sender.ebb_port(target)
            return await run_in_threadpool(studio_ebb.machine_action, port, label, str(action), doc, session.machine)
        port = sender.grbl_port(target)

        def run():
            pens = None
            if session.job is not None and action in ("pen_up", "pen_down"):
                pens = studio_grbl.pen_commands(session.export("gcode")[1].decode("ascii"))
            return studio_grbl.machine_action(port, str(action), doc, pens, grbl_settings_for(session.machine))

        return await run_in_threadpool(run)

    @app.get("/api/send/events")
    async def send_events(request: Request):
        """Server-sent events: the send's state on every change, until it ends."""

        async def stream():
            version, snap = sender.snapshot()
            yield f"data: {json.dumps(snap)}\n\n"
            while snap["state"] in ACTIVE:
                if await request.is_disconnected():
                    return  # the send goes on: it belongs to the server, not to the page
                version, snap = await asyncio.to_thread(sender.wait, version, 0.5)
                yield f"data: {json.dumps(snap)}\n\n"

        return StreamingResponse(stream(), media_type="text/event-stream", headers={"Cache-Control": "no-store"})

    # every change an open page follows wakes the event streams (they wait on the send's condition)
    def wake():
        with sender.changed:
            sender.changed.notify_all()

    session.listeners.append(wake)

    @app.get("/api/events")
    async def events(request: Request):
        """Server-sent events for as long as the page is open: ``job`` (the job's id and version and the
        background planning's progress) whenever one changes — another tab loaded or edited the job —
        and ``send`` (the send's state) on every change of it."""

        def changed(job, send_version):
            with sender.changed:  # woken by the sender's changes and the session's (wake)
                sender.changed.wait_for(lambda: session.event() != job or sender.s.version != send_version, 1.0)
            return session.event(), sender.snapshot()

        async def stream():
            job, (send_version, snap) = session.event(), sender.snapshot()
            yield f"retry: 1000\nevent: job\ndata: {json.dumps(job)}\n\nevent: send\ndata: {json.dumps(snap)}\n\n"
            while not await request.is_disconnected():
                new_job, (new_version, snap) = await asyncio.to_thread(changed, job, send_version)
                out = ""
                if new_job != job:
                    job = new_job
                    out += f"event: job\ndata: {json.dumps(job)}\n\n"
                if new_version != send_version:
                    send_version = new_version
                    out += f"event: send\ndata: {json.dumps(snap)}\n\n"
                yield out or ": still here\n\n"  # a comment: a closed page is noticed within a second

        return StreamingResponse(stream(), media_type="text/event-stream", headers={"Cache-Control": "no-store"})

    return app


def check_folders(folders) -> tuple[Path, ...]:
    out = []
    for f in folders:
        p = Path(f)
        if not p.is_dir():
            raise OutputError(f"{f}: no such folder; create it or give another --folder")
        out.append(p.resolve())
    return tuple(out)
