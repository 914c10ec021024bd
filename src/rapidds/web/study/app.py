"""The study app: FastAPI pages for the experimenter and the participant, JSON submits.

``GET /?token=KEY`` the experimenter's overview (the key ``rapidds study serve`` prints: the
overview names each participant's systems, and no participant page links to it);
``GET /p/{pid}`` the participant's current step (the round's plan and input form, the survey,
the ranking, the demographics form, or "done"): one address per participant, so a reload, a
reopened browser or a restarted server shows exactly where they stand.
``POST /api/p/{pid}/{round|survey|ranking|demographics}`` takes ``{"step": token, "fields":
{name: text}, "tracker": text?}`` and answers ``{"next": url}`` (200) or ``{"error": message}``:
400 for input the page must fix (a duration longer than any task of the study, an unknown
field, a tracker file too wide or too long), 404 for an unknown participant, 409 for a page
that answers a step already done (the message says what comes next), 413 for a body over
:data:`MAX_BODY`, 415/422 for a request no page of ours sends (not JSON, nested too deeply).
Never 500 for what a client sends.

All study work (SQLite, planning) runs in one worker thread that owns the
:class:`~rapidds.web.study.runner.StudySession`, so requests are served one at a time in
order, and a submit is never interleaved with another. After a round is recorded the next plan
is computed at once in that thread, while the browser loads the next page.

Safety as in the game server: requests for other host names than the server's are refused
(DNS rebinding), a POST from another site's page (``Origin`` not this server) is refused, and
submits must be JSON (a cross-site form cannot send it without a preflight we never answer).

Fetch studies also offer the "game" source (:mod:`rapidds.web.study.play`): ``GET /p/{pid}/play``
is the browser game's page for the participant's current round and ``/p/{pid}/ws`` its
WebSocket; the game records the round itself when the person's tasks are done.
"""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import json
import logging
import re
import secrets
from collections.abc import AsyncIterator, Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Annotated, Any, TypeVar
from urllib.parse import quote

from fastapi import FastAPI, Request, WebSocket
from fastapi.responses import HTMLResponse, JSONResponse, RedirectResponse, Response
from fastapi.staticfiles import StaticFiles
from pydantic import BaseModel, ConfigDict, Field, ValidationError
from starlette.exceptions import HTTPException as StarletteHTTPException

from rapidds.errors import RapiddsError, StateError, StudyDataError
from rapidds.settings import error_line
from rapidds.web.server import HostCheck, game_page, refuse_socket, same_origin
from rapidds.web.study import pages
from rapidds.web.study.play import GameRound, open_round
from rapidds.web.study.runner import InputError, OutOfTurn, StudySession, step_token
from rapidds.web.study.tracker import MAX_TRACKER_BYTES
from rapidds.worlds.capabilities import BrowserPlay, capability, lacks

__all__ = ["MAX_BODY", "StudyWorker", "create_study_app"]

log = logging.getLogger("rapidds.web")
MAX_BODY = 2 * MAX_TRACKER_BYTES + 64 * 1024
"""Largest submit body: a tracker file travels as a JSON string, and escaping its newlines and
quotes can double it (a 7.6 MiB CSV made a body past 8 MiB); the file itself is measured after
decoding against :data:`MAX_TRACKER_BYTES`."""
_PID = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.+-]{0,63}")
T = TypeVar("T")
_HEADERS = {"Cache-Control": "no-store", "X-Content-Type-Options": "nosniff",
            "Content-Security-Policy": "default-src 'self'; img-src 'self' data:; "
                                       "frame-ancestors 'none'"}
_TRACKER_HELP = (
    "One row per body point per sample, with the header <code>task,point,t,x,y,z</code>: the "
    "task (each of the person's tasks this round), the body point's index in the world's order "
    "(painting: 0 left hand, 1 right hand, 2 left elbow, 3 right elbow), the time in seconds "
    "and the position in metres; JSON: a list of objects with the same fields. See "
    "docs/design-notes.md, \u201cStudy app\u201d.")


class Submit(BaseModel):
    """The body of every submit."""

    model_config = ConfigDict(extra="forbid", strict=True)
    step: Annotated[str, Field(max_length=200)]
    fields: dict[Annotated[str, Field(max_length=100)],
                 Annotated[str, Field(max_length=2000)]] = Field(default_factory=dict,
                                                                 max_length=200)
    tracker: Annotated[str, Field(max_length=MAX_TRACKER_BYTES)] | None = None


