"""PSNR-against-size charts as plain SVG text, for the results page (bench/results_page.py).

Written here rather than with matplotlib because the page must regenerate byte for byte on any
machine from the committed JSON, and matplotlib is no dependency of the project: its output also
moves with its version and fonts. The charts need little: a log size axis, a linear dB axis,
lines with markers, single points and a legend. Every coordinate is rounded to 0.1 px so the
text is stable.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from html import escape

PANEL_WIDTH = 340.0
PANEL_HEIGHT = 250.0
MARGIN_LEFT, MARGIN_RIGHT, MARGIN_TOP, MARGIN_BOTTOM = 48.0, 12.0, 28.0, 40.0
LEGEND_ROW = 18.0
DB_CEILING = 72.0
"""Points above this are drawn on the panel's top edge with their value beside them: a file that
renders identically (biker's SPZ, 107 dB) would otherwise flatten every other curve."""
FONT = 'font-family="sans-serif" font-size="11"'


@dataclass(frozen=True)
class Series:
    """One method on one panel: points (bytes, dB), drawn as a line through them or as lone marks."""

    label: str
    color: str
    points: tuple[tuple[float, float], ...]
    line: bool = True
    marker: str = "circle"


@dataclass(frozen=True)
class Panel:
    """One framing: its title and the series measured at it."""

    title: str
    series: tuple[Series, ...] = field(default_factory=tuple)


def size_label(nbytes: float) -> str:
    """Bytes as a short axis label (decimal units, as the tables count them): 50 kB, 1 MB."""
    for unit, scale in (("MB", 1e6), ("kB", 1e3)):
        if nbytes >= scale:
            value = nbytes / scale
            return f"{value:.0f} {unit}" if value >= 1 and value == round(value) else f"{value:g} {unit}"
    return f"{nbytes:.0f} B"


def log_ticks(lo: float, hi: float) -> list[float]:
    """1-2-5 ticks within [lo, hi] on a log axis (at least the decades; more when few fall inside)."""
    ticks = []
    for exponent in range(math.floor(math.log10(lo)), math.ceil(math.log10(hi)) + 1):
        for mantissa in (1, 2, 5):
            value = mantissa * 10.0 ** exponent
            if lo <= value <= hi:
                ticks.append(value)
    return ticks


def linear_ticks(lo: float, hi: float) -> list[float]:
    """Round dB ticks: the finest step of 0.5 to 50 dB that gives 2 to 8 ticks (else the ends)."""
    for step in (0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0):
        first = math.ceil(lo / step) * step
        ticks = [first + i * step for i in range(int((hi - first) // step) + 1)]
        if 2 <= len(ticks) <= 8:
            return ticks
    return [lo, hi]


def size_range(panels: list[Panel]) -> tuple[float, float]:
    """One size axis for every panel of a figure, padded an eighth of a decade each side, so the
    framings of one scene line up file by file."""
    xs = [x for p in panels for s in p.series for x, _ in s.points]
    if not xs:
        raise ValueError("a chart needs at least one point")
    return 10 ** (math.log10(min(xs)) - 0.12), 10 ** (math.log10(max(xs)) + 0.12)


def db_range(panel: Panel) -> tuple[float, float]:
    """Each panel its own dB axis (test images and a viewer's framings span different ranges),
    padded to whole steps of 2 dB and one more."""
    ys = [y for s in panel.series for _, y in s.points]
    if not ys:
        return 0.0, 1.0
    return math.floor(min(ys) / 2) * 2 - 1, min(math.ceil(max(ys) / 2) * 2 + 1, DB_CEILING)


def _num(value: float) -> str:
    text = f"{value:.1f}"
    return "0.0" if text == "-0.0" else text


def _marker(shape: str, x: float, y: float, color: str) -> str:
    if shape == "square":
        return (f'<rect x="{_num(x - 3.5)}" y="{_num(y - 3.5)}" width="7" height="7" '
                f'fill="{color}"/>')
    if shape == "diamond":
        corners = ((x, y - 5), (x + 5, y), (x, y + 5), (x - 5, y))
        pts = " ".join(f"{_num(cx)},{_num(cy)}" for cx, cy in corners)
        return f'<polygon points="{pts}" fill="{color}"/>'
    return f'<circle cx="{_num(x)}" cy="{_num(y)}" r="3" fill="{color}"/>'


def chart(title: str, panels: list[Panel], y_label: str = "PSNR dB") -> str:
    """The SVG of one figure: panels side by side on one size axis, one legend under them."""
    x_lo, x_hi = size_range(panels)
    plot_w = PANEL_WIDTH - MARGIN_LEFT - MARGIN_RIGHT
    plot_h = PANEL_HEIGHT - MARGIN_TOP - MARGIN_BOTTOM
    legend = _legend_entries(panels)
    width = PANEL_WIDTH * len(panels)
    height = PANEL_HEIGHT + 22 + LEGEND_ROW * math.ceil(len(legend) / 3)

    def px(x: float) -> float:
        return (math.log10(x) - math.log10(x_lo)) / (math.log10(x_hi) - math.log10(x_lo)) * plot_w

    out = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{_num(width)}" height="{_num(height)}" '
           f'viewBox="0 0 {_num(width)} {_num(height)}">',
           f'<rect width="{_num(width)}" height="{_num(height)}" fill="white"/>',
           f'<text x="{_num(width / 2)}" y="16" text-anchor="middle" {FONT} font-weight="bold">'
           f'{escape(title)}</text>']
    for index, panel in enumerate(panels):
        y_lo, y_hi = db_range(panel)

        def py(y: float, y_lo: float = y_lo, y_hi: float = y_hi) -> float:
            return plot_h - (min(y, y_hi) - y_lo) / (y_hi - y_lo) * plot_h

        left, top = index * PANEL_WIDTH + MARGIN_LEFT, 22 + MARGIN_TOP
        out.append(f'<g transform="translate({_num(left)},{_num(top)})">')
        out.append(f'<text x="{_num(plot_w / 2)}" y="-8" text-anchor="middle" {FONT}>'
                   f'{escape(panel.title)}</text>')
        out.append(f'<rect width="{_num(plot_w)}" height="{_num(plot_h)}" fill="none" stroke="#888"/>')
        for tick in log_ticks(x_lo, x_hi):
            x = px(tick)
            out.append(f'<line x1="{_num(x)}" y1="0" x2="{_num(x)}" y2="{_num(plot_h)}" stroke="#eee"/>')
            out.append(f'<text x="{_num(x)}" y="{_num(plot_h + 14)}" text-anchor="middle" {FONT}>'
                       f'{size_label(tick)}</text>')
        for tick in linear_ticks(y_lo, y_hi):
            y = py(tick)
            out.append(f'<line x1="0" y1="{_num(y)}" x2="{_num(plot_w)}" y2="{_num(y)}" stroke="#eee"/>')
            out.append(f'<text x="-5" y="{_num(y + 4)}" text-anchor="end" {FONT}>{tick:g}</text>')
        out.append(f'<text x="{_num(plot_w / 2)}" y="{_num(plot_h + 30)}" text-anchor="middle" {FONT}>'
                   'file bytes (log)</text>')
        out.append(f'<text transform="translate(-34,{_num(plot_h / 2)}) rotate(-90)" '
                   f'text-anchor="middle" {FONT}>{escape(y_label)}</text>')
        for series in panel.series:
            points = sorted(series.points)
            if series.line and len(points) > 1:
                path = " ".join(f"{_num(px(x))},{_num(py(y))}" for x, y in points)
                out.append(f'<polyline points="{path}" fill="none" stroke="{series.color}" '
                           'stroke-width="1.5"/>')
            out.extend(_marker(series.marker, px(x), py(y), series.color) for x, y in points)
            out.extend(f'<text x="{_num(px(x) - 6)}" y="{_num(py(y) + 14)}" text-anchor="end" {FONT}>'
                       f'{y:.0f} dB</text>' for x, y in points if y > y_hi)
        out.append("</g>")
    top = PANEL_HEIGHT + 22
    for i, (label, color, marker) in enumerate(legend):
        x, y = 20 + (i % 3) * (width - 40) / 3, top + (i // 3) * LEGEND_ROW
        out.append(_marker(marker, x, y - 4, color))
        out.append(f'<text x="{_num(x + 10)}" y="{_num(y)}" {FONT}>{escape(label)}</text>')
    out.append("</svg>")
    return "\n".join(out) + "\n"


def _legend_entries(panels: list[Panel]) -> list[tuple[str, str, str]]:
    seen: dict[str, tuple[str, str, str]] = {}
    for panel in panels:
        for series in panel.series:
            seen.setdefault(series.label, (series.label, series.color, series.marker))
    return list(seen.values())
