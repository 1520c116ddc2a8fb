"""The run plots (paper Figs. 10-12): one PNG of the expected size, long runs, input checks."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from cnc.logger.plots import DPI, FIGSIZE_IN, min_max_envelope, plot_run

pytestmark = pytest.mark.computes  # pure computation: `make test` runs it beside the rest (tests/lanes.py)

CYCLE_S = 1e-3
EXPECTED_PX = (round(FIGSIZE_IN[0] * DPI), round(FIGSIZE_IN[1] * DPI))  # width, height


@pytest.fixture
def needs_matplotlib():
    return pytest.importorskip("matplotlib", reason="plotting needs matplotlib, which is not installed")


def circle_run(n: int, radius_mm: float = 50.0, speed_mm_s: float = 200.0, lag_ticks: int = 3) -> dict:
    """A circle at constant speed; the axis follows its setpoint lag_ticks late (a velocity lag)."""
    t = np.arange(n) * CYCLE_S
    phase = speed_mm_s / radius_mm * t
    commanded = np.stack([400 + radius_mm * np.cos(phase), 150 + radius_mm * np.sin(phase)], axis=1)
    velocity = speed_mm_s * np.stack([-np.sin(phase), np.cos(phase)], axis=1)
    actual = np.concatenate([np.repeat(commanded[:1], lag_ticks, axis=0), commanded[:-lag_ticks]])
    volts = velocity * (10.0 / 500.0) + 20.0 * (commanded - actual)
    return dict(t_s=t, commanded_mm=commanded, actual_mm=actual, velocity_mm_s=velocity, speed_command_v=volts)


def png_size(path) -> tuple[int, int]:
    head = path.read_bytes()[:24]
    assert head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR"
    return struct.unpack(">II", head[16:24])


def test_a_run_draws_figs_10_to_12_into_one_png_of_the_figure_size(needs_matplotlib, tmp_path):
    import matplotlib.image

    run = circle_run(4000)
    angle = np.linspace(0, 2 * np.pi, 721)
    programmed = np.stack([400 + 50 * np.cos(angle), 150 + 50 * np.sin(angle)], axis=1)
    out = tmp_path / "not" / "yet" / "there" / "run.png"

    plot_run(out, programmed_xy=programmed, title="circle R50 at 200 mm/s", **run)

    assert png_size(out) == EXPECTED_PX
    pixels = matplotlib.image.imread(out)
    assert pixels.shape[:2] == EXPECTED_PX[::-1]
    assert pixels[..., :3].std() > 0.05  # something was drawn, not a blank canvas


def test_a_million_tick_run_with_three_axes_plots_to_completion(needs_matplotlib, tmp_path):
    run = circle_run(1_000_000)
    for key in ("commanded_mm", "actual_mm", "velocity_mm_s", "speed_command_v"):
        run[key] = np.concatenate([run[key], np.zeros((1_000_000, 1))], axis=1)  # a Z column, not plotted
    out = tmp_path / "long.png"

    plot_run(out, axis_names=("x", "y", "z"), **run)

    assert png_size(out) == EXPECTED_PX


def test_plotting_leaves_the_callers_pyplot_backend_and_figures_alone(needs_matplotlib, tmp_path):
    import matplotlib.pyplot as plt

    before = plt.get_backend()
    plt.switch_backend("svg")  # a caller's backend other than Agg
    try:
        theirs = plt.figure()
        plot_run(tmp_path / "run.png", **circle_run(500))
        assert plt.get_backend() == "svg" and plt.fignum_exists(theirs.number)
    finally:
        plt.close("all")
        plt.switch_backend(before)


def test_the_envelope_of_a_million_ticks_keeps_a_one_tick_error_spike_at_its_time():
    t = np.arange(1_000_000) * CYCLE_S
    error_um = np.sin(t)
    error_um[654_321] = 37.0
    error_um[123_457] = -21.0

    t_drawn, e_drawn = min_max_envelope(t, error_um, 1000)

    assert len(e_drawn) <= 2000
    assert e_drawn.max() == 37.0 and t_drawn[e_drawn.argmax()] == t[654_321]
    assert e_drawn.min() == -21.0 and t_drawn[e_drawn.argmin()] == t[123_457]
    assert np.all(np.diff(t_drawn) >= 0)


@pytest.mark.parametrize("argument", ["commanded_mm", "actual_mm", "velocity_mm_s", "speed_command_v"])
def test_a_series_of_the_wrong_length_is_refused_naming_it_and_its_shape(argument, tmp_path):
    run = circle_run(100)
    run[argument] = run[argument][:99]

    with pytest.raises(ValueError, match=rf"{argument}.*\(99, 2\)"):
        plot_run(tmp_path / "bad.png", **run)
    assert not (tmp_path / "bad.png").exists()


def test_a_series_with_other_axes_than_the_setpoints_is_refused_naming_both_shapes(tmp_path):
    run = circle_run(100)
    run["speed_command_v"] = np.zeros((100, 3))

    with pytest.raises(ValueError, match=r"speed_command_v.*\(100, 3\).*commanded_mm.*\(100, 2\)"):
        plot_run(tmp_path / "bad.png", **run)


def test_a_programmed_contour_that_is_not_xy_pairs_is_refused(tmp_path):
    with pytest.raises(ValueError, match=r"programmed_xy.*\(50, 3\)"):
        plot_run(tmp_path / "bad.png", programmed_xy=np.zeros((50, 3)), **circle_run(100))


def test_a_time_base_that_is_not_one_dimensional_is_refused(tmp_path):
    run = circle_run(100)
    run["t_s"] = run["t_s"].reshape(100, 1)

    with pytest.raises(ValueError, match=r"t_s.*\(100, 1\)"):
        plot_run(tmp_path / "bad.png", **run)
