"""What several benchmark scripts share: processes from /proc (the package's), and a block of a doc
between markers."""

from __future__ import annotations

from pathlib import Path

from ilcc_graph.workers import processes_where

__all__ = ["processes_where", "write_between"]


def write_between(doc: Path, begin: str, end: str, text: str) -> None:
    """Put ``text`` between the ``begin`` and ``end`` markers of ``doc`` (appended with them if absent)."""
    body = doc.read_text() if doc.is_file() else ""
    block = f"{begin}\n{text}\n{end}"
    if begin in body and end in body:
        head, rest = body.split(begin, 1)
        body = head + block + rest.split(end, 1)[1]
    else:
        body = body.rstrip() + "\n\n" + block + "\n"
    doc.write_text(body)
