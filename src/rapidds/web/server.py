"""The web server of the browser game: the page, a WebSocket for the live state, a fixed tick.

FastAPI on uvicorn. ``GET /`` is the page (plain HTML, JavaScript and CSS shipped in
``rapidds/web/static``; no build step), ``/ws`` the one WebSocket a player's page opens. The
server's event loop runs the game at a fixed tick (60 Hz by default): every tick it advances the
live cycle (:meth:`BrowserPlayer.tick`) and sends the state to the connected page. Plans,
summaries and phase changes go out on the same socket when they change.

A slow page never slows the tick: each connection has its own sender task that sends the queued
control messages and then only the newest state (older ones are dropped, not queued), except
that a state where the cycle turns (started, the person's part done, over) is always sent. The
queue holds :data:`MAX_OUTBOX` messages at most: a page that floods the socket and never reads
the replies is disconnected (close code 1008).

Safety: one player per run (a second page is told so and closed); a WebSocket from another
origin (a page of another site trying to drive the game) is refused, and so is a request for
another host name than the server's (DNS rebinding); every message passes
:class:`rapidds.web.protocol.Gate` (refused ones are logged and answered, never raised);
uvicorn closes the socket on a frame over 4 KiB. Nothing the client sends names a file.
"""

from __future__ import annotations

import asyncio
import contextlib
import html
import json
import logging
import socket
import time
from collections import deque
from collections.abc import AsyncIterator, Callable, Mapping, Sequence
from importlib.resources import files
from typing import Any, Protocol
from urllib.parse import urlsplit

from fastapi import FastAPI, WebSocket
from fastapi.responses import HTMLResponse, Response
from fastapi.staticfiles import StaticFiles
from starlette.datastructures import Headers
from starlette.responses import PlainTextResponse
from starlette.types import ASGIApp, Receive, Scope, Send
from starlette.websockets import WebSocketState

from rapidds.errors import RapiddsError
from rapidds.web.player import BrowserPlayer
from rapidds.web.protocol import Comfort, Gate, Move, Refused, Start, Target, TooClose

__all__ = ["LOOPBACK", "WILDCARDS", "GameSession", "HostCheck", "Hub", "allowed_hosts",
           "create_app", "game_page", "listen", "machine_names", "reach_line", "refuse_socket",
           "same_origin", "serve", "served_url"]

log = logging.getLogger("rapidds.web")

LOOPBACK = ("127.0.0.1", "localhost", "::1")
WILDCARDS = ("", "0.0.0.0", "::")
"""Bind addresses that listen on every interface of the machine."""
WS_MAX_BYTES = 4096  # uvicorn closes the socket on a larger frame (the gate refuses > 256 B)
_LOGGED_REFUSALS = 20  # per connection; then every 100th, so a flood cannot flood the log
MAX_OUTBOX = 256
"""Messages queued for one page at most (replies to refused messages, turns of the cycle): a
page that reads keeps a handful; one that floods the socket and never reads is disconnected
here instead of growing the server's memory without bound."""
_BUSY = ("another browser is already playing this run; close it (or its tab) and reload this "
         "page")


class GameSession(Protocol):
    """What the server shows of a run: :class:`rapidds.web.session.PlaySession` is one; a study
    harness that runs its own loop around a :class:`BrowserPlayer` can bring its own."""

    player: BrowserPlayer
    summary: dict[str, Any] | None
    summary_version: int
    stored: int
    error: str | None

    @property
    def phase(self) -> str:
        """"waiting", "ready", "playing", "over", "done" or "error"."""
        ...

    def info(self) -> dict[str, Any]:
        """The welcome message's content: run id, cycles, player, hz, the scene."""
        ...


def allowed_hosts(host: str) -> list[str]:
    """Host names the server answers to (as a Host header names them, IPv6 without brackets):
    the loopback names and the address it listens on, so a page of another site cannot reach a
    local server by DNS rebinding. A wildcard bind (0.0.0.0, ::) answers to the machine's own
    names and addresses (:func:`machine_names`), still not to any name."""
    names = {*LOOPBACK, host.lower().strip("[]")} - {""}
    if host.strip("[]") in WILDCARDS:  # 0.0.0.0 too: the address the server prints
        names |= machine_names()
    return sorted(names)