class StudyWorker:
    """The session and the one thread it lives in: ``await worker.call(fn, *args)`` runs
    ``fn(session, *args)`` there."""

    def __init__(self, open_session: Callable[[], StudySession]):
        self._pool = ThreadPoolExecutor(1, thread_name_prefix="rapidds-study")
        try:
            self.session: StudySession = self._pool.submit(open_session).result()
        except BaseException:
            self._pool.shutdown(wait=True)
            raise

    def run(self, fn: Callable[..., T], *args: Any) -> T:
        """``fn(session, *args)`` in the worker thread, waited for (outside the event loop)."""
        return self._pool.submit(fn, self.session, *args).result()

    async def call(self, fn: Callable[..., T], *args: Any) -> T:
        loop = asyncio.get_running_loop()
        return await loop.run_in_executor(self._pool, fn, self.session, *args)

    def background(self, fn: Callable[..., Any], *args: Any) -> None:
        """Queue ``fn(session, *args)``; a failure is logged (the page that needs the result
        computes it again and reports)."""
        def work() -> None:
            try:
                fn(self.session, *args)
            except Exception:
                log.exception("background work failed")
        self._pool.submit(work)

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self._pool.submit(self.session.close).result(timeout=60)
        self._pool.shutdown(wait=True, cancel_futures=True)


def _error(status: int, message: str, **extra: Any) -> JSONResponse:
    return JSONResponse({"error": message, **extra}, status_code=status, headers=_HEADERS)


def _html(text: str, status: int = 200) -> HTMLResponse:
    return HTMLResponse(text, status_code=status, headers=_HEADERS)


def _check_pid(pid: str) -> str:
    if not _PID.fullmatch(pid):
        raise StudyDataError(f"'{pid[:80]}' is not a participant id")
    return pid


class _Games:
    """The game rounds in play, one per participant (or the one they played last)."""

    def __init__(self, worker: StudyWorker):
        self.worker = worker
        self.rounds: dict[str, GameRound] = {}
        self.opening = asyncio.Lock()

    async def open(self, world: BrowserPlay, pid: str, token: str) -> GameRound:
        """The game of ``pid``'s current round ``token``: the open one, or a new one (the first
        page, a failed one, or a server restarted meanwhile). OutOfTurn when the study has
        moved on."""
        async with self.opening:
            game = self.rounds.get(pid)
            if game is None or game.token != token or not game.open:
                if game is not None:
                    await game.close(f"{pid}'s round was opened again elsewhere, or the study "
                                     f"moved on: open /p/{pid}")
                    del self.rounds[pid]
                self.rounds[pid] = await open_round(self.worker, world, pid, token)
            return self.rounds[pid]

    async def close_all(self) -> None:
        for game in list(self.rounds.values()):
            await game.close()


def create_study_app(worker: StudyWorker, hosts: Sequence[str],
                     token: str | None = None) -> FastAPI:
    """The ASGI app of the study ``worker`` serves; ``hosts``: host names it answers to;
    ``token``: the experimenter's key to the overview (``/?token=...``; default a new random
    one, ``app.state.token``)."""
    key = token or secrets.token_urlsafe(18)
    games = _Games(worker)

    @contextlib.asynccontextmanager
    async def lifespan(_: FastAPI) -> AsyncIterator[None]:
        try:
            yield
        finally:  # a round in play is dropped, never half stored
            await games.close_all()

    app = FastAPI(lifespan=lifespan, docs_url=None, redoc_url=None, openapi_url=None)
    app.add_middleware(HostCheck, hosts=list(hosts))
    app.state.worker = worker
    app.state.token = key
    app.mount("/static", StaticFiles(packages=[("rapidds.web", "static")]), name="static")

    @app.exception_handler(StarletteHTTPException)
    async def http_error(request: Request, exc: StarletteHTTPException) -> Response:
        if request.url.path.startswith("/api/"):
            return _error(exc.status_code, str(exc.detail))
        return _html(pages.message_page(f"{exc.status_code}", str(exc.detail)), exc.status_code)

    _page_routes(app, worker, key)
    _game_routes(app, worker, games)
    _submit_routes(app, worker)
    return app


