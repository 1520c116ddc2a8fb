"""`waterjet watch`: a read-only terminal observer of a running controller over Zenoh.

It connects as a Zenoh client, catches up on the alarm history, then prints what the
controller publishes: the status about once a second in one line, every alarm event and
every procedure change as they arrive (with `--json`, every message as one JSON object per
line). Alarm events carry sequence numbers that increase by one per history entry; the
watcher fills any gap (an event lost while the session reconnected, or published while the
controller restarted) from the history, so it never misses an entry and never prints one twice.
"""

from __future__ import annotations

import argparse
import os
import queue
import signal
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, TextIO

import msgspec
import zenoh

from .bus import messages
from .bus.keys import Keys
from .bus.messages import AlarmEvent, HistoryPage, ProcedureState, SchemaVersionError, Status, decode
from .bus.certs import CertError, TlsFiles, files_for
from .bus.session import connect_endpoints, open_client
from .bus.states import ServoFault
from .config import DEFAULT_MACHINE, ConfigError, load_machine

CONNECT_TIMEOUT_S = 3.0  # how long the router may take to accept the session
ANSWER_TIMEOUT_S = 3.0  # how long the controller may take to answer or publish anything
PAGE_SIZE = 500  # history entries per query (the controller caps a page at 1000)
HISTORY_SHOWN = 10  # history entries printed at start-up in the human format
STATUS_PERIOD_S = 1.0  # the human format prints the status this often
GAP_GRACE_S = 0.5  # a status may announce an entry before its event arrives: wait this long
HOLE_RETRY_S = 1.0  # unfilled gaps (the history did not answer) are retried this often


class WatchError(RuntimeError):
    """The watcher cannot go on: no controller, a schema it does not speak, a refused query."""


class NoAnswer(WatchError):
    """Nobody answered a query within the timeout."""


# -- the alarm history --------------------------------------------------------------------


class History:
    """The controller's `alarms/history` queryable, read page by page (oldest first)."""

    def __init__(self, session: zenoh.Session, keys: Keys, timeout_s: float = ANSWER_TIMEOUT_S,
                 page_size: int = PAGE_SIZE) -> None:
        self.session, self.keys, self.timeout_s, self.page_size = session, keys, timeout_s, page_size

    def page(self, after: int) -> HistoryPage:
        """One page of entries with a sequence number above `after`; NoAnswer when nobody answers."""
        selector = f"{self.keys.alarms_history}?after={after};limit={self.page_size}"
        for reply in self.session.get(selector, timeout=self.timeout_s):
            if reply.ok is not None:
                return decode(reply.ok.payload.to_bytes(), HistoryPage)
            raise WatchError(f"{selector}: the controller answered with an error: {reply.err.payload.to_string()}")
        raise NoAnswer(f"{selector}: no answer within {self.timeout_s:g} s")

    def after(self, seq: int, up_to: int | None = None) -> list[AlarmEvent]:
        """Every entry with a sequence number above `seq` (and at most `up_to`), paging until done."""
        entries: list[AlarmEvent] = []
        while True:
            page = self.page(seq)
            entries += [e for e in page.entries if up_to is None or e.seq <= up_to]
            if not page.entries or not page.more or (up_to is not None and page.entries[-1].seq >= up_to):
                return entries
            seq = page.entries[-1].seq


class AlarmFollower:
    """Keeps the alarm events in sequence: drops repeats, fetches the entries a gap hides.

    `last_seq` is the newest entry handed out. An event more than one above it means entries
    were missed: they are read from the history and handed out before it. When the history
    does not answer (the control logic restarting), the event is still handed out and the
    gap is kept in `holes` until `fill_holes` reads it.
    """

    def __init__(self, history: History, last_seq: int = 0) -> None:
        self.history, self.last_seq = history, last_seq
        self.holes: list[tuple[int, int]] = []  # (first, last) sequence numbers still missing

    def catch_up(self) -> list[AlarmEvent]:
        """Every entry after `last_seq` (start-up, or a status announcing newer entries)."""
        entries = self.history.after(self.last_seq)
        if entries:
            self.last_seq = max(self.last_seq, entries[-1].seq)
        return entries

    def accept(self, event: AlarmEvent) -> list[AlarmEvent]:
        """The entries to show for a live event, in sequence order: missed ones first; [] for a repeat."""
        if event.seq <= self.last_seq:
            return []
        first_missing, self.last_seq = self.last_seq + 1, event.seq
        if event.seq == first_missing:
            return [event]
        try:
            return [*self.history.after(first_missing - 1, up_to=event.seq - 1), event]
        except NoAnswer:
            self.holes.append((first_missing, event.seq - 1))
            return [event]

    def fill_holes(self) -> list[AlarmEvent]:
        """Read the gaps an unanswered history query left; those still unanswered stay."""
        found, still = [], []
        for first, last in self.holes:
            try:
                found += self.history.after(first - 1, up_to=last)
            except NoAnswer:
                still.append((first, last))
        self.holes = still
        return found


