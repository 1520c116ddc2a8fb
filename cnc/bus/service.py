"""One command service: how every door of the controller serves its queries, the same way in each.

A door is a set of `Route`s: a key, the message type its payload decodes to, who may send it (the
user the key names and that user's role; the station holding the command lock) and its handler.
For each query the service decodes the payload into the typed message (a malformed one is
refused, never a crash), checks the caller, runs the handler and replies: the handler's answer,
or `Reply(False, "<what>: <why>")` for a `CommandRefused` - the one refusal type of the
controller. A read route (its asker expects the data's own type) answers a refusal with a Zenoh
error carrying the same text.

Anything else a handler raises is a bug, and the policy is STYLE.md's third tier, the same in
every process: logged with its stack; when the route commands motion or the jet, the machine to
its safe state (jet off, axes stopped on the path) before anything else; the internal-error alarm
(the process's `on_bug`: the control logic raises it itself, the other processes report it to
the logic on `internal/logic/bug`, which does both); the reply says internal error; the service
keeps serving the next query.

Serving is polled (`poll()`, from the process's own loop: the logic's scan, the planner's and the
logger's loops, none of which may be entered by a Zenoh thread) or threaded (`threaded=True`: a
worker thread per lane, the gateway's, so that a stop never queues behind a load or a history
query). Replies go out through `send` (the logic answers from its recorder's thread, once what a
command raised is stored).

Fault injection (the simulated board only): `inject` reads which handlers must raise
`InjectedBug` ("<process>/<verb>,...", the `sim` block's `inject_bug`, set by
`Supervisor.set_sim`), so that the policy is tested through the real processes while they cut.
"""

from __future__ import annotations

import json
import logging
import queue
import threading
from dataclasses import dataclass
from typing import Any, Callable, Protocol

import msgspec
import zenoh

from .access import Roles
from .keys import Keys
from .messages import InternalError, Reply, SchemaVersionError, decode, encode
from .users import role_at_least

log = logging.getLogger(__name__)

DEFERRED = object()  # a handler's result: the answer comes later, by `Request.answer`


class CommandRefused(Exception):
    """A request refused before anything changed; the message says why, with the values."""


class InjectedBug(RuntimeError):
    """A bug put into a handler on purpose (fault injection on the simulated board)."""


class LockCheck(Protocol):
    """The command lock as the service asks it: refuse (CommandRefused) anyone but the holder."""

    def require(self, user: str, station: str) -> None: ...


@dataclass(frozen=True)
class Caller:
    """Who sent a query: the user its key names (`u/<user>/...`, which the router lets only that
    user send: authenticated), and the station and Zenoh session its attachment declares."""

    user: str = ""
    station: str = ""
    session: str = ""


class Request:
    """One query as a handler sees it: the route's verb, the key it came on, the caller, the raw
    payload, the decoded message (None for a route without a payload type) and the selector's
    parameters. `answer()` replies later, for a handler that returned DEFERRED."""

    __slots__ = ("verb", "what", "key", "caller", "payload", "message", "params", "_query", "_service", "_route")

    def __init__(self, service: "CommandService", route: "Route", query: Any, caller: Caller, payload: bytes) -> None:
        self._service, self._route, self._query = service, route, query
        self.verb, self.key, self.caller, self.payload = route.verb, str(query.key_expr), caller, payload
        self.what = route.what(self.key) if route.what is not None else route.verb
        self.message: Any = None
        self.params = dict(query.selector.parameters)

    @property
    def read(self) -> bool:
        """The route answers with data (a refusal is a Zenoh error)."""
        return self._route.read

    @property
    def motion(self) -> bool:
        """The route commands motion or the jet: a bug in it brings the machine to its safe state."""
        return self._route.motion

    def answer(self, message: msgspec.Struct) -> None:
        """Reply now to a request whose handler returned DEFERRED."""
        self._service._finish(self, message)


