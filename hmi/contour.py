"""The operator screen's contour field: the loaded program's path, cut progress, live head and travel limits."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pyqtgraph as pg
from PySide6.QtCore import Qt
from PySide6.QtGui import QColor, QPainterPath, QPen
from PySide6.QtWidgets import QGraphicsItem, QGraphicsPathItem, QGraphicsRectItem, QVBoxLayout, QWidget

from cnc.bus.messages import ProgramPath

RAPID, LINE, ARC = 0, 1, 2  # gcode.canon's numbering, repeated here because hmi reaches cnc only via cnc.bus

CHUNK_POINTS = 4096  # feed-path points per pre-built path item: bounds a progress update and lets Qt cull off-view chunks
MAX_ARC_STEPS = 1024  # a display cap: a huge radius must not explode the vertex count
CONTINUITY_MM = 1e-6  # a feed move starting this close to the previous end continues the same polyline
HEAD_CROSS_PX = 12.0  # half-length of the head cross arms, in screen pixels

CUT, CURRENT, TO_CUT, RAPIDS, TRAVEL, HEAD = "cut", "current", "to_cut", "rapid", "travel", "head"


def _pen(color: str, width: float = 1.0, style: Qt.PenStyle = Qt.PenStyle.SolidLine) -> QPen:
    """A cosmetic pen: its width is in screen pixels whatever the zoom, and Qt strokes it on the fast path."""
    pen = QPen(QColor(color))
    pen.setWidthF(width)
    pen.setStyle(style)
    pen.setCosmetic(True)
    return pen




def _pens() -> dict[str, QPen]:
    """The styles per category. Rapids are faint and thin rather than dashed: a dashed cosmetic pen
    costs Qt a dash pattern per stroke, a third of the frame on a nesting program."""
    return {
        CUT: _pen("#4caf50"), CURRENT: _pen("#ffb000", 3.0), TO_CUT: _pen("#e8f4ff"),
        RAPIDS: _pen("#4a5866"), TRAVEL: _pen("#c04040", 1.0, Qt.PenStyle.DashLine),
        HEAD: _pen("#ff40ff", 2.0),
    }


@dataclass(frozen=True)
class FeedPolyline:
    """Every cutting move (lines and tessellated arcs) as one NaN-broken polyline, in program order.

    Segment k's vertices are `x[first[k] : last[k] + 1]`; consecutive continuous moves share their
    joint vertex, so `first[k] == last[k - 1]`. A rapid owns no vertex: `first` points just past the
    vertices before it and `last` at the last of them, so slicing by segment index always works."""

    x: np.ndarray
    y: np.ndarray
    first: np.ndarray
    last: np.ndarray


def arc_steps(radius_mm: np.ndarray, sweep_rad: np.ndarray, tolerance_mm: float) -> np.ndarray:
    """Chords per arc so the sagitta (chord-to-arc distance) stays within `tolerance_mm`.

    A chord spanning angle a deviates from the arc by r (1 - cos(a / 2)); solving for a gives the
    largest step 2 acos(1 - tol / r)."""
    ratio = np.clip(1.0 - tolerance_mm / np.maximum(radius_mm, 1e-12), -1.0, 1.0)
    step = 2.0 * np.arccos(ratio)
    with np.errstate(divide="ignore", invalid="ignore"):
        n = np.ceil(np.abs(sweep_rad) / np.where(step > 0, step, np.inf))
    return np.clip(np.nan_to_num(n, nan=1.0), 1, MAX_ARC_STEPS).astype(np.int64)


def tessellate_arcs(
    start: np.ndarray, end: np.ndarray, center: np.ndarray, cw: np.ndarray, tolerance_mm: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Arcs (rows of (x, y) start, end, centre) as polylines: (x, y, count) with `count[j]` vertices for arc j.

    An arc that ends where it starts is a full circle, as in G-code. The first and last vertices are
    the exact start and end, so arcs join their neighbours without a gap."""
    r = np.hypot(*(start - center).T)
    a0 = np.arctan2(start[:, 1] - center[:, 1], start[:, 0] - center[:, 0])
    a1 = np.arctan2(end[:, 1] - center[:, 1], end[:, 0] - center[:, 0])
    ccw_sweep = np.mod(a1 - a0, 2 * np.pi)
    ccw_sweep = np.where(ccw_sweep < 1e-9, 2 * np.pi, ccw_sweep)
    cw_sweep = np.mod(a0 - a1, 2 * np.pi)
    cw_sweep = np.where(cw_sweep < 1e-9, 2 * np.pi, cw_sweep)
    sweep = np.where(cw, -cw_sweep, ccw_sweep)
    steps = arc_steps(r, sweep, tolerance_mm)
    count = steps + 1
    arc_of = np.repeat(np.arange(len(r)), count)
    begins = np.cumsum(count) - count
    k = np.arange(int(count.sum())) - np.repeat(begins, count)
    theta = a0[arc_of] + sweep[arc_of] * (k / steps[arc_of])
    x = center[arc_of, 0] + r[arc_of] * np.cos(theta)
    y = center[arc_of, 1] + r[arc_of] * np.sin(theta)
    ends = begins + steps
    x[begins], y[begins] = start[:, 0], start[:, 1]
    x[ends], y[ends] = end[:, 0], end[:, 1]
    return x, y, count