# -- output ---------------------------------------------------------------------------------


def _clock(stamp_ns: int) -> str:
    return time.strftime("%H:%M:%S", time.localtime(stamp_ns / 1e9))


def _duration(seconds: float) -> str:
    if seconds < 0:
        return "--"
    minutes, s = divmod(int(round(seconds)), 60)
    return f"{minutes // 60}:{minutes % 60:02d}:{s:02d}" if minutes >= 60 else f"{minutes}:{s:02d}"


def status_line(st: Status) -> str:
    """One line a person reads at a glance: state, motion, jet and pump, link, alarms, program."""
    axes = " ".join(f"{a.name.upper()} {a.position_mm:9.3f}" for a in st.axes)
    alarms = f"alarms {st.alarms_active}" + (f" ({st.alarm_level})" if st.alarm_level else "")
    if st.program is None:
        program = "no program"
    else:
        p = st.program
        program = f"{p.name} {100 * p.progress:5.1f} % line {p.line} ETA {_duration(p.eta_s)} ({p.result})"
    fault = f" | FAULT {st.fault}{' ' + st.fault_axis if st.fault_axis else ''}" if st.fault != ServoFault.NONE.name else ""
    return (
        f"{_clock(st.stamp_ns)} {st.machine_state} {st.mode} phase {st.cycle_phase} | planner {st.planner_state}"
        f" | {axes} | feed {st.feed_actual_mm_s:7.1f} mm/s ({100 * st.feed_override:.0f} %)"
        f" | jet {'ON' if st.jet_on else 'off'} | pump {'ON' if st.pump_on else 'off'} {st.pump_pressure_bar:.0f} bar"
        f" | PLC {st.plc_link} | {alarms} | {program}{fault}"
    )


def alarm_line(e: AlarmEvent, source: str = "") -> str:
    detail = f": {e.detail}" if e.detail else ""
    origin = f" [{source}]" if source else ""
    return f"{_clock(e.stamp_ns)} #{e.seq} {e.action.upper()} {e.level} {e.code} {e.text}{detail}{origin}"


def procedure_line(p: ProcedureState) -> str:
    if not p.id:
        return "procedure: none"
    where = f" step {p.step + 1}/{len(p.steps)}" if p.step >= 0 else ""
    awaited = f": {p.instruction}" if p.instruction else ""
    return f"procedure {p.id} ({p.title}) {p.state}{where}{awaited}"


class HumanOutput:
    """Lines for a terminal: the status thinned to one a second, events as they come."""

    def __init__(self, out: TextIO) -> None:
        self.out = out
        self.next_status = 0.0

    def history(self, key: str, entries: list[AlarmEvent], caught_up: bool) -> None:
        if caught_up:
            shown = entries[-HISTORY_SHOWN:]
            self._print(f"alarm history: {len(entries)} entries" + (f", the last {len(shown)}:" if shown else ""))
            for e in shown:
                self._print("  " + alarm_line(e))
        else:
            for e in entries:
                self._print(alarm_line(e, "from history"))

    def message(self, key: str, msg: msgspec.Struct) -> None:
        if isinstance(msg, Status):
            now = time.monotonic()
            if now >= self.next_status:
                self.next_status = now + STATUS_PERIOD_S
                self._print(status_line(msg))
        elif isinstance(msg, AlarmEvent):
            self._print(alarm_line(msg))
        elif isinstance(msg, ProcedureState):
            self._print(procedure_line(msg))

    def _print(self, line: str) -> None:
        self.out.write(line + "\n")
        self.out.flush()


class JsonOutput:
    """One JSON object per message and line, `{"key": ..., "message": {...}}`: every message."""

    def __init__(self, out: TextIO) -> None:
        self.out = out
        self.encoder = msgspec.json.Encoder()

    def history(self, key: str, entries: list[AlarmEvent], caught_up: bool) -> None:
        for e in entries:
            self.message(key, e)

    def message(self, key: str, msg: msgspec.Struct) -> None:
        self.out.write(self.encoder.encode({"key": key, "message": msg}).decode() + "\n")
        self.out.flush()


# -- watching -------------------------------------------------------------------------------


@dataclass(frozen=True)
class _Received:
    key: str
    payload: bytes