@dataclass(frozen=True)
class Route:
    """One key a door serves. `kind`: the payload's message type (None: the handler reads the raw
    payload, if any); `read`: the answer is data, and a refusal a Zenoh error; `role`: the sender's
    least role (the user the key names); `lock`: its station must hold the command lock;
    `motion`: the handler commands motion or the jet (a bug brings the machine to its safe state);
    `lane`: which worker serves it (threaded services); `audit`: every answer goes to the audit
    hook; `what`: the name refusals carry, from the key (default the verb); `bare`: a query without
    a payload stands for the message with its defaults (a stop that says nothing but its key)."""

    verb: str
    key: str
    handler: Callable[[Request], Any]
    kind: type | None = None
    read: bool = False
    role: str = ""
    lock: bool = False
    motion: bool = False
    lane: str = "main"
    audit: bool = False
    what: Callable[[str], str] | None = None
    bare: bool = False


OnBug = Callable[[Request, BaseException], None]


class CommandService:
    """The queryables of one process's doors; `close()` undeclares them and stops the workers."""

    def __init__(
        self, session: zenoh.Session, keys: Keys, process: str, on_bug: OnBug, *, threaded: bool = False,
        roles: Roles | None = None, lock: LockCheck | None = None,
        audit: Callable[[Request, Reply], None] | None = None, send: Callable[[Callable[[], None]], None] | None = None,
        inject: Callable[[], str] | None = None,
    ) -> None:
        """`on_bug(request, exc)`: the process's safe state (when `request`'s route commands motion)
        and internal-error alarm; `inject`: the handlers to fail on purpose, "<process>/<verb>,..."
        (`cnc.data.injection`: only on the simulated board)."""
        self.session, self.keys, self.process, self.on_bug = session, keys, process, on_bug
        self.threaded, self.roles, self.lock, self.audit = threaded, roles, lock, audit
        self.send = send or (lambda reply: reply())
        self.inject = inject
        self.routes: list[tuple[Route, Any]] = []
        self.lanes: dict[str, queue.Queue] = {}
        self.workers: list[threading.Thread] = []

    # -- declaring ------------------------------------------------------------------------------

    def serve(self, *routes: Route) -> None:
        """Declare the queryables of `routes` (in a threaded service each lane gets its worker)."""
        for route in routes:
            if self.threaded:
                lane = self._lane(route.lane)
                queryable = self.session.declare_queryable(route.key, lambda q, r=route, to=lane: to.put((r, q)))
            else:
                queryable = self.session.declare_queryable(route.key)
            self.routes.append((route, queryable))

    def post(self, lane: str, job: Callable[[], None]) -> None:
        """Run `job` on `lane`'s worker, in turn with its queries (an event the door acts on, such as
        the lock holder's station lost, goes on the realtime lane)."""
        self._lane(lane).put((None, job))

    def _lane(self, name: str) -> queue.Queue:
        if name not in self.lanes:
            self.lanes[name] = queue.Queue()
            worker = threading.Thread(target=self._work, args=(self.lanes[name],), name=f"{self.process}-{name}", daemon=True)
            self.workers.append(worker)
            worker.start()
        return self.lanes[name]

    def close(self) -> None:
        for _, queryable in self.routes:
            queryable.undeclare()
        for lane in self.lanes.values():
            lane.put(None)
        for worker in self.workers:
            worker.join(5.0)

    # -- serving --------------------------------------------------------------------------------

    def poll(self, lanes: tuple[str, ...] | None = None) -> None:
        """Serve every query waiting on the routes of `lanes` (all when None): a polled service."""
        for route, queryable in self.routes:
            if lanes is None or route.lane in lanes:
                while (query := queryable.try_recv()) is not None:
                    self.handle(route, query)

    def _work(self, items: queue.Queue) -> None:
        while (item := items.get()) is not None:
            route, job = item
            if route is None:
                self._run_job(job)
            else:
                self.handle(route, job)

    def _run_job(self, job: Callable[[], None]) -> None:
        try:
            job()
        except Exception:  # a bug in an event the door acts on: logged, the worker goes on
            log.exception("%s: an internal job failed", self.process)

    def handle(self, route: Route, query: Any) -> None:
        """Decode, check, run, reply; a bug by the third tier's policy. Never raises."""
        payload = query.payload.to_bytes() if query.payload is not None else b""
        request = Request(self, route, query, _caller(query, self.keys), payload)
        try:
            self._check(route, request)
            if route.kind is not None:
                try:
                    sent = payload if query.payload is not None else b"{}"  # none at all: an empty object
                    request.message = route.kind() if route.bare and not payload else decode(sent, route.kind)
                except (msgspec.ValidationError, msgspec.DecodeError, SchemaVersionError) as exc:
                    raise CommandRefused(f"malformed command: {exc}") from None
            if self.inject is not None and f"{self.process}/{route.verb}" in self.inject().split(","):
                raise InjectedBug(f"{self.process}/{route.verb}: a bug injected on the simulated machine")
            answer = route.handler(request)
        except CommandRefused as exc:
            answer = _Declined(f"{request.what}: {exc}")
        except Exception as exc:
            answer = self._bug(request, exc)
        if answer is DEFERRED:
            return
        self._finish(request, Reply(True) if answer is None else answer)

    def _check(self, route: Route, request: Request) -> None:
        user, station = request.caller.user, request.caller.station
        if route.role and self.roles is not None:
            role = self.roles.role(user)
            if role is None:
                raise CommandRefused(f"user {user!r} has no account on this machine")
            if not role_at_least(role, route.role):
                raise CommandRefused(f"user {user!r} is an {role}; this needs an {route.role}")
        if route.lock and self.lock is not None:
            self.lock.require(user, station)

    def _bug(self, request: Request, exc: BaseException) -> "_Declined":
        log.error("%s: %s failed (a bug)", self.process, request.what, exc_info=exc)
        try:
            self.on_bug(request, exc)
        except Exception:
            log.exception("%s: could not even report the bug in %s", self.process, request.what)
        safe = "; the machine is brought to its safe state" if request.motion else ""
        return _Declined(f"{request.what}: internal error in the {self.process}: {exc!r}{safe} "
                        "(alarm internal_error; the controller log has the stack)")

    def _finish(self, request: Request, answer: Any) -> None:
        route, query = request._route, request._query
        reply = Reply(False, answer.text) if isinstance(answer, _Declined) else answer
        # the audit row handed over before the reply goes out (a queue's put: the disk is written by
        # the trail's own thread): once the asker has its answer and sends the next command, from
        # a thread of this process that may run first, this one's row is already in line before it
        if route.audit and self.audit is not None and isinstance(reply, Reply):
            try:
                self.audit(request, reply)
            except Exception:
                log.exception("%s: could not record %s in the audit trail", self.process, request.what)
        if route.read and isinstance(answer, _Declined):
            self.send(lambda: _reply_err(query, answer.text))
        else:
            self.send(lambda: _reply(query, reply))