def machine_names() -> set[str]:
    """This machine's host name, its fully qualified name and the addresses they resolve to
    (no traffic but the resolver's)."""
    names = {socket.gethostname().lower(), socket.getfqdn().lower()} - {""}
    for name in list(names):
        with contextlib.suppress(OSError, UnicodeError):
            names |= {str(info[4][0]).split("%")[0].lower()
                      for info in socket.getaddrinfo(name, None)}
    return names


def request_host(headers: Mapping[str, str]) -> str | None:
    """The host name a request's Host header names (IPv6 without brackets, no port), None when
    it is missing or malformed."""
    raw = headers.get("host")
    if not raw or any(c in raw for c in "/?#@ \\"):
        return None
    try:
        parts = urlsplit("//" + raw)
        if parts.port is None and raw.endswith(":"):
            return None
    except ValueError:  # a bad port or IPv6 literal
        return None
    return parts.hostname or None


class HostCheck:
    """ASGI middleware: requests and sockets for another host name than ``hosts`` get 400 with
    one line (DNS rebinding). Unlike Starlette's TrustedHostMiddleware it reads IPv6 literals
    (``Host: [::1]:8000``) the same on every Starlette version."""

    def __init__(self, app: ASGIApp, hosts: Sequence[str]):
        self.app, self.hosts = app, frozenset(h.lower().strip("[]") for h in hosts)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] in ("http", "websocket"):
            name = request_host(Headers(scope=scope))
            if name not in self.hosts:
                shown = ", ".join(sorted(self.hosts)[:8])
                await PlainTextResponse(
                    f"this server answers to the host names {shown}, not "
                    f"{(name or 'a missing or malformed Host header')[:80]!s}",
                    status_code=400)(scope, receive, send)
                return
        await self.app(scope, receive, send)


def same_origin(headers: Mapping[str, str]) -> bool:
    """Whether a request comes from this server's own pages (or names no origin: not a
    browser page of another site)."""
    origin = headers.get("origin")
    return origin is None or urlsplit(origin).netloc == headers.get("host")


def _dumps(obj: Any) -> str:
    return json.dumps(obj, separators=(",", ":"), allow_nan=False)


class _Connection:
    """The player's socket: a gate for what comes in, an outbox and the newest state for what
    goes out."""

    def __init__(self, ws: WebSocket):
        self.ws = ws
        self.gate = Gate()
        self.outbox: deque[str] = deque()
        self.state: str | None = None
        self.wake = asyncio.Event()
        self.sent_plan = -1
        self.sent_summary = -1
        self.sent_phase: str | None = None
        self.turn: tuple[object, ...] | None = None
        self.overflow = False  # the page stopped reading: the receiver drops it

    def control(self, obj: dict[str, Any]) -> None:
        self.queue(_dumps(obj))

    def queue(self, text: str) -> None:
        """Send ``text`` after what is queued; a full queue marks the page as not reading."""
        if len(self.outbox) >= MAX_OUTBOX:
            self.overflow = True
            return
        self.outbox.append(text)
        self.wake.set()

    async def sender(self) -> None:
        try:
            while True:
                await self.wake.wait()
                self.wake.clear()
                while self.outbox:
                    await self.ws.send_text(self.outbox.popleft())
                if self.state is not None:
                    text, self.state = self.state, None
                    await self.ws.send_text(text)
        except Exception as exc:  # the page went away mid-send: the receiver ends the session
            log.debug("sender stopped: %s", exc)