def subscriptions(keys: Keys, with_position: bool) -> dict[str, type[msgspec.Struct]]:
    """The keys the watcher subscribes to and their message types (`position` only when the
    schema has a `Position` message and it is asked for)."""
    subs: dict[str, type[msgspec.Struct]] = {
        keys.status: Status, keys.event_alarm: AlarmEvent, keys.procedure: ProcedureState,
    }
    position = getattr(messages, "Position", None)
    if with_position and position is not None:
        subs[keys.position] = position
    return subs


class Watcher:
    """One observer session: subscribes, catches up on the history, then shows what arrives.

    Samples are queued by Zenoh's callbacks and decoded and printed by the caller's thread,
    in arrival order, so output needs no lock and a slow terminal never blocks Zenoh for long.
    """

    def __init__(self, session: zenoh.Session, keys: Keys, output: HumanOutput | JsonOutput,
                 with_position: bool = False) -> None:
        self.session, self.keys, self.output = session, keys, output
        self.kinds = subscriptions(keys, with_position)
        self.inbox: queue.Queue[_Received] = queue.Queue()
        self.follower = AlarmFollower(History(session, keys))
        self.subscribers = [
            session.declare_subscriber(key, lambda s, key=key: self.inbox.put(_Received(key, s.payload.to_bytes())))
            for key in self.kinds
        ]
        self._ahead_since: float | None = None  # when a status first announced entries not yet seen
        self._next_hole_retry = 0.0

    def start(self, where: str) -> None:
        """Catch up on the history; raise WatchError naming `where` when nothing answers at all."""
        try:
            entries = self.follower.catch_up()
        except NoAnswer:
            # the router is there but not the control logic's history: a status proves a controller
            status = self._first_status(ANSWER_TIMEOUT_S)
            if status is None:
                raise WatchError(f"no controller at {where}: is it running?") from None
            print(f"waterjet watch: {self.keys.alarms_history} does not answer (control logic not running?):"
                  " showing live events only", file=sys.stderr)
            entries = []
        self.output.history(self.keys.alarms_history, entries, caught_up=True)

    def _first_status(self, timeout_s: float) -> Status | None:
        deadline = time.monotonic() + timeout_s
        while (left := deadline - time.monotonic()) > 0:
            try:
                item = self.inbox.get(timeout=left)
            except queue.Empty:
                return None
            self.handle(item)
            if item.key == self.keys.status:
                return decode(item.payload, Status)
        return None

    def run(self, should_stop: Callable[[], bool]) -> None:
        """Show messages until `should_stop()`; checked at least every 0.1 s."""
        while not should_stop():
            try:
                item = self.inbox.get(timeout=0.1)
            except queue.Empty:
                continue
            self.handle(item)

    def handle(self, item: _Received) -> None:
        """Decode one sample (refusing another schema version) and show it; keep alarms in sequence."""
        try:
            msg = decode(item.payload, self.kinds[item.key])
        except msgspec.ValidationError as exc:
            raise WatchError(f"{item.key}: the controller sent a message this watcher cannot read: {exc}") from None
        except msgspec.DecodeError as exc:
            raise WatchError(f"{item.key}: the controller sent malformed JSON: {exc}") from None
        if isinstance(msg, AlarmEvent):
            for e in self.follower.accept(msg):
                if e is msg:
                    self.output.message(item.key, e)
                else:  # a missed entry, read from the history
                    self.output.history(self.keys.alarms_history, [e], caught_up=False)
            return
        self.output.message(item.key, msg)
        if isinstance(msg, Status):
            self._check_behind(msg.alarm_seq)

    def _check_behind(self, newest_seq: int) -> None:
        """A status says the history holds entries no event brought: after a grace period (the
        event may still be on its way) read them; retry unfilled gaps now and then."""
        now = time.monotonic()
        if newest_seq > self.follower.last_seq:
            if self._ahead_since is None:
                self._ahead_since = now
            elif now - self._ahead_since >= GAP_GRACE_S:
                self._ahead_since = None
                try:
                    self.output.history(self.keys.alarms_history, self.follower.catch_up(), caught_up=False)
                except NoAnswer:
                    pass  # the logic is away: the next status asks again
        else:
            self._ahead_since = None
        if self.follower.holes and now >= self._next_hole_retry:
            self._next_hole_retry = now + HOLE_RETRY_S
            self.output.history(self.keys.alarms_history, self.follower.fill_holes(), caught_up=False)

    def close(self) -> None:
        for sub in self.subscribers:
            sub.undeclare()


def open_session(
    endpoints: list[str], timeout_s: float = CONNECT_TIMEOUT_S, credentials: tuple[str, str] | None = None,
    tls: TlsFiles | None = None,
) -> zenoh.Session:
    """A client session on `endpoints`, retrying until `timeout_s`; WatchError when none accepts."""
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            return open_client(endpoints, credentials, tls)
        except zenoh.ZError:
            if time.monotonic() > deadline:
                raise WatchError(f"no controller at {', '.join(endpoints)}: is it running?") from None
            time.sleep(0.25)


