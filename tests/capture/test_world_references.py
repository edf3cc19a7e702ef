"""The one world-reference rule (capture/world_references.py) that the folder reader, the store
of uploads and POST /captures apply."""

from __future__ import annotations

import itertools

import pytest

from wandcal.capture.world_references import ORDER, reference_clash


@pytest.mark.parametrize("given", [set(c) for k in range(len(ORDER) + 1) for c in itertools.combinations(ORDER, k)])
def test_a_capture_holds_at_most_one_world_reference(given):
    clash = reference_clash(given)
    if len(given) <= 1:  # none (the wand volume sets the frame) or one reference: allowed
        assert clash is None
        return
    assert clash is not None and {clash.kept, clash.at_fault} <= given and clash.kept != clash.at_fault
    said = clash.message()
    assert clash.kept in said and clash.at_fault in said and "keep one of them" in said
    with pytest.raises(ValueError, match="not a world-reference file"):
        reference_clash(given | {"wand.csv"})
