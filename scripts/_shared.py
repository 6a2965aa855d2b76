"""What several benchmark scripts share: processes from /proc, and a block of a doc between markers."""

from __future__ import annotations

import os
from pathlib import Path


def processes_where(field: int, value: int) -> list[int]:
    """PIDs of the live (not zombie) processes whose /proc/<pid>/stat field ``field`` (after the
    command name: 0 state, 1 parent, 2 process group) equals ``value``. Linux only."""
    out = []
    for d in filter(str.isdigit, os.listdir("/proc")):
        try:
            fields = Path(f"/proc/{d}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[field]) == value and fields[0] != "Z":
            out.append(int(d))
    return out


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
