"""The machine file loads into typed config, and every error names file, table, key and range."""

from __future__ import annotations

import tomllib
from pathlib import Path

import pytest

from cnc.config import ConfigError, load_machine, loads_machine, reference_toml

from .conftest import MACHINE_FILE, REPO

pytestmark = pytest.mark.computes  # pure computation: `make test` runs it beside the rest (tests/lanes.py)

MINIMAL = "[axis.x]\ntravel_min_mm = 0\ntravel_max_mm = 100\n"


def test_shipped_machine_describes_the_papers_table():
    cfg = load_machine(MACHINE_FILE)
    assert cfg.axis_names == ("x", "y")
    x, y = cfg.axis["x"], cfg.axis["y"]
    assert (x.travel_min_mm, x.travel_max_mm, y.travel_min_mm, y.travel_max_mm) == (0, 1600, 0, 1200)
    for a in (x, y):
        assert a.max_velocity_mm_s == 500 and a.max_accel_mm_s2 == 5000 and a.max_jerk_mm_s3 == 200000
        assert a.volts_per_mm_s == pytest.approx(10.0 / 1000.0)
        assert a.encoder_resolution_mm == 0.001 and a.following_error_limit_mm == 0.5
    assert cfg.timing.base_rate_hz == 1000 and cfg.timing.logic_divisor == 4
    assert cfg.board.kind == "sim" and cfg.machine.name == "waterjet"


@pytest.mark.parametrize(
    "text, expected",
    [
        (MINIMAL + "max_speed = 3\n", "m.toml: [axis.x] max_speed: unknown key (known keys:"),
        (MINIMAL + "max_velocity_mm_s = 20000\n", "m.toml: [axis.x] max_velocity_mm_s: 20000.0 is out of range: allowed 0.1 to 10000 mm/s"),
        (MINIMAL + "following_error_limit_mm = \"big\"\n", "m.toml: [axis.x] following_error_limit_mm: expected a number, got 'big' (allowed 0.001 to 100 mm)"),
        ("[axis.x]\ntravel_min_mm = 0\n", "m.toml: [axis.x] travel_max_mm: missing required key (allowed -100000 to 100000 mm)"),
        ("[timing]\nbase_rate_hz = 1000\n", "m.toml: (top level) axis: missing required table"),
        (MINIMAL + "[axis.q]\ntravel_min_mm = 0\ntravel_max_mm = 1\n", "m.toml: [axis] q: unknown axis (allowed: x, y, z)"),
        (MINIMAL + "[timing]\nwatchdog_missed_ticks = 2.5\n", "m.toml: [timing] watchdog_missed_ticks: expected an integer, got 2.5 (allowed 1 to 1000 ticks)"),
        (MINIMAL + "[timing]\nbase_rate_hz = 100\n", "m.toml: [timing] base_rate_hz: 100.0 is out of range: allowed 250 to 4000 Hz"),
        (MINIMAL + "[board]\nkind = \"pci\"\n", "m.toml: [board] kind: 'pci' is not one of: sim"),
        (MINIMAL + "[pumps]\n", "m.toml: (top level) pumps: unknown key"),
        ("[axis.x]\ntravel_min_mm = 10\ntravel_max_mm = 10\n", "m.toml: [axis.x] travel_max_mm: 10 must be greater than travel_min_mm 10"),
        (MINIMAL + "[sim.axes.y]\n", "m.toml: [sim.axes] y: no such axis declared (declared: x)"),
        (MINIMAL + "[sim.axes.x]\nfriction = 1\n", "m.toml: [sim.axes.x] friction: unknown key"),
        (MINIMAL + "[zenoh]\nlisten = \"tcp/1.2.3.4:1\"\n", "m.toml: [zenoh] listen: expected a list of strings"),
        (MINIMAL + "[machine]\nname = \"a/b\"\n", "m.toml: [machine] name: 'a/b' must be letters, digits"),
        (MINIMAL + "[timing\n", "m.toml:4:8: TOML syntax error: Expected ']'"),
        (MINIMAL + "[gateway]\nstatus_rate_hz = true\n", "m.toml: [gateway] status_rate_hz: expected a number, got True"),
        (MINIMAL + "[timing]\nbase_rate_hz = 250\n",  # the shipped fifo_low_ms 20 at a planner period of 5 x 4 ms
         "m.toml: [planner] fifo_low_ms: 20 ms must be more than twice the planner's period (5 ticks = 20 ms)"),
        (MINIMAL + "[planner]\ndivisor = 10\n", "m.toml: [planner] fifo_low_ms: 20 ms must be more than twice the planner's"),
    ],
)
def test_config_errors_name_file_table_key_and_allowed_range(text, expected):
    with pytest.raises(ConfigError) as err:
        loads_machine(text, "m.toml")
    assert str(err.value).startswith(expected), str(err.value)


def test_toml_syntax_error_names_line():
    with pytest.raises(ConfigError, match=r"^m\.toml:4:5: TOML syntax error"):
        loads_machine(MINIMAL + "x = = 2\n[timing]\n", "m.toml")


def test_missing_file_and_non_utf8_are_named(tmp_path):
    with pytest.raises(ConfigError, match=r"nope\.toml: file not found"):
        load_machine(tmp_path / "nope.toml")
    bad = tmp_path / "bad.toml"
    bad.write_bytes(b"[machine]\nname = \"\xff\"\n")
    with pytest.raises(ConfigError, match=r"bad\.toml: .*not UTF-8"):
        load_machine(bad)


