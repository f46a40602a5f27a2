"""Text from data files, made inert for a Markdown page: it renders as the text it is, never as markup.

A ``result.json`` is data written by whoever made the run directory; its texts (system, metric, claim,
evidence, paper_ref...) must not become links, images, HTML or headings on the page. :func:`md_text` escapes
HTML (``& < >`` as entities, so no raw ``<script`` survives) and every Markdown construct a single line can
open; :func:`md_pre` shows a text verbatim as a preformatted block; :func:`md_link_target` makes a relative
path a link destination that cannot break out of ``(...)`` or carry a scheme.
"""

from __future__ import annotations

import html
import re
from urllib.parse import quote

# escaped with a backslash: code, emphasis, links and images, tables, headings, strikethrough, GitHub math
_SPECIAL = re.compile(r"[\\`*_\[\]|#~$(!]")
# CommonMark line endings and other control characters would end a table row or start a new block
_CONTROL = re.compile(r"[\x00-\x1f\x7f]+")
# a line that starts with these would be a list item or a setext underline
_LEADING = re.compile(r"^[-+=]|^\d+[.)]")


def md_text(value: object) -> str:
    """``value`` as one line of Markdown that renders exactly as its text (no markup of its own)."""
    text = html.escape(_CONTROL.sub(" ", str(value)), quote=False)  # & < > → entities: no tag, no <autolink>

    def escape(m: re.Match[str]) -> str:
        c, i = m.group(), m.start()
        before, after = text[i - 1:i], text[i + 1:i + 2]
        if c == "_" and before.isalnum() and after.isalnum():
            return c  # intraword (N_mov): cannot open or close emphasis
        if (c == "(" and before != "]") or (c == "!" and after != "["):
            return c  # only "](" opens a link destination and "![" an image
        return "\\" + c

    text = _SPECIAL.sub(escape, text)
    return _LEADING.sub(lambda m: m.group()[:-1] + "\\" + m.group()[-1], text)


def md_pre(value: object) -> str:
    """``value`` as a one-line HTML preformatted block (a command line: shown verbatim; control characters
    become spaces; ``& < > [ ]`` are entities, so not even the raw text reads as markup)."""
    text = html.escape(_CONTROL.sub(" ", str(value)), quote=False)
    return f"<pre><code>{text.replace('[', '&#91;').replace(']', '&#93;')}</code></pre>"


def md_link_target(relative_path: str) -> str:
    """A relative POSIX path as a link destination: every character but letters, digits, ``/ . _ - ~`` is
    percent-encoded, so it cannot close the link, start a title or name a scheme (``javascript:``)."""
    return quote(relative_path, safe="/")