def _page_routes(app: FastAPI, worker: StudyWorker, key: str) -> None:
    """The experimenter's overview and each participant's current step."""

    @app.get("/", response_class=HTMLResponse)
    async def overview(token: str = "") -> Response:
        if not hmac.compare_digest(token.encode("utf-8", "replace"), key.encode("utf-8")):
            return _html(pages.message_page(
                "Experimenters only", "The overview names each participant's systems, so it "
                "needs the experimenter's address that 'rapidds study serve' printed at start "
                "(/?token=...). A participant's page is /p/ID."), 403)
        rows = await worker.call(lambda s: s.overview())
        design = await worker.call(lambda s: s.store.design)
        base = await worker.call(lambda s: s.store.base_config)
        facts = (f"{design.participants} participants, systems {', '.join(design.systems)}, "
                 f"{design.rounds} rounds each; world {base.world} ({base.variant}), "
                 f"gamma {base.gamma}, seed {design.seed}. Open a participant to run their "
                 "session; every submit is stored at once.")
        return _html(pages.overview_page("Study overview", rows, pages.e(facts)))

    @app.get("/p/{pid}", response_class=HTMLResponse)
    async def participant(pid: str) -> Response:
        try:
            _check_pid(pid)
            step = await worker.call(lambda s: s.next_step(pid))
        except StudyDataError as exc:
            return _html(pages.message_page("Unknown participant", str(exc)), 404)
        token = step_token(step)
        blocks = await worker.call(lambda s: len(s.store.design.systems))
        if step.kind == "round":
            held = await worker.call(lambda s: s.plan(pid))
            assert held is not None
            game = f"/p/{pid}/play" if worker.session.has_game else None
            sources = await worker.call(lambda s: s.sources(pid))
            comfort = await worker.call(lambda s: s.store.design.comfort)
            return _html(pages.round_page(pid, held[1].as_dict(), tracker_help=_TRACKER_HELP,
                                          game=game, sources=sources, comfort=comfort))
        if step.kind == "survey":
            items = await worker.call(lambda s: s.items())
            return _html(pages.survey_page(pid, token, int(step.block or 0), blocks, items))
        if step.kind == "ranking":
            return _html(pages.ranking_page(pid, token, blocks))
        if step.kind == "demographics":
            return _html(pages.demographics_page(pid, token))
        return _html(pages.done_page(pid))

    @app.get("/p/{pid}/", include_in_schema=False)
    async def participant_slash(pid: str) -> Response:
        return RedirectResponse(f"/p/{pid}", status_code=307)


def _game_routes(app: FastAPI, worker: StudyWorker, games: _Games) -> None:
    """The browser game of a participant's current round: its page and its socket."""

    @app.get("/p/{pid}/play", response_class=HTMLResponse)
    async def play(pid: str) -> Response:
        world = capability(worker.session.world, "browser_play")
        if world is None:
            return _html(pages.message_page(
                "No game in this study", f"{lacks(worker.session.world, 'browser_play')}: "
                f"record the round on /p/{pid}"), 404)
        try:
            _check_pid(pid)
            step = await worker.call(lambda s: s.next_step(pid))
        except StudyDataError as exc:
            return _html(pages.message_page("Unknown participant", str(exc)), 404)
        if step.kind != "round":
            return _html(pages.message_page(
                "No round to play", f"{pid} has no round to play now: their next step is "
                f"{step.describe()}. Open /p/{pid} to go on."), 409)
        token = step_token(step)
        try:
            await games.open(world, pid, token)
        except OutOfTurn as exc:
            return _html(pages.message_page("No round to play", str(exc)), 409)
        return _html(game_page(f"/p/{pid}/ws?step={quote(token)}"))

    @app.websocket("/p/{pid}/ws")
    async def play_socket(ws: WebSocket, pid: str, step: str = "") -> None:
        """The game page's socket; ``step``: the round the page plays (a page of a round the
        study moved past is refused; after a restart the round's game is opened again)."""
        if not same_origin(ws.headers):
            await ws.close(code=1008)  # another site's page: nothing said, nothing opened
            return
        world = capability(worker.session.world, "browser_play")
        if world is None:
            await refuse_socket(ws, lacks(worker.session.world, "browser_play"))
            return
        try:
            _check_pid(pid)
            now = await worker.call(lambda s: s.next_step(pid))
        except StudyDataError as exc:
            await refuse_socket(ws, str(exc))
            return
        if now.kind != "round" or step_token(now) != step:
            await refuse_socket(ws, f"this round is over for the study: {pid}'s next step is "
                                    f"{now.describe()}; open /p/{pid}")
            return
        try:
            game = await games.open(world, pid, step)
        except OutOfTurn as exc:
            await refuse_socket(ws, str(exc))
            return
        await game.hub.connect(ws)