def test_defaults_fill_what_the_file_leaves_out():
    cfg = loads_machine(MINIMAL)
    assert cfg.timing.watchdog_missed_ticks == 5
    assert cfg.axis["x"].encoder_resolution_mm == 0.001
    assert cfg.sim.axis("x").drive_time_constant_s == 0.003


def test_overrides_apply_and_are_validated():
    cfg = loads_machine(MINIMAL, "m.toml", {"zenoh.listen": ["tcp/127.0.0.1:9"], "timing.watchdog_missed_ticks": 3})
    assert cfg.zenoh.listen == ["tcp/127.0.0.1:9"] and cfg.timing.watchdog_missed_ticks == 3
    with pytest.raises(ConfigError, match=r"\[timing\] watchdog_missed_ticks: 0 is out of range"):
        loads_machine(MINIMAL, "m.toml", {"timing.watchdog_missed_ticks": 0})


def test_reference_file_documents_every_option_and_is_in_sync():
    committed = (REPO / "machines" / "reference.toml").read_text()
    assert committed == reference_toml(), "regenerate: python -m cnc.config > machines/reference.toml"
    parsed = tomllib.loads(committed)
    assert "axis" in parsed and "x" in parsed["axis"]
    for key in ("max_jerk_mm_s3", "following_error_limit_mm", "drive_time_constant_s", "watchdog_missed_ticks", "status_rate_hz"):
        assert f"# {key} = " in committed


def test_paths_in_the_machine_file_are_taken_from_its_directory_and_the_history_defaults_to_the_state_dir(tmp_path, monkeypatch):
    from cnc.config import beside
    from cnc.runtime.procs import program_dir
    from cnc.runtime.supervisor import default_history_path

    machine = tmp_path / "m" / "machine.toml"
    machine.parent.mkdir()
    machine.write_text(MINIMAL + '[logic]\nhistory = "var/h.sqlite"\n[gateway]\nprogram_dir = "/srv/nc"\n')
    cfg = load_machine(machine)
    assert default_history_path(cfg) == str(tmp_path / "m" / "var" / "h.sqlite")
    assert program_dir(cfg, default_history_path(cfg)) == "/srv/nc"
    assert beside(cfg, "/abs/x") == Path("/abs/x")
    monkeypatch.setenv("XDG_STATE_HOME", str(tmp_path / "state"))
    plain_file = machine.with_name("plain.toml")
    plain_file.write_text(MINIMAL)
    plain = load_machine(plain_file)
    assert default_history_path(plain) == str(tmp_path / "state" / "waterjet" / plain.machine.name / "history.sqlite")
    assert program_dir(plain, default_history_path(plain)) == str(tmp_path / "state" / "waterjet" / plain.machine.name / "programs")


def _shipped_with(replace: tuple[str, str] | None = None, drop_alarm: str | None = None) -> str:
    text = MACHINE_FILE.read_text()
    if replace:
        assert replace[0] in text
        text = text.replace(*replace)
    if drop_alarm:
        blocks = text.split("[[alarm]]\n")
        text = "[[alarm]]\n".join(b for b in blocks if f'id = "{drop_alarm}"\n' not in b)
    return text


def test_a_safety_alarm_may_be_reworded_or_made_graver_but_never_demoted():
    doors = 'id = "doors_open"\nlevel = "error"\ntext = "Safety door open"'
    reworded = loads_machine(_shipped_with((doors, 'id = "doors_open"\nlevel = "fatal"\ntext = "Door open"')), "m.toml")
    entry = next(a for a in reworded.alarm if a.id == "doors_open")
    assert (entry.level, entry.text) == ("fatal", "Door open")
    with pytest.raises(ConfigError, match=r"m\.toml: \[\[alarm\]\] #\d+ \(doors_open\) level: 'warning' is below 'error'"):
        loads_machine(_shipped_with((doors, 'id = "doors_open"\nlevel = "warning"\ntext = "Safety door open"')), "m.toml")


@pytest.mark.parametrize("alarm_id", ["x_drive", "barrier_interrupted", "operator_lost", "press_button", "mains_off"])
def test_a_catalogue_without_an_alarm_the_controller_raises_is_refused_naming_it(alarm_id):
    with pytest.raises(ConfigError, match=rf"m\.toml: \[\[alarm\]\] id: the catalogue lacks alarms the controller raises: "
                                          rf"{alarm_id}"):
        loads_machine(_shipped_with(drop_alarm=alarm_id), "m.toml")


def test_every_servo_fault_and_stop_cut_cause_has_its_alarm_in_the_shipped_catalogue():
    from cnc.interlock import CAUSE_FAULTS, StopCause
    from cnc.data.layout import ServoFault
    from cnc.safety import fault_alarm, minimum_levels

    config = load_machine(MACHINE_FILE)
    ids = {a.id: a.level for a in config.alarm}
    for fault in ServoFault:
        if fault == ServoFault.NONE:
            continue
        for axis in range(len(config.axis_names)):
            alarm = fault_alarm(fault, config.axis_names, axis)
            assert alarm in ids and ids[alarm] in ("error", "fatal"), (fault, alarm)
    assert {cause for cause, _ in CAUSE_FAULTS} == set(StopCause)
    assert set(minimum_levels(config.axis_names)) <= set(ids)
