"""`waterjet router`: a shop router in its own process relays between stations and controllers."""

from __future__ import annotations

import signal
import subprocess
import sys
import threading
from pathlib import Path

import pytest
import zenoh

from cnc.bus.keys import Keys
from cnc.bus.access import open_machine_router, plan_access, run_dir
from cnc.bus.session import open_client, open_router, zenoh_config
from cnc.config import load_machine

from .conftest import MACHINE_FILE, REPO, free_port
from .test_access_control import PASSWORDS, accounts_file, put_until_received, reached, replies


class ShopRouter:
    """`python -m cnc.router ...` in a subprocess, started when it has printed where it listens."""

    def __init__(self, *args: str) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "cnc.router", *args], cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )
        self.banner = self.proc.stdout.readline()  # blocks until the router is open (or has failed)
        if " listening on " not in self.banner:
            self.proc.kill()
            raise AssertionError(f"router did not start: {self.banner!r} {self.proc.stderr.read()!r}")

    def stop(self) -> tuple[int, str]:
        """SIGTERM, as a service manager would; the exit code and the rest of its output."""
        self.proc.send_signal(signal.SIGTERM)
        out, _err = self.proc.communicate(timeout=10)
        return self.proc.returncode, out


@pytest.fixture
def sessions():
    opened: list[zenoh.Session] = []
    yield opened
    for s in reversed(opened):
        s.close()


def test_router_relays_between_clients_on_different_endpoints_and_stops_on_sigterm(sessions):
    a, b = f"tcp/127.0.0.1:{free_port()}", f"tcp/127.0.0.1:{free_port()}"
    router = ShopRouter("--listen", a, "--listen", b)
    try:
        assert a in router.banner and b in router.banner and "no access control" in router.banner
        publisher, subscriber = open_client([a]), open_client([b])
        sessions += [publisher, subscriber]
        got: list[str] = []
        received = threading.Event()
        _sub = subscriber.declare_subscriber("wj/shop/status", lambda s: (got.append(s.payload.to_string()), received.set()))
        assert put_until_received(lambda: publisher.put("wj/shop/status", "idle"), received)
        assert got[0] == "idle"
    finally:
        code, out = router.stop()
    assert code == 0 and "stopped" in out


def test_controller_router_connected_to_the_shop_router_reaches_its_stations(sessions):
    shop_ep, controller_ep = f"tcp/127.0.0.1:{free_port()}", f"tcp/127.0.0.1:{free_port()}"
    router = ShopRouter("--listen", shop_ep)
    try:
        controller = open_router([controller_ep], connect=[shop_ep])
        station = open_client([shop_ep])
        sessions += [controller, station]
        _cmd = controller.declare_queryable("wj/m1/cmd/**", lambda q: q.reply(q.key_expr, "ok"))
        received = threading.Event()
        _sub = station.declare_subscriber("wj/m1/status", lambda s: received.set())
        assert put_until_received(lambda: controller.put("wj/m1/status", "{}"), received)
        reached(controller, station, Keys("wj", "m1"))
        assert replies(station, "wj/m1/cmd/start") == ["ok"]
    finally:
        assert router.stop()[0] == 0


def shop_machine(tmp_path: Path) -> Path:
    """The shipped machine with accounts, written where the shop router can read it."""
    accounts_file(tmp_path).rename(tmp_path / "machine.users")  # beside the machine file: its default place
    path = tmp_path / "machine.toml"
    path.write_text(MACHINE_FILE.read_text(encoding="utf-8"), encoding="utf-8")
    return path


def test_a_shop_router_refuses_a_machine_without_accounts(tmp_path):
    path = tmp_path / "machine.toml"
    path.write_text(MACHINE_FILE.read_text(encoding="utf-8"), encoding="utf-8")
    proc = subprocess.run([sys.executable, "-m", "cnc.router", "--listen", f"tcp/127.0.0.1:{free_port()}",
                           "--machine", str(path)], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and "has no accounts" in proc.stderr and "waterjet users add" in proc.stderr


def test_shop_router_with_a_machine_logs_stations_in_and_applies_its_rules(tmp_path, sessions):
    machine = shop_machine(tmp_path)
    shop_ep, controller_ep = f"tcp/127.0.0.1:{free_port()}", f"tcp/127.0.0.1:{free_port()}"
    router = ShopRouter("--listen", shop_ep, "--machine", str(machine))
    socket = run_dir() / f"test-shop-{free_port()}.sock"
    try:
        assert "access control of machine" in router.banner
        cfg = load_machine(machine, {"zenoh.listen": [controller_ep], "zenoh.connect": [shop_ep]})
        keys = Keys(cfg.zenoh.key_prefix, cfg.machine.name)
        plan = plan_access(cfg, socket)
        controller = open_machine_router(cfg, plan)  # logs in to the shop router as the controller
        sessions.append(controller)
        seen: list[str] = []
        _cmd = controller.declare_queryable(
            f"{keys.root}/u/*/cmd/**", lambda q: (seen.append(str(q.key_expr)), q.reply(q.key_expr, "ok"))
        )
        _internal = controller.declare_queryable(keys.logic("drives"), lambda q: q.reply(q.key_expr, "internal"))

        with pytest.raises(zenoh.ZError):
            sessions.append(zenoh.open(zenoh_config("client", connect=[shop_ep])))
        observer = open_client([shop_ep], ("observer1", PASSWORDS["observer1"]))
        operator = open_client([shop_ep], ("operator1", PASSWORDS["operator1"]))
        sessions += [observer, operator]
        received = threading.Event()
        _sub = observer.declare_subscriber(keys.status, lambda s: received.set())
        assert put_until_received(lambda: controller.put(keys.status, "{}"), received)
        reached(controller, observer, keys)
        assert replies(observer, keys.cmd("start", "observer1")) == []
        assert replies(operator, keys.cmd("start", "observer1")) == []
        assert replies(operator, keys.cmd("hold", "operator1")) == ["ok"]
        assert replies(operator, keys.logic("drives")) == []
        assert seen == [keys.cmd("hold", "operator1")]
    finally:
        socket.unlink(missing_ok=True)
        assert router.stop()[0] == 0