def _submit_routes(app: FastAPI, worker: StudyWorker) -> None:
    """``POST /api/p/{pid}/{kind}``: read the body, then hand it to the session."""

    @app.post("/api/p/{pid}/{kind}")
    async def submit(request: Request, pid: str, kind: str) -> Response:
        if kind not in ("round", "survey", "ranking", "demographics"):
            return _error(404, f"no such submit: {kind[:40]!r}")
        sub = await _read_submit(request)
        if isinstance(sub, Response):
            return sub
        return await _store_submit(worker, pid, kind, sub)


async def _read_submit(request: Request) -> Submit | Response:
    """The request's :class:`Submit`, or the error response for a request no page of ours
    sends (another site, not JSON, too large, nested too deeply)."""
    if not same_origin(request.headers):
        origin = request.headers.get("origin", "")
        return _error(403, f"a submit from another site ({origin[:80]}) is refused")
    ctype = request.headers.get("content-type", "").split(";")[0].strip().lower()
    if ctype != "application/json":
        return _error(415, "send the submit as JSON (Content-Type: application/json)")
    size = request.headers.get("content-length")
    if size is not None and (not size.isdigit() or int(size) > MAX_BODY):
        return _error(413, f"the request is larger than {MAX_BODY // 2**20} MiB")
    body = bytearray()
    async for chunk in request.stream():
        body += chunk
        if len(body) > MAX_BODY:
            return _error(413, f"the request is larger than {MAX_BODY // 2**20} MiB")
    try:
        raw = json.loads(body)
        json.dumps(raw, ensure_ascii=False).encode("utf-8")  # no lone surrogate (\ud800)
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        return _error(422, f"the body is not valid JSON ({exc})")
    except UnicodeEncodeError:
        return _error(422, "the body holds text that is not valid Unicode (a lone surrogate)")
    except ValueError:  # a whole number of over 4300 digits: Python's limit on int(text)
        return _error(400, "the body holds a number too long to read (over 4300 digits)")
    except RecursionError:  # e.g. 100 000 '[': no page sends more than two levels
        return _error(422, "the body's JSON is nested too deeply")
    try:
        return Submit.model_validate(raw)
    except ValidationError as exc:
        return _error(422, error_line(exc, empty="body"))


async def _store_submit(worker: StudyWorker, pid: str, kind: str, sub: Submit) -> Response:
    """Hand a well-formed submit to the session; its refusals become 400/404/409."""
    try:
        _check_pid(pid)
        if kind == "round":
            source = sub.fields.get("source", "")
            fields = {k: v for k, v in sub.fields.items() if k != "source"}
            await worker.call(lambda s: s.submit_round(pid, sub.step, source, fields,
                                                       sub.tracker))
            worker.background(lambda s: s.plan(pid))  # the next page's plan, right away
        elif kind == "survey":
            await worker.call(lambda s: s.submit_survey(pid, sub.step, sub.fields))
        elif kind == "ranking":
            await worker.call(lambda s: s.submit_ranking(pid, sub.step, sub.fields))
        else:
            await worker.call(lambda s: s.submit_demographics(pid, sub.step, sub.fields))
    except OutOfTurn as exc:
        return _error(409, str(exc), next=f"/p/{pid}")
    except InputError as exc:
        return _error(400, str(exc))
    except StudyDataError as exc:  # an unknown participant
        return _error(404, str(exc))
    except StateError as exc:  # the store refused (out of turn in another way, locked)
        return _error(409, str(exc), next=f"/p/{pid}")
    except RapiddsError as exc:
        return _error(400, str(exc))
    return JSONResponse({"next": f"/p/{pid}"}, headers=_HEADERS)
