"""Unroll and nest share one rule for the longest part a sheet holds (`fabline.shop.stock.usable_extent`): a strip
the unroll makes at that length, straight or bent by a few hundredths of a millimetre, nests on an empty sheet."""

from __future__ import annotations


import numpy as np
import pytest

from fabline.errors import FablineError
from fabline.nest import NestOptions, nest
from fabline.shop.stock import StockItem, usable_extent
from fabline.unroll import Part, PartSet, UnrollOptions


def _bent_strip(part_id: str, length: float, sagitta: float, h: float = 100.0) -> Part:
    """A curved-strip part as unroll writes one from an imported model: both long edges arcs of the same sagitta."""
    bulge = 2.0 * sagitta / length if sagitta else 0.0  # tan(angle / 4) of a shallow arc
    outline = np.array([[0.0, -h / 2, bulge], [length, -h / 2, 0.0], [length, h / 2, -bulge], [0.0, h / 2, 0.0],
                        [0.0, -h / 2, 0.0]])
    return Part(part_id, "curved-strip" if sagitta else "strip", outline, lamella="A-001", grain=True,
                meta={"length_mm": length})


def test_unroll_splits_strips_to_the_nests_usable_length():
    options = UnrollOptions(sheet_length=4000.0, sheet_margin=10.0)
    assert options.usable_length == usable_extent(4000.0, 10.0) == 3980.0


@pytest.mark.parametrize("sagitta", [0.0, 0.02, 2.0])
def test_a_strip_of_the_usable_length_nests_on_an_empty_sheet(sagitta):
    """3979 mm: one millimetre under the usable length, bent as far as an imported model's noise (0.02 mm) or a
    real in-plane curve (2 mm) bends it."""
    strip = _bent_strip("A-001-L.1", 3979.0, sagitta)
    options = NestOptions(time_limit=1.0)
    result = nest(PartSet([strip], {"h": 100.0, "t": 1.5}), [StockItem("sheet", 4000.0, 2000.0)], options)
    assert result.report["sheets_used"] == 1


def test_a_part_too_long_for_any_sheet_is_named_once_with_its_size():
    strip = _bent_strip("A-001-L.1", 3990.0, 0.02)
    with pytest.raises(FablineError) as error:
        nest(PartSet([strip], {"h": 100.0, "t": 1.5}), [StockItem("sheet", 4000.0, 2000.0)], NestOptions(time_limit=1.0))
    message = str(error.value)
    assert "A-001-L.1" in message and "3990" in message and "sheet sheet" not in message