def feed_polyline(path: ProgramPath, tolerance_mm: float) -> FeedPolyline:
    """Lay every line and arc of `path` into one NaN-broken polyline, vectorised (see `FeedPolyline`).

    Each feed move gets a slot block: one leading slot (NaN, a pen-up) then its vertices. A move that
    continues the previous one drops its leading NaN and its start vertex (the shared joint)."""
    kind = np.asarray(path.kind, dtype=np.int64)
    start = np.column_stack([np.asarray(path.start_x, float), np.asarray(path.start_y, float)]).reshape(-1, 2)
    end = np.column_stack([np.asarray(path.end_x, float), np.asarray(path.end_y, float)]).reshape(-1, 2)
    feed = kind != RAPID
    arcs = np.flatnonzero(kind == ARC)
    ax, ay, acount = tessellate_arcs(
        start[arcs], end[arcs],
        np.column_stack([np.asarray(path.center_x, float), np.asarray(path.center_y, float)]).reshape(-1, 2)[arcs],
        np.asarray(path.cw, dtype=bool)[arcs], tolerance_mm,
    )
    vertices = np.where(feed, 2, 0)
    vertices[arcs] = acount
    slots = np.where(feed, vertices + 1, 0)
    begin = np.cumsum(slots) - slots
    xs = np.full(int(slots.sum()), np.nan)
    ys = np.full_like(xs, np.nan)
    lines = np.flatnonzero(kind == LINE)
    xs[begin[lines] + 1], ys[begin[lines] + 1] = start[lines, 0], start[lines, 1]
    xs[begin[lines] + 2], ys[begin[lines] + 2] = end[lines, 0], end[lines, 1]
    at = np.repeat(begin[arcs] + 1, acount) + (np.arange(len(ax)) - np.repeat(np.cumsum(acount) - acount, acount))
    xs[at], ys[at] = ax, ay

    continues = np.zeros(len(kind), dtype=bool)
    if len(kind) > 1:
        gap = np.hypot(*(start[1:] - end[:-1]).T)
        continues[1:] = feed[1:] & feed[:-1] & (gap <= CONTINUITY_MM)
    keep = np.ones(len(xs), dtype=bool)
    keep[begin[continues]] = False
    keep[begin[continues] + 1] = False
    emitted = np.where(continues, vertices - 1, slots)
    cum_end = np.cumsum(emitted)
    last = cum_end - 1
    first = np.where(feed, cum_end - vertices, cum_end)
    return FeedPolyline(xs[keep], ys[keep], first, last)


class _PathItem(QGraphicsPathItem):
    """A path item that never takes part in mouse hit-testing: Qt would otherwise stroke the whole
    path to build its shape on every press, and the view's pan/zoom needs no item picking."""

    def __init__(self, pen: QPen, z: float) -> None:
        super().__init__()
        self.setPen(pen)
        self.setZValue(z)
        self.setAcceptedMouseButtons(Qt.MouseButton.NoButton)

    def shape(self) -> QPainterPath:  # noqa: D102 - see class docstring
        return QPainterPath()


def _qpath(x: np.ndarray, y: np.ndarray, connect: str = "finite") -> QPainterPath:
    return pg.arrayToQPath(x, y, connect=connect) if len(x) else QPainterPath()


