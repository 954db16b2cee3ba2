"""A report as a list of blocks, written both as Markdown and as one self-contained HTML file.

One source for both formats keeps them in step; the HTML inlines every figure (base64 PNG),
so it can be mailed or attached to a paper's supplementary material as a single file.
"""

from __future__ import annotations

import base64
import html
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from tactile_bench.io import atomic_write_text

_CSS = """
body { font-family: system-ui, sans-serif; max-width: 1100px; margin: 2em auto; color: #222; }
table { border-collapse: collapse; margin: 1em 0; font-size: 0.9em; }
th, td { border: 1px solid #ccc; padding: 0.3em 0.6em; text-align: left; }
th { background: #f2f2f2; }
figure { margin: 1em 0; }
figcaption { font-size: 0.85em; color: #555; }
img { max-width: 100%; }
"""


@dataclass
class Document:
    """Blocks in order: headings, paragraphs, tables and figures (PNG files)."""

    title: str
    blocks: list[tuple] = field(default_factory=list)

    def heading(self, text: str, level: int = 2) -> None:
        self.blocks.append(("heading", text, level))

    def paragraph(self, text: str) -> None:
        self.blocks.append(("paragraph", text))

    def bullets(self, items: Sequence[str]) -> None:
        self.blocks.append(("bullets", list(items)))

    def table(self, header: Sequence[str], rows: Sequence[Sequence[str]]) -> None:
        self.blocks.append(("table", list(header), [list(r) for r in rows]))

    def figure(self, path: Path, caption: str) -> None:
        self.blocks.append(("figure", Path(path), caption))

    # ------------------------------------------------------------------ writers
    def to_markdown(self, relative_to: Path) -> str:
        """Markdown; figures are linked relative to ``relative_to`` (the .md's folder)."""
        out = [f"# {self.title}", ""]
        for block in self.blocks:
            kind = block[0]
            if kind == "heading":
                out += ["#" * block[2] + " " + block[1], ""]
            elif kind == "paragraph":
                out += [block[1], ""]
            elif kind == "bullets":
                out += [f"- {item}" for item in block[1]] + [""]
            elif kind == "table":
                header, rows = block[1], block[2]
                out.append("| " + " | ".join(header) + " |")
                out.append("| " + " | ".join("---" for _ in header) + " |")
                out += ["| " + " | ".join(c.replace("|", "\\|") for c in r) + " |" for r in rows]
                out.append("")
            elif kind == "figure":
                link = _relative(block[1], relative_to)
                out += [f"![{block[2]}]({link})", "", f"*{block[2]}*", ""]
        return "\n".join(out)

    def to_html(self) -> str:
        """One HTML page with every figure inlined."""
        out = [
            "<!DOCTYPE html>",
            '<html lang="en"><head><meta charset="utf-8">',
            f"<title>{html.escape(self.title)}</title><style>{_CSS}</style></head><body>",
            f"<h1>{html.escape(self.title)}</h1>",
        ]
        for block in self.blocks:
            kind = block[0]
            if kind == "heading":
                level = min(block[2], 6)
                out.append(f"<h{level}>{html.escape(block[1])}</h{level}>")
            elif kind == "paragraph":
                out.append(f"<p>{html.escape(block[1])}</p>")
            elif kind == "bullets":
                items = "".join(f"<li>{html.escape(i)}</li>" for i in block[1])
                out.append(f"<ul>{items}</ul>")
            elif kind == "table":
                head = "".join(f"<th>{html.escape(h)}</th>" for h in block[1])
                body = "".join(
                    "<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in r) + "</tr>"
                    for r in block[2]
                )
                out.append(f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>")
            elif kind == "figure":
                data = base64.b64encode(Path(block[1]).read_bytes()).decode("ascii")
                caption = html.escape(block[2])
                out.append(
                    f'<figure><img alt="{caption}" src="data:image/png;base64,{data}">'
                    f"<figcaption>{caption}</figcaption></figure>"
                )
        out.append("</body></html>")
        return "\n".join(out)

    def write(self, markdown_path: Path, html_path: Path, links_from: Path | None = None) -> None:
        """Both files, atomically; Markdown figure links are relative to ``links_from``
        (default: the Markdown file's folder; a report published elsewhere links from there)."""
        atomic_write_text(markdown_path, self.to_markdown(links_from or markdown_path.parent))
        atomic_write_text(html_path, self.to_html())


def _relative(path: Path, start: Path) -> str:
    try:
        return path.resolve().relative_to(start.resolve()).as_posix()
    except ValueError:
        return path.as_posix()
