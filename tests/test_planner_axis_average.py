"""A section held back by its curves takes a longer axis average where that runs it sooner.

The axis average's length comes from the tolerance (`limits.axis_average_samples`); a section whose
arcs are capped under their feed by the curvature steps where they meet lines may run sooner with a
longer one (`sections._longer_averages`). These tests hold what that must keep: every axis limit,
every record within P, the planned time the one run, under the operator's controls too; and that
sections whose curves run at their feed keep the average their tolerance gives.
"""

from __future__ import annotations

import numpy as np
import pytest

from gcode.interp import interpret

from cnc.machine_dialect import dialect_for
from cnc.planner import sections
from cnc.planner.limits import axis_average_samples
from cnc.planner.sections import Section, iter_steps

from .conftest import REPO, machine_config
from .test_planner_motion import _operator_at_random, run, within_limits, within_tolerance

pytestmark = pytest.mark.computes  # pure computation: `make test` runs it beside the rest (tests/lanes.py)

FIG10 = (REPO / "cnc" / "control" / "fig10_contour.ngc").read_text()


def _curved_sections(text: str) -> list[Section]:
    config = machine_config()
    program = interpret(text, dialect_for(config))
    return [s for s in iter_steps(program, config) if isinstance(s, Section) and s.limits.smoothing.geometry_share > 0.0]


def _own_averages_only(monkeypatch) -> None:
    monkeypatch.setattr(sections, "_longer_averages", lambda whole, config, cut, elements, path, limits, seconds:
                        (elements, path, limits))


def test_the_fig10_contour_takes_a_longer_axis_average_and_runs_sooner_within_every_limit_and_p(monkeypatch):
    """At F30000 and P 0.005 the contour's arcs are capped at 60-240 mm/s, most of it by the jerk
    of the curvature steps where they meet the straights: its own 8-sample average (balance of a
    step's jerk and an arc's deviation) gave 2.96 s; a longer one spreads the steps, and the
    contour ends sooner (2.69 s), every axis within its limits and every record within P."""
    own = axis_average_samples(machine_config(), 0.005)
    (contour,) = _curved_sections(FIG10)
    assert contour.limits.smoothing.n_axis > own
    program, _, records, planned = run(FIG10, chunk=97)
    within_limits(records)
    assert (within_tolerance(program, records) <= 1e-9).all()
    assert len(records) == planned, "the planned cycle time is the one run"
    _own_averages_only(monkeypatch)
    (mine,) = _curved_sections(FIG10)
    assert mine.limits.smoothing.n_axis == own
    _, _, with_own, planned_own = run(FIG10, chunk=97)
    assert len(with_own) == planned_own
    assert len(with_own) - len(records) >= 200, "sooner by a tenth of its time"


@pytest.mark.parametrize("seed", [1, 4, 9])
def test_holds_and_overrides_at_random_on_the_fig10_contour_keep_every_limit_and_p(seed):
    """The longer average under the operator's controls (holds, resumes, overrides 0-200 %, a stop,
    records taken 1 to 200 at a time): limits and P anywhere."""
    program, records, _, _ = _operator_at_random(seed, text=FIG10)
    within_limits(records)
    assert (within_tolerance(program, records) <= 1e-9).all()


def test_contours_whose_curves_run_at_their_feed_keep_the_average_their_tolerance_gives():
    """A CAM part at a waterjet feed (F2400, P 0.05): its arcs run at the feed, nothing holds the
    section back, and its average is the tolerance's own (no section is made more than once)."""
    text = "\n".join([
        "G21 G90 G64 P0.05", "G0 X10 Y7", "G41 D1 G1 X10 Y10 F2400", "G1 X40 Y10", "G3 X45 Y15 I0 J5",
        "G1 X45 Y30", "G3 X40 Y35 R5", "G1 X15 Y35", "G3 X10 Y30 I0 J-5", "G1 X10 Y10", "G40 G1 X8 Y8", "M2"]) + "\n"
    curved = _curved_sections(text)
    assert curved
    own = axis_average_samples(machine_config(), 0.05)
    assert all(s.limits.smoothing.n_axis == own for s in curved)
    assert all(np.all(s.limits.v_hard[s.path.arc] >= s.limits.v_feed[s.path.arc]) for s in curved)
