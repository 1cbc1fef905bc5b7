"""The assembly plan's pages as one printable PDF (A3 landscape, a page per SVG page, in the same order).

fpdf2 places each SVG page as vector paths and text (no raster), so the PDF is the same drawing as the SVGs and its
text (labels, node ids, tables) stays searchable.
"""

from __future__ import annotations

import io
import logging
import os

from fabline.fileio import atomic_output

PDF = "plan.pdf"


def write_pdf(pages: list[str], path: str | os.PathLike, size: tuple[float, float]) -> None:
    """Write the SVG texts `pages` (each `size` mm, width x height) as the pages of one PDF at `path`."""
    from fpdf import FPDF

    width, height = size
    pdf = FPDF(orientation="L" if width > height else "P", unit="mm", format=(min(size), max(size)))
    pdf.set_auto_page_break(False)
    pdf.set_creator("fabline assembly")
    svg_log = logging.getLogger("fpdf.svg")
    level = svg_log.level
    svg_log.setLevel(logging.ERROR)  # fpdf2 notes every <title> it leaves out: the page title is not drawn anyway
    try:
        for text in pages:
            pdf.add_page()
            # the PDF's built-in fonts hold Latin-1 only: any other character of a name or id prints as "?"
            text = text.encode("latin-1", "replace").decode("latin-1")
            pdf.image(io.BytesIO(text.encode("utf-8")), x=0, y=0, w=width, h=height)
    finally:
        svg_log.setLevel(level)
    with atomic_output(path, "wb") as handle:
        handle.write(bytes(pdf.output()))