class Hub:
    """The tick loop and the (at most one) connected player of ``session``."""

    def __init__(self, session: GameSession):
        self.session, self.player = session, session.player
        self.hz = session.player.hz  # the game's tick is the server's tick: game time = real time
        self.conn: _Connection | None = None
        self.ticks = 0
        self.late = 0  # ticks that ran more than one period late
        self._tick_failed = False

    # -- the tick -----------------------------------------------------------------------------
    async def tick_loop(self) -> None:
        loop = asyncio.get_running_loop()
        period = 1.0 / self.hz
        deadline = loop.time()
        while True:
            deadline += period
            delay = deadline - loop.time()
            if delay > 0:
                await asyncio.sleep(delay)
            else:
                if delay < -period:
                    self.late += 1
                if delay < -0.25:  # far behind (a stall): drop the backlog, keep real time
                    deadline = loop.time()
                # catching up: still let the senders run, so every tick's state goes out
                await asyncio.sleep(0)
            try:
                self.tick()
            except Exception:  # e.g. news that cannot be sent: logged, and the game goes on
                if not self._tick_failed:
                    log.exception("a tick failed")
                    self._tick_failed = True

    def tick(self) -> None:
        """One tick: advance the game, hand the state and any news to the page."""
        try:
            state = self.player.tick()
        except Exception:
            if not self._tick_failed:  # once: a broken game must not flood the log
                log.exception("the game failed to advance")
                self._tick_failed = True
            return
        self.ticks += 1
        conn = self.conn
        if conn is None:
            return
        self._news(conn)
        if state is not None:
            text = _dumps(state)
            turn = (state["cycle"], state["started"], state["human_done"], state["over"],
                    state["ask"])
            if turn != conn.turn:  # a state where the cycle turns is queued, never dropped
                conn.turn = turn
                conn.queue(text)
            else:
                conn.state = text
        conn.wake.set()

    def _news(self, conn: _Connection) -> None:
        version = self.player.plan_version
        if version != conn.sent_plan:
            view = self.player.plan_view()
            if view is not None:
                conn.control(view)
            conn.sent_plan = version
        s = self.session
        if s.summary_version != conn.sent_summary and s.summary is not None:
            conn.sent_summary = s.summary_version
            conn.control(s.summary)
        phase = s.phase
        if phase != conn.sent_phase:
            conn.sent_phase = phase
            conn.control({"type": "phase", "phase": phase, "cycle": self.player.cycle,
                          "stored": s.stored, "error": s.error})

    # -- the player's messages ----------------------------------------------------------------
    def handle(self, conn: _Connection, raw: str | bytes) -> None:
        try:
            msg = conn.gate.check(raw)
            if isinstance(msg, Move):
                self.player.steer(move=(msg.dx, msg.dy))
            elif isinstance(msg, Target):
                self.player.steer(target=(msg.x, msg.y))
            elif isinstance(msg, Start) and not self.player.start(msg.cycle):
                conn.gate.refused += 1
                raise Refused(f"cycle {msg.cycle} is not ready to start (on screen: cycle "
                              f"{self.player.cycle}, {self.player.phase})")
            elif isinstance(msg, TooClose) and not self.player.too_close(msg.cycle):
                conn.gate.refused += 1
                raise Refused(f"cycle {msg.cycle} is not under way (on screen: cycle "
                              f"{self.player.cycle}, {self.player.phase})")
            elif isinstance(msg, Comfort) and not self.player.answer(msg.cycle, msg.answer):
                conn.gate.refused += 1
                raise Refused(f"no comfort question about cycle {msg.cycle} is open")
        except Refused as exc:
            n = conn.gate.refused
            if n <= _LOGGED_REFUSALS or n % 100 == 0:
                log.warning("refused a message (%d so far): %s", n, exc)
            conn.control({"type": "refused-message", "reason": str(exc)})

    async def connect(self, ws: WebSocket) -> None:
        if not same_origin(ws.headers):
            log.warning("refused a WebSocket from origin %s (this server is %s)",
                        ws.headers.get("origin"), ws.headers.get("host"))
            await ws.close(code=1008)
            return
        await ws.accept()
        if self.conn is not None:
            log.warning("refused a second browser: one player per run")
            await refuse_socket(ws, _BUSY)
            return
        conn = _Connection(ws)
        self.conn = conn
        log.info("a player connected")
        conn.control({"type": "welcome", **self.session.info()})
        sender = asyncio.create_task(conn.sender())
        try:
            while True:
                event = await ws.receive()
                if event["type"] == "websocket.disconnect":
                    break
                raw = event.get("text")
                self.handle(conn, raw if raw is not None else (event.get("bytes") or b""))
                if conn.overflow:
                    log.warning("dropped a page that sends but does not read (%d messages "
                                "waiting for it)", len(conn.outbox))
                    break
        finally:
            sender.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await sender
            if self.conn is conn:
                self.conn = None
            if self.player.restart():
                log.info("the player left mid-cycle: the cycle starts again when they return")
            if ws.application_state != WebSocketState.DISCONNECTED:
                # bounded: a page that does not read may never take the close frame
                with contextlib.suppress(Exception):
                    await asyncio.wait_for(ws.close(code=1008 if conn.overflow else 1000), 2.0)