class _FeedLayer:
    """One tessellation of the feed path, drawn as fixed-size chunks of pre-built paths.

    A progress update re-styles whole chunks (a pen change, no path rebuild) and rebuilds only the
    cut / to-cut partial paths of the chunks the split runs through, so its cost is bounded by
    `CHUNK_POINTS` whatever the program's size; chunks off screen are culled by Qt."""

    def __init__(self, feed: FeedPolyline, pens: dict[str, QPen], add) -> None:  # noqa: ANN001 - the view's adder
        self.feed, self._pens = feed, pens
        n = len(feed.x)
        starts = np.arange(0, max(n - 1, 1), CHUNK_POINTS) if n else np.zeros(0, np.int64)
        self.span = np.column_stack([starts, np.minimum(starts + CHUNK_POINTS, n - 1)]).reshape(-1, 2)
        self.chunks = [add(_PathItem(pens[TO_CUT], 2)) for _ in self.span]
        for item, (lo, hi) in zip(self.chunks, self.span):
            item.setPath(_qpath(feed.x[lo:hi + 1], feed.y[lo:hi + 1]))
        self.style: list[str | None] = [TO_CUT] * len(self.chunks)
        self.cut_part = add(_PathItem(pens[CUT], 2))
        self.todo_part = add(_PathItem(pens[TO_CUT], 2))
        self.items = [*self.chunks, self.cut_part, self.todo_part]
        self.visible = True

    def split(self, i: int) -> tuple[int, int]:
        """Vertices [0, a) are cut and [b, n) are to cut when segment i is being cut (-1: none yet)."""
        if i < 0:
            return 0, 0
        f, segments = self.feed, len(self.feed.first)
        cut_end = int(f.last[i - 1]) + 1 if i > 0 else 0
        todo_begin = int(f.first[i + 1]) if i + 1 < segments else len(f.x)
        return cut_end, todo_begin

    def set_progress(self, i: int) -> None:
        """Re-style the chunks for segment i being cut (see the class docstring)."""
        cut_end, todo_begin = self.split(i)
        lo, hi = self.span[:, 0], self.span[:, 1]
        styles = np.where(hi < cut_end, 0, np.where(lo >= todo_begin, 1, 2))  # 2: the split runs through it
        for c, code in enumerate(styles.tolist()):
            self._style_chunk(c, (CUT, TO_CUT, None)[code])
        split = np.flatnonzero(styles == 2)
        f = self.feed
        if len(split):
            first, last = self.span[split[0], 0], self.span[split[-1], 1]
            self.cut_part.setPath(_qpath(f.x[first:cut_end], f.y[first:cut_end]))
            self.todo_part.setPath(_qpath(f.x[todo_begin:last + 1], f.y[todo_begin:last + 1]))
        else:
            self.cut_part.setPath(QPainterPath())
            self.todo_part.setPath(QPainterPath())

    def _style_chunk(self, c: int, style: str | None) -> None:
        """Give chunk c a pen, or hide it (None) when the split runs through it."""
        if style == self.style[c]:
            return
        self.style[c] = style
        self.chunks[c].setVisible(self.visible and style is not None)
        if style is not None:
            self.chunks[c].setPen(self._pens[style])

    def set_visible(self, visible: bool) -> None:
        """Show or hide the whole layer (hidden chunks keep their style for when it comes back)."""
        self.visible = visible
        for item, style in zip(self.chunks, self.style):
            item.setVisible(visible and style is not None)
        self.cut_part.setVisible(visible)
        self.todo_part.setVisible(visible)


