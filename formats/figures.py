"""Figures written to files: a matplotlib figure (:mod:`evtools.plots` makes them) saved as PNG, SVG or PDF by
the file name's extension, atomically (a failed write leaves nothing), with its text as text in SVG and PDF."""

from __future__ import annotations

import os

from evtools.formats.errors import FormatError
from evtools.formats.io import atomic_path

FIGURE_FORMATS = {".png": "png", ".svg": "svg", ".pdf": "pdf"}
"""Figure formats, by the extension of the file name."""


class FigureError(FormatError):
    """A figure that cannot be written: a name without a figure extension, a file that cannot be written."""


def figure_format(path: str | os.PathLike) -> str:
    """The matplotlib format of ``path`` (png, svg, pdf) from its extension; a clear error otherwise."""
    extension = os.path.splitext(os.fspath(path))[1].lower()
    if extension not in FIGURE_FORMATS:
        raise FigureError(f"{path}: give a figure name ending in {', '.join(FIGURE_FORMATS)}")
    return FIGURE_FORMATS[extension]


def save_figure(figure, path: str | os.PathLike) -> None:
    """Write ``figure`` to ``path`` and close it: atomically, in the format of the extension, text as text (not
    outlines) in SVG and PDF, no date in their metadata (the same figure gives the same bytes)."""
    import matplotlib.pyplot as plt

    kind = figure_format(path)
    try:
        with atomic_path(path, os.path.splitext(os.fspath(path))[1]) as temporary, \
                plt.rc_context({"svg.fonttype": "none", "pdf.fonttype": 42}):
            figure.savefig(temporary, format=kind, dpi=150, bbox_inches="tight",
                           metadata={"Date": None} if kind in ("svg", "pdf") else None)
    except OSError as error:
        raise FigureError(f"{path}: cannot write ({error.strerror or error})") from None
    finally:
        plt.close(figure)
