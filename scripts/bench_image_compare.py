"""Two runs of scripts/bench_image.py side by side (issue 37: accuracy before and after a change of the
image stage): per set, boards found, corner RMS / median / max error against the true projection, NEES
and the time per image, and the RMS ratio after / before against the issue's bound (within 10 %).

    python scripts/bench_image_compare.py BEFORE.md AFTER.md [--label-before X] [--label-after Y] [--write]

``--write`` puts the table into docs/bench_speed.md as its own section (replacing an older one).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from bench_speed import DOC, replace_section  # (scripts/ is the running script's folder)

HEADING = "\n## Accuracy of the image stage before and after the cheap search (scripts/bench_image.py)\n"


def rows(path: Path) -> dict[str, dict[str, str]]:
    """The table of a bench_image.py markdown file: set name -> column -> cell."""
    lines = [ln for ln in path.read_text().splitlines() if ln.startswith("| ")]
    keys = [k.strip() for k in lines[0].strip("|").split("|")]
    out = {}
    for ln in lines[1:]:
        cells = [c.strip() for c in ln.strip("|").split("|")]
        out[cells[0]] = dict(zip(keys, cells, strict=True))
    return out


def _num(cell: str) -> float | None:
    try:
        return float(cell.split()[0])
    except (ValueError, IndexError):
        return None


def table(before: dict, after: dict) -> tuple[str, list[str]]:
    head = ["set", "found", "RMS px", "after / before", "median px", "max px", "NEES", "s/image mean"]
    out = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    worse = []
    for name, a in after.items():
        b = before.get(name)
        if b is None:
            continue
        ra, rb = _num(a.get("RMS px", "-")), _num(b.get("RMS px", "-"))
        ratio = f"{ra / rb:.3f}" if ra is not None and rb else "-"
        if ra is not None and rb and ra / rb > 1.10:
            worse.append(f"{name}: RMS {rb:.3f} -> {ra:.3f} px")
        if int(a["found"].split("/")[0]) < int(b["found"].split("/")[0]):
            worse.append(f"{name}: found {b['found']} -> {a['found']}")
        cells = [name] + [f"{b.get(k, '-')} -> {a.get(k, '-')}" for k in ("found", "RMS px")] + [ratio]
        cells += [
            f"{b.get(k, '-')} -> {a.get(k, '-')}" for k in ("median px", "max px", "NEES", "s/image mean")
        ]
        out.append("| " + " | ".join(cells) + " |")
    return "\n".join(out), worse


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("before", type=Path)
    ap.add_argument("after", type=Path)
    ap.add_argument("--label-before", default="before")
    ap.add_argument("--label-after", default="after")
    ap.add_argument("--write", action="store_true")
    args = ap.parse_args(argv)
    text, worse = table(rows(args.before), rows(args.after))
    verdict = (
        "Every simulated set's corner RMS within 10 % of before and no board lost."
        if not worse
        else "Outside the bound: " + "; ".join(worse) + "."
    )
    section = (
        HEADING + "\n"
        f"`nice python scripts/bench_image.py --frames 20 --seed 0` with {args.label_before} and with "
        f"{args.label_after}, each cell before -> after (`scripts/bench_image_compare.py`). Errors are "
        "against the simulator's true projection (up to the half turn of a symmetric board); "
        "recorded sets: boards found only. Times per image were measured on a shared machine at "
        "different moments and compare poorly.\n\n" + text + "\n\n" + verdict + "\n"
    )
    print(section)
    if args.write:
        replace_section(HEADING, section)
        print(f"wrote {DOC}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