async def refuse_socket(ws: WebSocket, reason: str) -> None:
    """Accept ``ws`` only to tell the page why it cannot play (shown, never retried), and close
    it."""
    if ws.application_state == WebSocketState.CONNECTING:
        await ws.accept()
    await ws.send_text(_dumps({"type": "refused", "reason": reason}))
    await ws.close(code=4009)


def _static(name: str) -> str:
    return (files("rapidds.web") / "static" / name).read_text(encoding="utf-8")


def game_page(ws_path: str | None = None) -> str:
    """The game's page; ``ws_path``: a study round's WebSocket (one per participant; the page
    then speaks of rounds of a study), else ``/ws``."""
    page = _static("index.html")
    if ws_path is None:
        return page
    return page.replace("<body>", f'<body data-ws="{html.escape(ws_path, quote=True)}">', 1)


def create_app(session: GameSession, hosts: Sequence[str] = LOOPBACK) -> FastAPI:
    """The ASGI app of ``session``: the page, its assets and the player's WebSocket; requests
    for another host name than ``hosts`` are refused (400)."""
    hub = Hub(session)

    @contextlib.asynccontextmanager
    async def lifespan(_: FastAPI) -> AsyncIterator[None]:
        task = asyncio.create_task(hub.tick_loop())
        try:
            yield
        finally:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task

    app = FastAPI(lifespan=lifespan, docs_url=None, redoc_url=None, openapi_url=None)
    app.add_middleware(HostCheck, hosts=list(hosts))
    app.state.hub = hub
    headers = {"Cache-Control": "no-store", "X-Content-Type-Options": "nosniff",
               "Content-Security-Policy": "default-src 'self'; connect-src 'self'; "
                                          "img-src 'self' data:; frame-ancestors 'none'"}

    @app.get("/", response_class=HTMLResponse)
    def index() -> Response:
        return HTMLResponse(game_page(), headers=headers)

    app.mount("/static", StaticFiles(packages=[("rapidds.web", "static")]), name="static")

    @app.websocket("/ws")
    async def ws_endpoint(ws: WebSocket) -> None:
        await hub.connect(ws)

    return app


def served_url(sock: socket.socket) -> str:
    """The address a listening socket serves, as a browser opens it (IPv6 in brackets)."""
    bound = sock.getsockname()
    shown = f"[{bound[0]}]" if ":" in bound[0] else bound[0]
    return f"http://{shown}:{bound[1]}/"


def reach_line(host: str, hosts: Sequence[str]) -> str | None:
    """What a bind beyond loopback exposes, in one line (None on loopback): the names other
    machines can reach the server by."""
    if host in LOOPBACK:
        return None
    return f"listening on {host}: other machines can reach it by the names {', '.join(hosts)}"


def listen(host: str, port: int) -> socket.socket:
    """A listening socket on ``host:port`` (port 0: any free port); one line if it cannot."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
    except OSError as exc:
        sock.close()
        raise RapiddsError(f"cannot listen on {host}:{port} ({exc.strerror or exc})") from None
    sock.listen(16)
    sock.setblocking(False)
    return sock


def serve(session: GameSession, sock: socket.socket, *,
          on_ready: Callable[[], None] | None = None) -> None:
    """Serve ``session`` on ``sock`` until Ctrl-C (SIGINT) or SIGTERM."""
    import uvicorn

    hosts = allowed_hosts(str(sock.getsockname()[0]))
    config = uvicorn.Config(create_app(session, hosts), log_level="warning", lifespan="on",
                            ws_max_size=WS_MAX_BYTES, timeout_graceful_shutdown=3,
                            access_log=False)
    server = uvicorn.Server(config)
    if on_ready is not None:
        on_ready()
    t0 = time.perf_counter()
    server.run(sockets=[sock])
    log.info("server stopped after %.0f s", time.perf_counter() - t0)