class _Declined:
    """A refusal or an internal error on its way to the asker (a Reply, or a read's Zenoh error)."""

    __slots__ = ("text",)

    def __init__(self, text: str) -> None:
        self.text = text


def report_to_logic(session: zenoh.Session, keys: Keys, process: str) -> OnBug:
    """The `on_bug` of a process other than the logic: tell the logic, which brings the machine to
    its safe state when the route commands motion and raises the internal-error alarm. Sent without
    waiting (the asking process may be a loop that must not block)."""
    def report(request: Request, exc: BaseException) -> None:
        message = InternalError(process, request.what, repr(exc), request.motion)
        session.get(keys.logic("bug"), payload=encode(message), encoding=zenoh.Encoding.APPLICATION_JSON, timeout=5.0)
    return report


def _caller(query: Any, keys: Keys) -> Caller:
    attached: dict = {}
    if query.attachment is not None:
        try:
            value = json.loads(query.attachment.to_bytes())
            attached = value if isinstance(value, dict) else {}
        except ValueError:
            attached = {}
    station, session = attached.get("station", ""), attached.get("session", "")
    return Caller(keys.user_of(str(query.key_expr)), station if isinstance(station, str) else "",
                  session if isinstance(session, str) else "")


def _reply(query: Any, message: msgspec.Struct) -> None:
    query.reply(query.key_expr, encode(message), encoding=zenoh.Encoding.APPLICATION_JSON)
    query.drop()


def _reply_err(query: Any, text: str) -> None:
    query.reply_err(zenoh.ZBytes(text.encode()))
    query.drop()
