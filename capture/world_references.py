"""Which world references one capture may hold together: the one rule that the capture folder's
reader (:func:`wandcal.capture.folder.read_capture`), the service's store of uploads
(:mod:`wandcal.service.storage`) and ``POST /captures`` all apply.

A static L-frame (static.csv) or axis points (axis.csv) set the whole world frame; floor points
(floor.csv) or a dropped object's track (drop.csv) set only its vertical, the rest from the wand
volume; with none of them the wand volume sets it (docs/inputs.md). Two whole frames or two
verticals cannot both hold, and a vertical beside a whole frame would be ignored, so a capture
holds at most one of the four files: a second is refused, never silently dropped.
"""

from __future__ import annotations

from collections.abc import Collection
from dataclasses import dataclass

from wandcal.drivers.capture_files import AXIS_FILE, DROP_FILE, FLOOR_FILE, STATIC_FILE

WHOLE_FRAME = {STATIC_FILE: "the static object", AXIS_FILE: "axis points"}  # each sets the whole world frame
VERTICAL_ONLY = {FLOOR_FILE: "floor points", DROP_FILE: "a dropped object's track"}  # each sets the vertical only
# the order in which a clash is named: the earlier file is kept, the later one is at fault
ORDER = (STATIC_FILE, AXIS_FILE, FLOOR_FILE, DROP_FILE)


@dataclass(frozen=True)
class ReferenceClash:
    """Two world-reference files a capture may not hold together. ``at_fault`` names the file to
    take out (the later of the two in ``ORDER``), ``kept`` the one that sets what both would."""

    at_fault: str
    kept: str

    def message(self, where: str = "this capture") -> str:
        """The refusal: what sets the frame twice, in ``where``, and what to do."""
        if self.kept in VERTICAL_ONLY:
            what = f"the world's vertical is set by {self.kept} and by {self.at_fault}"
        elif self.at_fault in WHOLE_FRAME:
            what = (f"the world frame is set by {self.kept} ({WHOLE_FRAME[self.kept]}) and by {self.at_fault} "
                    f"({WHOLE_FRAME[self.at_fault]})")
        else:
            what = f"the world frame is set by {self.kept}, which also sets the vertical that {self.at_fault} would"
        return f"{what} in {where}; keep one of them (the other would be ignored)"


def reference_clash(given: Collection[str]) -> ReferenceClash | None:
    """The clash among ``given`` (the world-reference file names a capture holds with rows: any of
    static.csv, axis.csv, floor.csv, drop.csv), or None when there is none. Any two of them clash:
    static.csv and axis.csv each set the whole frame, floor.csv and drop.csv each set its vertical,
    and a vertical beside a whole frame would be ignored (the module's docstring)."""
    unknown = set(given) - set(ORDER)
    if unknown:
        raise ValueError(f"not a world-reference file: {sorted(unknown)}")
    held = [name for name in ORDER if name in given]
    return ReferenceClash(at_fault=held[1], kept=held[0]) if len(held) > 1 else None
