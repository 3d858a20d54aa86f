"""A markdown file as one self-contained HTML page, for the MLflow UI's artifact preview.

The UI (3.x) renders a `.md` artifact without its images (an image link shows as its text) and shows an `.html`
artifact in a sandboxed frame that loads no file beside it; only images inside the page itself (data: URIs)
appear. So the report is logged twice: report.md for editors and the disk, report.html for the UI.
"""

from __future__ import annotations

import base64
import html
from pathlib import Path

IMAGE_TYPES = {".png": "image/png", ".jpg": "image/jpeg", ".jpeg": "image/jpeg", ".svg": "image/svg+xml"}
STYLE = """body{font-family:system-ui,sans-serif;margin:1.5em;max-width:1100px;color:#1f2328}
table{border-collapse:collapse;margin:0.5em 0 1.5em}th,td{border:1px solid #d0d7de;padding:3px 8px;text-align:left}
th{background:#f6f8fa}img{max-width:100%;display:block;margin:0.5em 0}code{background:#f6f8fa}"""


def inline_image(src: str, folder: Path) -> str:
    """A relative link to an image file in `folder` (not above it) as a data: URI; any other link as it is."""
    if "://" in src or src.startswith(("data:", "/")):
        return src
    path = (folder / src).resolve()
    mime = IMAGE_TYPES.get(path.suffix.lower())
    if mime is None or not path.is_file() or not path.is_relative_to(folder.resolve()):
        return src
    return f"data:{mime};base64,{base64.b64encode(path.read_bytes()).decode()}"


def html_page(md_path: str | Path, out: str | Path | None = None) -> Path:
    """Write the markdown file as HTML (tables; raw HTML in the text escaped) with its images inlined; returns
    the page's path (default: beside it, .html)."""
    from markdown_it import MarkdownIt

    md_path = Path(md_path)
    out = Path(out) if out else md_path.with_suffix(".html")
    parser = MarkdownIt("commonmark", {"html": False}).enable("table")
    tokens = parser.parse(md_path.read_text())
    for token in tokens:
        for child in token.children or []:
            if child.type == "image":
                child.attrSet("src", inline_image(str(child.attrGet("src")), md_path.parent))
    body = parser.renderer.render(tokens, parser.options, {})
    title = next((t.content for k, t in enumerate(tokens[1:]) if tokens[k].type == "heading_open"), md_path.stem)
    out.write_text(f"<!doctype html>\n<html><head><meta charset=\"utf-8\"><title>{html.escape(title)}</title>"
                   f"<style>{STYLE}</style></head>\n<body>\n{body}</body></html>\n")
    return out
