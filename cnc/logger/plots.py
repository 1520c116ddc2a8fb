"""Plots of a position-control run as in the paper's Figs. 10-12: XY contour and per-axis tracking.

Fig. 10 is the XY test contour (desired dotted, actual solid); Figs. 11 and 12 are, for the
X and Y axes, the reference speed, the position tracking error and the control output (the
speed command in volts to the servo drive) against time. `plot_run` draws all three into one
PNG. Runs of 10^6 servo ticks are decimated before drawing: time series to a min/max
envelope per pixel column, so a one-tick error spike stays visible; XY paths to one point per
small grid cell visited, so every excursion larger than a fraction of a pixel stays drawn.

matplotlib is imported inside `plot_run` and draws with its non-interactive Agg canvas, so
importing this module costs nothing on a controller that never plots.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

FIGSIZE_IN = (12.0, 10.0)
DPI = 110
ENVELOPE_COLUMNS = 1000  # min/max bins per time plot: more than its width in pixels
XY_CELLS = 2000  # grid cells across the XY plot's larger extent: a few per pixel
UM_PER_MM = 1000.0


def plot_run(
    out_png: str | Path,
    *,
    t_s: np.ndarray,
    commanded_mm: np.ndarray,
    actual_mm: np.ndarray,
    velocity_mm_s: np.ndarray,
    speed_command_v: np.ndarray,
    programmed_xy: np.ndarray | None = None,
    axis_names: tuple[str, ...] = ("x", "y"),
    title: str = "",
) -> None:
    """Draw Figs. 10-12 of one run into `out_png` (FIGSIZE_IN at DPI); creates its directory.

    t_s is (n,); commanded_mm, actual_mm, velocity_mm_s and speed_command_v are (n, k) with
    k >= 2, columns in `axis_names` order; only the first two axes are plotted.
    programmed_xy, (m, 2) samples of the programmed contour, is the desired curve of Fig. 10;
    without it the setpoints are. Raises ValueError, naming the argument and the shapes,
    when the inputs do not fit together.
    """
    series = _validated(t_s, commanded_mm, actual_mm, velocity_mm_s, speed_command_v, axis_names)
    desired_xy = _validated_contour(programmed_xy) if programmed_xy is not None else series["commanded_mm"][:, :2]

    # Agg, attached to this figure only: works headless (controller, CI) and, unlike
    # matplotlib.use("Agg"), does not switch or close the figures of a caller's pyplot session.
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=FIGSIZE_IN, dpi=DPI)
    FigureCanvasAgg(fig)
    outer = fig.add_gridspec(1, 2, wspace=0.22, left=0.07, right=0.97, top=0.93, bottom=0.06)
    _draw_contour(fig.add_subplot(outer[0, 0]), desired_xy, series["actual_mm"][:, :2])
    right = outer[0, 1].subgridspec(2, 1, hspace=0.28)
    for i, fig_no in enumerate((11, 12)):
        _draw_axis_panel(fig, right[i, 0], fig_no, axis_names[i], i, series)
    if title:
        fig.suptitle(title, fontsize=13)
    out = Path(out_png)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=DPI)


def _validated(t_s, commanded_mm, actual_mm, velocity_mm_s, speed_command_v, axis_names) -> dict[str, np.ndarray]:
    t = np.asarray(t_s, dtype=float)
    if t.ndim != 1 or t.shape[0] < 2:
        raise ValueError(f"t_s must have shape (n,) with n >= 2, got {t.shape}")
    named = {
        "commanded_mm": commanded_mm,
        "actual_mm": actual_mm,
        "velocity_mm_s": velocity_mm_s,
        "speed_command_v": speed_command_v,
    }
    out = {"t_s": t}
    for name, value in named.items():
        a = np.asarray(value, dtype=float)
        if a.ndim != 2 or a.shape[0] != t.shape[0] or a.shape[1] < 2:
            raise ValueError(f"{name} must have shape (n, k) with n = {t.shape[0]} (from t_s) and k >= 2, got {a.shape}")
        out[name] = a
    k = out["commanded_mm"].shape[1]
    for name in named:
        if out[name].shape[1] != k:
            raise ValueError(f"{name} has shape {out[name].shape}, commanded_mm has {out['commanded_mm'].shape}")
    if len(axis_names) < 2:
        raise ValueError(f"axis_names must name at least the two plotted axes, got {tuple(axis_names)!r}")
    return out


def _validated_contour(programmed_xy) -> np.ndarray:
    p = np.asarray(programmed_xy, dtype=float)
    if p.ndim != 2 or p.shape[1] != 2 or p.shape[0] < 2:
        raise ValueError(f"programmed_xy must have shape (m, 2) with m >= 2, got {p.shape}")
    return p


def _draw_contour(ax, desired_xy: np.ndarray, actual_xy: np.ndarray) -> None:
    both = np.concatenate([desired_xy, actual_xy])
    cell_mm = float(np.ptp(both, axis=0).max()) / XY_CELLS
    ax.plot(*thin_path(desired_xy, cell_mm).T, ":", color="tab:blue", lw=1.6, label="desired")
    ax.plot(*thin_path(actual_xy, cell_mm).T, "-", color="tab:red", lw=0.9, label="actual")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel("X [mm]")
    ax.set_ylabel("Y [mm]")
    ax.set_title("Fig. 10: XY test contour")
    ax.grid(True, lw=0.4, alpha=0.5)
    ax.legend(loc="upper right")


def _draw_axis_panel(fig, cell, fig_no: int, axis_name: str, i: int, series: dict[str, np.ndarray]) -> None:
    t = series["t_s"]
    error_um = (series["commanded_mm"][:, i] - series["actual_mm"][:, i]) * UM_PER_MM
    rows = (
        (series["velocity_mm_s"][:, i], "ref. speed\n[mm/s]", "tab:blue"),
        (error_um, "position\nerror [um]", "tab:red"),
        (series["speed_command_v"][:, i], "control\noutput [V]", "tab:green"),
    )
    grid = cell.subgridspec(3, 1, hspace=0.08)
    first = None
    for row, (y, label, color) in enumerate(rows):
        ax = fig.add_subplot(grid[row, 0], sharex=first)
        if first is None:
            first = ax
        ax.plot(*min_max_envelope(t, y, ENVELOPE_COLUMNS), color=color, lw=0.8)
        ax.set_ylabel(label, fontsize=9)
        ax.grid(True, lw=0.4, alpha=0.5)
        ax.tick_params(labelsize=8)
        if row < 2:
            ax.tick_params(labelbottom=False)
    first.set_title(f"Fig. {fig_no}: {axis_name.upper()}-axis tracking error")
    first.set_xlim(t[0], t[-1])
    ax.set_xlabel("time [s]")


def min_max_envelope(t: np.ndarray, y: np.ndarray, columns: int) -> tuple[np.ndarray, np.ndarray]:
    """Thin (t, y) to at most 2 * columns samples: each bin's minimum and maximum, in time order.

    Bins hold equal numbers of samples (ticks are evenly spaced), so a bin is a pixel column
    or less. Keeping both extremes of every bin, at their own times, draws the same envelope
    as the full series would; plain striding would drop short spikes.
    """
    n = t.shape[0]
    if n <= 2 * columns:
        return t, y
    per_bin = -(-n // columns)
    padded = np.pad(y, (0, per_bin * columns - n), mode="edge").reshape(columns, per_bin)
    base = np.arange(columns) * per_bin
    i_min = np.minimum(base + padded.argmin(axis=1), n - 1)
    i_max = np.minimum(base + padded.argmax(axis=1), n - 1)
    picks = np.stack([np.minimum(i_min, i_max), np.maximum(i_min, i_max)], axis=1).ravel()
    return t[picks], y[picks]


def thin_path(xy: np.ndarray, cell_mm: float) -> np.ndarray:
    """Drop each XY sample that lies in the same cell_mm grid cell as the one before it.

    Every cell the path passes through keeps a sample, so the drawn path strays from the full
    one by at most a cell's diagonal; a machine at rest or crawling collapses to a few points.
    """
    if xy.shape[0] <= 2 or not cell_mm > 0.0:
        return xy
    cells = np.floor((xy - xy.min(axis=0)) / cell_mm)
    keep = np.ones(xy.shape[0], dtype=bool)
    keep[1:-1] = np.any(cells[1:-1] != cells[:-2], axis=1)
    return xy[keep]


QUALITY_COLOURS = {1: "#d62728", 2: "#ff7f0e", 3: "#2ca02c", 4: "#1f77b4", 5: "#9467bd"}  # separation .. finest


def plot_speed_by_quality(
    out_png: str | Path, distance_mm: np.ndarray, speed_mm_s: np.ndarray, quality: np.ndarray, straight_mm_s: np.ndarray,
    title: str = "",
) -> None:
    """The speed along the path of a run under the cutting model (`cnc.cutmodel`): the setpoint speed
    against the distance travelled, coloured by the quality in force where the jet cuts (grey where
    it does not), with each quality's straight speed dashed above it: the slow-downs in corners, arcs
    and lead-ins are where the curve drops below its dashes. ValueError names a misfit argument."""
    d, v, q, cap = (np.asarray(a) for a in (distance_mm, speed_mm_s, quality, straight_mm_s))
    if not (d.ndim == v.ndim == q.ndim == cap.ndim == 1 and len(d) == len(v) == len(q) == len(cap) and len(d) >= 2):
        raise ValueError(f"distance_mm, speed_mm_s, quality and straight_mm_s must be (n,) alike with n >= 2, got "
                         f"{d.shape}, {v.shape}, {q.shape}, {cap.shape}")
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(FIGSIZE_IN[0], FIGSIZE_IN[1] * 0.6), dpi=DPI)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot(1, 1, 1)
    ax.plot(d, v * 60.0, color="0.75", lw=0.8, label="jet off / rapid")
    for level, colour in QUALITY_COLOURS.items():
        at = q == level
        if not at.any():
            continue
        ax.plot(d, np.where(at, v * 60.0, np.nan), color=colour, lw=1.2, label=f"quality {level}")
        ax.plot(d, np.where(at, cap * 60.0, np.nan), color=colour, lw=0.8, ls="--")
    ax.set_xlabel("distance along the path (mm)")
    ax.set_ylabel("speed (mm/min)")
    top = float(np.nanmax(np.where(q > 0, np.maximum(v, cap), 0.0))) * 60.0
    if top > 0.0:
        ax.set_ylim(0.0, top * 1.25)
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper right", fontsize=8, ncol=3)
    if title:
        ax.set_title(title, fontsize=11)
    out = Path(out_png)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(out, dpi=DPI)