class ContourView(QWidget):
    """The whole program's contour with cut / being cut / to cut styled apart, rapids faint, the
    head as a live cross and the travel limits as a rectangle; wheel zooms, drag pans, `fit()` (or a
    double click) frames the program, at an equal aspect ratio (mm are mm).

    The feed path is tessellated twice per program: at `tolerance_mm` for close-ups and at
    `overview_tolerance_mm` for views where a pixel is larger than that, where the fine arcs would only
    cost frame time. The overview swaps in while a pixel covers at least that many mm."""

    def __init__(
        self,
        path: ProgramPath | None = None,
        travel_mm: tuple[float, float, float, float] | None = None,
        tolerance_mm: float = 0.01,
        overview_tolerance_mm: float = 0.5,
        parent: QWidget | None = None,
    ) -> None:
        super().__init__(parent)
        self.tolerance_mm = tolerance_mm
        self.overview_tolerance_mm = overview_tolerance_mm
        self._pens = _pens()
        self.plot = pg.PlotWidget(background="#101418")
        self.plot.setAspectLocked(True, ratio=1.0)
        self.plot.hideButtons()
        self.plot.setMenuEnabled(False)
        self.plot.disableAutoRange()
        # No axes: the travel rectangle gives the scale, and the whole frame budget goes to the contour.
        self.plot.hideAxis("bottom")
        self.plot.hideAxis("left")
        self.plot.scene().sigMouseClicked.connect(self._on_click)
        layout = QVBoxLayout(self)
        layout.setContentsMargins(0, 0, 0, 0)
        layout.addWidget(self.plot)
        self._view = self.plot.getViewBox()
        self._view.sigRangeChanged.connect(self._choose_layer)
        self._view.sigResized.connect(self._choose_layer)

        self._rapids = self._add(_PathItem(self._pens[RAPIDS], 1))
        self._current = self._add(_PathItem(self._pens[CURRENT], 3))
        self._travel = self._add(QGraphicsRectItem())
        self._travel.setPen(self._pens[TRAVEL])
        self._travel.setVisible(False)
        self._head = self._add(_PathItem(self._pens[HEAD], 4))
        cross = QPainterPath()
        cross.moveTo(-HEAD_CROSS_PX, 0)
        cross.lineTo(HEAD_CROSS_PX, 0)
        cross.moveTo(0, -HEAD_CROSS_PX)
        cross.lineTo(0, HEAD_CROSS_PX)
        self._head.setPath(cross)
        self._head.setFlag(QGraphicsItem.GraphicsItemFlag.ItemIgnoresTransformations)
        self._head.setVisible(False)

        self._fine: _FeedLayer | None = None
        self._overview: _FeedLayer | None = None
        self._kind = np.empty(0, dtype=np.int64)
        self._rapid_xy = np.empty((0, 4))
        self._rapid_index = np.empty(0, dtype=np.int64)
        self._progress = 0
        if travel_mm is not None:
            self.set_travel(*travel_mm)
        if path is not None:
            self.set_path(path)

    def _add(self, item: QGraphicsItem) -> QGraphicsItem:
        self._view.addItem(item, ignoreBounds=True)
        return item

    def set_path(self, path: ProgramPath) -> None:
        """Show a new program: tessellate it, build the chunked feed paths and the rapids, and start
        with nothing cut (progress -1). The view is not moved; call `fit()` to frame it."""
        for layer in (self._fine, self._overview):
            for item in layer.items if layer else ():
                self._view.removeItem(item)
        self._kind = np.asarray(path.kind, dtype=np.int64)
        self._fine = _FeedLayer(feed_polyline(path, self.tolerance_mm), self._pens, self._add)
        self._overview = _FeedLayer(feed_polyline(path, self.overview_tolerance_mm), self._pens, self._add)
        rapids = self._rapid_index = np.flatnonzero(self._kind == RAPID)
        self._rapid_xy = np.column_stack([
            np.asarray(path.start_x, float)[rapids], np.asarray(path.start_y, float)[rapids],
            np.asarray(path.end_x, float)[rapids], np.asarray(path.end_y, float)[rapids],
        ]).reshape(-1, 4)
        # pairs: each rapid is its own start-end stroke, rapids never join each other
        self._rapids.setPath(_qpath(self._rapid_xy[:, 0::2].ravel(), self._rapid_xy[:, 1::2].ravel(), "pairs"))
        self._progress = -2
        self.set_progress(-1)
        self._choose_layer()

    def set_progress(self, segment_index: int) -> None:
        """Segments [0, i) are cut, segment i is being cut, the rest are to cut (i is clamped to the
        program; -1: the run has not reached the first segment, everything is to cut; i == number
        of segments means all cut). Only chunk pens and the partial chunks around the split
        change: the tessellation is reused."""
        i = int(min(max(segment_index, -1), len(self._kind)))
        if i == self._progress or self._fine is None:
            return
        self._progress = i
        self._fine.set_progress(i)
        self._overview.set_progress(i)
        self._current.setPath(self._segment_path(i))

    def _segment_path(self, i: int) -> QPainterPath:
        """The fine path of the segment being cut (a rapid is drawn as its straight move)."""
        if not 0 <= i < len(self._kind):
            return QPainterPath()
        if self._kind[i] == RAPID:
            sx, sy, ex, ey = self._rapid_xy[int(np.searchsorted(self._rapid_index, i))]
            return _qpath(np.array([sx, ex]), np.array([sy, ey]), "all")
        f = self._fine.feed
        lo, hi = int(f.first[i]), int(f.last[i])
        return _qpath(f.x[lo:hi + 1], f.y[lo:hi + 1])

    def _choose_layer(self, *_: object) -> None:
        """Draw the overview tessellation while a pixel spans at least its tolerance (its chords are
        then within a pixel of the true arcs), the fine one when zoomed in closer."""
        if self._fine is None:
            return
        px_w, _px_h = self._view.viewPixelSize()
        overview = px_w >= self.overview_tolerance_mm
        if overview != self._overview.visible or overview == self._fine.visible:
            self._overview.set_visible(overview)
            self._fine.set_visible(not overview)

    @property
    def showing_overview(self) -> bool:
        """True while the coarse overview tessellation is the one drawn."""
        return self._overview is not None and self._overview.visible

    def set_head(self, x: float, y: float) -> None:
        """Move the head cross to machine position (x, y) mm; the cross keeps its pixel size."""
        self._head.setPos(x, y)
        self._head.setVisible(True)

    def set_travel(self, xmin: float, xmax: float, ymin: float, ymax: float) -> None:
        """Draw the machine's travel limits (mm) as a rectangle."""
        self._travel.setRect(xmin, ymin, xmax - xmin, ymax - ymin)
        self._travel.setVisible(True)

    def fit(self) -> None:
        """Frame the whole program (feed and rapids); with no program, frame the travel rectangle."""
        bounds = self.path_bounds()
        if bounds is None:
            if not self._travel.isVisible():
                return
            r = self._travel.rect()
            bounds = (r.left(), r.right(), r.top(), r.bottom())
        xmin, xmax, ymin, ymax = bounds
        self._view.setRange(xRange=(xmin, xmax), yRange=(ymin, ymax), padding=0.03)

    def path_bounds(self) -> tuple[float, float, float, float] | None:
        """(xmin, xmax, ymin, ymax) mm of everything drawn for the program, or None with no program."""
        if self._fine is None:
            return None
        f = self._fine.feed
        xs = np.concatenate([f.x, self._rapid_xy[:, 0], self._rapid_xy[:, 2]])
        ys = np.concatenate([f.y, self._rapid_xy[:, 1], self._rapid_xy[:, 3]])
        if not np.isfinite(xs).any():
            return None
        return float(np.nanmin(xs)), float(np.nanmax(xs)), float(np.nanmin(ys)), float(np.nanmax(ys))

    def visible_range(self) -> tuple[float, float, float, float]:
        """The shown area as (xmin, xmax, ymin, ymax) mm."""
        (x0, x1), (y0, y1) = self._view.viewRange()
        return x0, x1, y0, y1

    def set_visible_range(self, xmin: float, xmax: float, ymin: float, ymax: float) -> None:
        """Show this area (mm); the locked aspect ratio may widen one side."""
        self._view.setRange(xRange=(xmin, xmax), yRange=(ymin, ymax), padding=0.0)

    def head_position(self) -> tuple[float, float] | None:
        """Where the head cross is drawn, in machine mm, or None before the first `set_head`."""
        if not self._head.isVisible():
            return None
        p = self._view.mapSceneToView(self._head.scenePos())
        return p.x(), p.y()

    def point_counts(self) -> dict[str, int]:
        """Vertices drawn per category (cut, current, to_cut, rapid) in the fine tessellation, shared
        joints counted in each category that draws them."""
        if self._fine is None:
            return {CUT: 0, CURRENT: 0, TO_CUT: 0, RAPIDS: 0}
        cut_end, todo_begin = self._fine.split(self._progress)
        x = self._fine.feed.x
        return {
            CUT: int(np.isfinite(x[:cut_end]).sum()), CURRENT: self._current.path().elementCount(),
            TO_CUT: int(np.isfinite(x[todo_begin:]).sum()), RAPIDS: self._rapids.path().elementCount(),
        }

    @property
    def progress(self) -> int:
        """The index of the segment being cut (segments before it are cut)."""
        return self._progress

    def _on_click(self, event) -> None:  # noqa: ANN001 - pyqtgraph's MouseClickEvent
        """A double click frames the program again after zooming or panning around."""
        if event.double():
            self.fit()