# -- command line ---------------------------------------------------------------------------


def add_connection_arguments(parser: argparse.ArgumentParser) -> None:
    """How a terminal tool finds the controller (`address`): `--connect`, `--machine`, `--prefix`,
    `--credentials` (shared by `waterjet watch` and `waterjet log`)."""
    parser.add_argument("--connect", action="append", metavar="ENDPOINT",
                        help="Zenoh endpoint of the controller (repeatable; default: the machine file's [zenoh] listen)")
    parser.add_argument("--machine", "-m", default=DEFAULT_MACHINE, help=f"machine file (default {DEFAULT_MACHINE})")
    parser.add_argument("--prefix", help="key prefix (default: the machine file's [zenoh] key_prefix)")
    parser.add_argument("--credentials", metavar="FILE",
                        help="a user:password line to log in with, when the controller has accounts")
    parser.add_argument("--tls", metavar="DIR", help="for tls/ endpoints: a directory with ca.pem and the station's "
                        "certificate pair (`waterjet certs station NAME`)")
    parser.add_argument("--tls-name", default="watch", help="the station certificate's name in --tls (default watch)")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The options of `waterjet watch` (shared by `python -m cnc.watch`)."""
    add_connection_arguments(parser)
    parser.add_argument("--json", action="store_true", help="every message as one JSON object per line")
    parser.add_argument("--seconds", type=float, metavar="N", help="stop after N seconds (default: until SIGINT/SIGTERM)")


def session_for(args: argparse.Namespace, endpoints: list[str]) -> zenoh.Session:
    """The session the connection options describe (`--credentials`, `--tls`), retrying as
    `open_session` does; WatchError when an option is wrong or no controller accepts it."""
    return open_session(endpoints, credentials=_credentials(args.credentials), tls=_tls(args))


def _tls(args: argparse.Namespace) -> TlsFiles | None:
    """The station's TLS files from `--tls` and `--tls-name`, or None."""
    if not args.tls:
        return None
    try:
        return files_for(Path(args.tls), args.tls_name).check()
    except CertError as exc:
        raise WatchError(f"--tls {exc}") from None


def _credentials(path: str | None) -> tuple[str, str] | None:
    """The first user:password of the file (the station's own login), or None."""
    if not path:
        return None
    from .bus.access import station_login

    try:
        return station_login(path)
    except ValueError as exc:
        raise WatchError(f"--credentials {exc}") from None


def _machine_file(path: str) -> Path:
    """The machine file; the default one is also looked for beside the package (run from anywhere)."""
    if not Path(path).exists() and path == DEFAULT_MACHINE:
        here = Path(__file__).resolve().parent.parent / DEFAULT_MACHINE
        if here.exists():
            return here
    return Path(path)


def address(args: argparse.Namespace) -> tuple[Keys, list[str]]:
    """The machine's keys and the endpoints to reach it, from `--machine`, `--prefix` and `--connect`
    (the options `add_arguments` declares; `waterjet log` shares them). ConfigError for a bad file."""
    config = load_machine(_machine_file(args.machine))
    return (Keys(args.prefix or config.zenoh.key_prefix, config.machine.name),
            args.connect or connect_endpoints(config.zenoh.listen))


def run(args: argparse.Namespace) -> int:
    """Watch until `--seconds` pass or SIGINT/SIGTERM (exit 0); 1 when the controller cannot be watched."""
    try:
        keys, endpoints = address(args)
    except ConfigError as exc:
        print(f"waterjet watch: {exc}", file=sys.stderr)
        return 2
    output = JsonOutput(sys.stdout) if args.json else HumanOutput(sys.stdout)
    stop = {"requested": False}
    deadline = None if args.seconds is None else time.monotonic() + args.seconds

    def on_signal(_signum: int, _frame: object) -> None:
        stop["requested"] = True

    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        session = session_for(args, endpoints)
        try:
            watcher = Watcher(session, keys, output, with_position=args.json)
            try:
                watcher.start(", ".join(endpoints))
                watcher.run(lambda: stop["requested"] or (deadline is not None and time.monotonic() >= deadline))
            finally:
                watcher.close()
        finally:
            session.close()
    except SchemaVersionError as exc:
        print(f"waterjet watch: refusing the controller at {', '.join(endpoints)}: {exc}", file=sys.stderr)
        return 1
    except WatchError as exc:
        print(f"waterjet watch: {exc}", file=sys.stderr)
        return 1
    except BrokenPipeError:
        # the reader went away (`| head`): not an error; keep the interpreter's final flush quiet
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="waterjet watch", description=__doc__.splitlines()[0])
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
