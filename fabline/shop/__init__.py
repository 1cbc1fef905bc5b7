"""What the shop cuts on and with, below the stages that plan for it: the sheet stock on hand (sheets and
remnants, `fabline.stock/1`, and a sheet's usable extent) and the operation layers every drawing uses.

The names load their modules on first use (`fabline.lazy`).
"""

from fabline.lazy import lazy_surface

__getattr__, __all__ = lazy_surface(__name__, {
    "layers": ("LAYERS", "Layer"),
    "stock": ("StockItem", "load_stock", "parse_sheet_size", "save_stock", "stock_after", "usable_extent"),
})
