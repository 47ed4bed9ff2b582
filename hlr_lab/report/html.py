"""The report's pieces as HTML strings: embedded PNG images, inline SVG charts, tables. No template
engine and no network: everything the page shows is inside the file."""

from __future__ import annotations

import base64
import html

import cv2
import numpy as np

STYLE = """
body { font: 14px/1.45 system-ui, sans-serif; margin: 2em auto; max-width: 1100px; color: #222; }
h1 { font-size: 1.6em; } h2 { margin-top: 2em; border-bottom: 1px solid #ccc; }
table { border-collapse: collapse; margin: 1em 0; } td, th { padding: .3em .7em; border: 1px solid #ddd; }
th { background: #f3f3f3; } td.num { text-align: right; font-variant-numeric: tabular-nums; }
.swatch { display: inline-block; width: 1.2em; height: 1.2em; border: 1px solid #888; vertical-align: middle; }
figure { display: inline-block; margin: .4em; text-align: center; } figcaption { font-size: .9em; color: #555; }
.charts svg { margin: .4em; border: 1px solid #eee; } .note { color: #666; }
.misplaced { background: #fde8e6; border: 1px solid #d9534f; padding: .6em 1em; }
"""


def escape(text: object) -> str:
    """``text`` as HTML text."""
    return html.escape(str(text))


def page(title: str, body: str) -> str:
    """A whole self-contained HTML page: ``title`` as its title and heading, ``body`` (HTML) below."""
    return (
        f'<!DOCTYPE html><html lang="en"><head><meta charset="utf-8"><title>{escape(title)}</title>'
        f"<style>{STYLE}</style></head><body><h1>{escape(title)}</h1>{body}</body></html>\n"
    )


def png_data_uri(rgb: np.ndarray) -> str:
    """(H, W, 3) uint8 RGB → a data: URI holding it as PNG."""
    ok, png = cv2.imencode(".png", np.ascontiguousarray(rgb[..., ::-1]))
    if not ok:
        raise ValueError("PNG encoding failed")
    return "data:image/png;base64," + base64.b64encode(png.tobytes()).decode("ascii")


def figure(rgb: np.ndarray, caption: str) -> str:
    """An ``<figure>`` of an (H, W, 3) uint8 RGB image, embedded, with its caption."""
    img = f'<img src="{png_data_uri(rgb)}" alt="{escape(caption)}">'
    return f"<figure>{img}<figcaption>{escape(caption)}</figcaption></figure>"


def tone_map(radiance: np.ndarray, white: float) -> np.ndarray:
    """(H, W, 3) linear radiance → uint8 sRGB-ish for display (NaN → mid grey), ``white`` → 255."""
    v = np.nan_to_num(radiance / white, nan=0.18)
    return (np.clip(v, 0, 1) ** (1 / 2.2) * 255).round().astype(np.uint8)


def error_map(captured: np.ndarray, rendered: np.ndarray, mask: np.ndarray, scale: float) -> np.ndarray:
    """|captured − rendered| (mean over channels) / scale through a perceptual colour map; black off ``mask``."""
    err = np.zeros(mask.shape)
    err[mask] = np.abs(captured[mask] - rendered[mask]).mean(axis=-1) / scale
    coloured = cv2.applyColorMap((np.clip(err, 0, 1) * 255).astype(np.uint8), cv2.COLORMAP_INFERNO)[..., ::-1]
    coloured[~mask] = 0
    return coloured


def table(headers: list[str], rows: list[list[str]], numeric_from: int = 1) -> str:
    """An HTML table; cells are HTML already; columns from ``numeric_from`` on are right-aligned."""
    head = "".join(f"<th>{escape(h)}</th>" for h in headers)
    body = "".join(
        "<tr>"
        + "".join(f'<td class="{"num" if i >= numeric_from else ""}">{c}</td>' for i, c in enumerate(r))
        + "</tr>"
        for r in rows
    )
    return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"


def swatch(rgb8) -> str:
    """A small square of the colour ``rgb8`` (three 0–255 values)."""
    r, g, b = (int(c) for c in rgb8)
    return f'<span class="swatch" style="background: rgb({r},{g},{b})"></span>'


def scatter_svg(
    points: list[tuple[float, float, str]],
    *,
    x_range: tuple[float, float],
    y_range: tuple[float, float],
    x_label: str,
    y_label: str,
    title: str,
    line: list[tuple[float, float]] | None = None,
    size: tuple[int, int] = (420, 260),
) -> str:
    """A small chart: labelled points (x, y, label) and an optional polyline, axes with their ranges."""
    w, h = size
    left, bottom, top, right = 50, 35, 25, 15
    (x0, x1), (y0, y1) = x_range, y_range
    mid = (top + h - bottom) / 2

    def sx(x: float) -> float:
        return left + (x - x0) / (x1 - x0 or 1) * (w - left - right)

    def sy(y: float) -> float:
        return h - bottom - (y - y0) / (y1 - y0 or 1) * (h - top - bottom)

    parts = [
        f'<svg width="{w}" height="{h}" role="img" aria-label="{escape(title)}">',
        f'<text x="{w / 2}" y="16" text-anchor="middle" font-size="13">{escape(title)}</text>',
        f'<line x1="{left}" y1="{h - bottom}" x2="{w - right}" y2="{h - bottom}" stroke="#888"/>',
        f'<line x1="{left}" y1="{top}" x2="{left}" y2="{h - bottom}" stroke="#888"/>',
        f'<text x="{(left + w - right) / 2}" y="{h - 5}" text-anchor="middle" font-size="11">{escape(x_label)}</text>',
        f'<text x="12" y="{mid}" font-size="11" transform="rotate(-90 12 {mid})" text-anchor="middle">'
        f"{escape(y_label)}</text>",
    ]
    for x in (x0, x1):
        parts.append(
            f'<text x="{sx(x)}" y="{h - bottom + 13}" text-anchor="middle" font-size="10">{x:g}</text>'
        )
    for y in (y0, y1):
        parts.append(f'<text x="{left - 4}" y="{sy(y) + 3}" text-anchor="end" font-size="10">{y:.3g}</text>')
    if line:
        coords = " ".join(f"{sx(x):.1f},{sy(y):.1f}" for x, y in line)
        parts.append(f'<polyline points="{coords}" fill="none" stroke="#d33" stroke-width="1.5"/>')
    for x, y, label in points:
        parts.append(
            f'<circle cx="{sx(x):.1f}" cy="{sy(y):.1f}" r="3" fill="#2a6fdb"><title>{escape(label)}</title></circle>'
        )
        if label:
            parts.append(
                f'<text x="{sx(x) + 5:.1f}" y="{sy(y) - 4:.1f}" font-size="10">{escape(label)}</text>'
            )
    parts.append("</svg>")
    return "".join(parts)
