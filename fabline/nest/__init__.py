"""The nest stage: parts onto sheets, and the nesting format that export reads."""

from fabline.nest.layout import (SCHEMA, CommonCut, Nesting, Placement, Sheet, load_nesting, nesting_from_dict,
                                 nesting_to_dict, parts_path, place, save_nesting)
from fabline.nest.nester import NestOptions, NestResult, nest
from fabline.nest.stock import StockItem, load_stock, parse_sheet_size, save_stock, stock_after
from fabline.nest.svg import write_sheet_svgs
from fabline.nest.validate import validate_nesting

__all__ = ["SCHEMA", "CommonCut", "NestOptions", "NestResult", "Nesting", "Placement", "Sheet", "StockItem",
           "load_nesting", "load_stock", "nest", "nesting_from_dict", "nesting_to_dict", "parse_sheet_size",
           "parts_path", "place", "save_nesting", "save_stock", "stock_after", "validate_nesting",
           "write_sheet_svgs"]
