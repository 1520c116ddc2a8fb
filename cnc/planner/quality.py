"""The cutting model on a program: the quality of every segment, and the speed cap of every element.

`CutPlan.of` binds a `CutModel` (`cnc/cutmodel.py`) to an interpreted program: the setup's quality
holds from the first segment; a `(QUALITY, n)` comment changes it for the segments after it; the
lead-in after each pierce (the first feed move with the jet on after it opened) runs at the
setup's pierce quality. Segments with the jet closed, and rapids, have no cap of the model.

`CutPlan.caps` gives, for the elements of one section (`sections.py`), the model's speed cap in
mm/s: the quality's straight speed; on arcs (programmed ones and the planner's corner blends) the
jet-lag cap of their radius and sweep; at the small kinks the planner runs through, the corner
cap of their angle on both neighbours. In "quality" mode the planner takes these as the feed
wherever they are below the programmed F; in "feed" mode they are not applied (the model only
reports: `cnc/cutcheck.py`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from gcode.canon import ARC, LINE
from gcode.program import Program

from ..cutmodel import CutModel, CutSetup, model_for, setup_of_program
from ..materials import MaterialError
from .geometry import PathArrays
from .limits import KINK_MAX_RAD
from .path import COLLINEAR_RAD, Element


if TYPE_CHECKING:
    from ..config import MachineConfig


class CutPlanError(ValueError):
    """A program's cutting comments contradict each other; the text names the lines."""


@dataclass
class CutPlan:
    """A program's qualities per segment (0: no model there) and the model that gives their speeds."""

    model: CutModel
    quality: np.ndarray  # int8 per program segment

    @classmethod
    def of(cls, program: Program, model: CutModel) -> "CutPlan":
        seg = program.segments
        n = len(seg)
        quality = np.full(n, model.setup.quality, dtype=np.int8)
        first_material = None
        for m in sorted(program.messages, key=lambda m: m.segment):
            if m.kind == "quality":
                quality[m.segment:] = m.data["quality"]
            elif m.kind == "material":
                d = m.data
                if first_material is None:
                    first_material = m
                elif (d["material"], d["thickness_mm"]) != (first_material.data["material"], first_material.data["thickness_mm"]):
                    raise CutPlanError(
                        f"line {m.line}: ({m.text}) names another material or thickness than line {first_material.line}: "
                        "a program cuts one sheet")
                elif m.segment > first_material.segment:
                    quality[m.segment:] = d["quality"]  # a later one, same sheet: a change of quality
        if n:
            jet = seg["jet"].astype(bool)
            feed_move = np.isin(seg["kind"], (LINE, ARC)) & jet
            opened = np.flatnonzero(jet & ~np.concatenate(([False], jet[:-1])))
            moves = np.flatnonzero(feed_move)
            k = np.searchsorted(moves, opened)
            # the first cutting move after each opening (a move found from two openings belongs to the later)
            quality[np.unique(moves[k[k < len(moves)]])] = model.setup.pierce_quality
        return cls(model, quality)

    @property
    def applies(self) -> bool:
        """Whether the planner takes the model's caps (mode "quality") or cuts at F ("feed")."""
        return self.model.uses_quality

    def caps(self, elements: list[Element], path: PathArrays) -> np.ndarray:
        """The model's speed cap of each element, mm/s (inf where the model does not cap it)."""
        n = len(elements)
        out = np.full(n, np.inf)
        if not n:
            return out
        segment = np.array([e.segment for e in elements], dtype=np.int64)
        cutting = np.array([e.jet and e.kind in (LINE, ARC) for e in elements], dtype=bool)
        q = np.where(cutting, self.quality[np.clip(segment, 0, len(self.quality) - 1)], 0).astype(np.int64)
        modelled = q > 0
        if not modelled.any():
            return out
        model = self.model
        out[modelled] = model.speed_mm_s[q[modelled]]
        for quality in np.unique(q[modelled]):
            on = q == quality
            arcs = on & path.arc
            if arcs.any():
                out[arcs] = np.minimum(out[arcs], model.arc_cap(int(quality), path.radius[arcs], path.sweep[arcs]))
        if n > 1:
            kinks = path.kink_angles()
            at = np.flatnonzero((kinks > COLLINEAR_RAD) & (kinks <= KINK_MAX_RAD) & modelled[:-1] & modelled[1:])
            for i in at:
                qk = int(max(q[i], q[i + 1]))  # the finer of the two
                cap = float(model.turn_cap(qk, kinks[i]))
                out[i], out[i + 1] = min(out[i], cap), min(out[i + 1], cap)
        return out

    def quality_of(self, segment: int) -> int:
        return int(self.quality[segment]) if 0 <= segment < len(self.quality) else 0


def cut_plan_for(program: Program, given: CutSetup | None, config: "MachineConfig", name: str) -> tuple[CutPlan | None, str]:
    """A program's cutting job and its plan: the operator's `given`, else the program's `(MATERIAL, ...)`
    comment, read off the machine's material library; with the text the screen shows. (None, "")
    when neither chose one: the program cuts at its F. CutPlanError says what is wrong, naming the
    program (and the comment's line): the material, the thickness against its chart, two sheets."""
    setup = setup_of_program(program.messages, given)
    if setup is None:
        return None, ""
    try:
        plan = CutPlan.of(program, model_for(setup, config))
    except (MaterialError, CutPlanError) as exc:
        where = "" if given is not None else next((f":{m.line}" for m in program.messages if m.kind == "material"), "")
        raise CutPlanError(f"{name}{where}: cutting job: {exc}") from None
    note = "" if plan.model.corners_modelled else "; corners not modelled (no trail-back in its chart)"
    return plan, f"{setup.describe()}, by {'the operator' if given is not None else 'the program'}{note}"
