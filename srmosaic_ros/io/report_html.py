"""report.html: a run's report as one self-contained page that opens offline.

The page is plain HTML with its CSS inline and its figures inline as base64 PNG or JPEG (``data:`` URLs):
no script, no font, no stylesheet and no image from anywhere else, and a Content-Security-Policy
that forbids the browser to fetch anything but ``data:`` images. A section says plainly when the
run has no data for it.

Markers the tests read (and a user's script may): each ``<section>`` carries ``data-section``
(its key) and ``data-figures`` (the figures in it); each ``<img>`` carries ``data-figure`` (the
section's key) and the attributes its figure was given (e.g. ``data-failed-frames``).
"""
from __future__ import annotations

import base64
import html
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from .mosaic_files import atomic_path

__all__ = ['ReportFigure', 'ReportSection', 'render_report', 'write_report_html']

#: The browser may load nothing but the page's own inline styles and data: images.
CSP = "default-src 'none'; img-src data:; style-src 'unsafe-inline'"

_CSS = """
body { font-family: system-ui, sans-serif; margin: 0 auto; max-width: 1100px; padding: 0 1.2em 2em; color: #222; }
h1 { font-size: 1.5em; margin-bottom: 0.2em; } h2 { font-size: 1.2em; border-bottom: 1px solid #ccc; }
.sub { color: #666; margin-top: 0; }
table { border-collapse: collapse; margin: 0.5em 0; } td, th { padding: 0.2em 0.8em; text-align: left;
  vertical-align: top; border-bottom: 1px solid #eee; } th { color: #555; font-weight: 600; white-space: nowrap; }
figure { display: inline-block; margin: 0.4em 1em 0.4em 0; } figcaption { color: #555; font-size: 0.9em; max-width: 640px; }
img { max-width: 100%; height: auto; border: 1px solid #ddd; }
.empty { color: #777; font-style: italic; } .warn { color: #9a4b00; } .bad { color: #b00020; }
nav a { margin-right: 1em; }
"""


@dataclass
class ReportFigure:
    """One figure: its PNG (or JPEG) bytes, alt text, a caption and extra ``data-*`` attributes (name
    without the prefix -> value)."""

    image: bytes
    alt: str
    caption: str = ''
    attrs: dict[str, str] = field(default_factory=dict)


@dataclass
class ReportSection:
    """A section of the page: key (HTML id), title, a table of (label, value) rows, figures, notes
    (one paragraph each; ``warnings`` in the warning colour), and ``empty``: what to say when the
    run has no data for it (shown, in place of rows and figures, when it is not '')."""

    key: str
    title: str
    rows: list[tuple[str, str]] = field(default_factory=list)
    figures: list[ReportFigure] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    empty: str = ''


def _attr(name: str) -> str:
    return ''.join(c if c.isalnum() or c == '-' else '-' for c in name.lower())


def _figure_html(section: str, fig: ReportFigure) -> str:
    mime = 'image/jpeg' if fig.image[:2] == b'\xff\xd8' else 'image/png'
    data = base64.b64encode(fig.image).decode('ascii')
    extra = ''.join(f' data-{_attr(k)}="{html.escape(str(v))}"' for k, v in fig.attrs.items())
    caption = f'<figcaption>{html.escape(fig.caption)}</figcaption>' if fig.caption else ''
    return (f'<figure><img src="data:{mime};base64,{data}" alt="{html.escape(fig.alt)}" '
            f'data-figure="{html.escape(section)}"{extra}>{caption}</figure>')


def _section_html(sec: ReportSection) -> str:
    parts = [f'<section id="{html.escape(sec.key)}" data-section="{html.escape(sec.key)}" '
             f'data-figures="{0 if sec.empty else len(sec.figures)}">', f'<h2>{html.escape(sec.title)}</h2>']
    if sec.empty:
        parts.append(f'<p class="empty">{html.escape(sec.empty)}</p>')
    else:
        if sec.rows:
            parts.append('<table>' + ''.join(f'<tr><th>{html.escape(k)}</th><td>{html.escape(v)}</td></tr>'
                                             for k, v in sec.rows) + '</table>')
        parts += [f'<p class="warn">{html.escape(w)}</p>' for w in sec.warnings]
        parts += [f'<p>{html.escape(n)}</p>' for n in sec.notes]
        parts += [_figure_html(sec.key, f) for f in sec.figures]
    parts.append('</section>')
    return '\n'.join(parts)


def render_report(title: str, subtitle: str, sections: Sequence[ReportSection]) -> str:
    """The page's HTML text (UTF-8, self-contained: module docstring)."""
    nav = ' '.join(f'<a href="#{html.escape(s.key)}">{html.escape(s.title)}</a>' for s in sections)
    body = '\n'.join(_section_html(s) for s in sections)
    return ('<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
            f'<meta http-equiv="Content-Security-Policy" content="{CSP}">'
            '<meta name="viewport" content="width=device-width, initial-scale=1">'
            f'<title>{html.escape(title)}</title><style>{_CSS}</style></head><body>\n'
            f'<h1>{html.escape(title)}</h1><p class="sub">{html.escape(subtitle)}</p><nav>{nav}</nav>\n'
            f'{body}\n</body></html>\n')


def write_report_html(path: str | Path, title: str, subtitle: str, sections: Sequence[ReportSection]) -> None:
    """Write the page to ``path`` atomically (a reader never sees half a page)."""
    with atomic_path(path) as tmp:
        Path(tmp).write_text(render_report(title, subtitle, sections), encoding='utf-8')
