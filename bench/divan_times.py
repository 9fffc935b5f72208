#!/usr/bin/env python3
"""Read divan's table from stdin and print one benchmark's times in seconds.

    cargo bench -p ilqr --bench solver -- seed | python3 bench/divan_times.py seed_solve/new_solver
    -> fastest=0.00104 slowest=0.001855 median=0.001423 mean=0.001439 samples=100

A row is named by its path in the tree without the file's root
(`request/lean/t=2`, `backward/full_pass_n100`). With --field NAME only that
value is printed (e.g. `--field median`). Exits 1 if the row is not found.
Standard library only, so it runs without the bench venv.
"""

from __future__ import annotations

import re
import sys

UNITS = {"ps": 1e-12, "ns": 1e-9, "µs": 1e-6, "us": 1e-6, "ms": 1e-3, "s": 1.0}
FIELDS = ("fastest", "slowest", "median", "mean", "samples", "iters")
ROW = re.compile(r"[├╰]─ (\S+)")


def rows(text: str) -> dict[str, dict[str, float]]:
    """Every timed row of a divan table, by path."""
    out: dict[str, dict[str, float]] = {}
    stack: list[tuple[int, str]] = []  # (column of the branch glyph, name)
    for line in text.splitlines():
        m = ROW.search(line)
        if not m:
            continue
        col, name = m.start(), m.group(1)
        while stack and stack[-1][0] >= col:
            stack.pop()
        stack.append((col, name))
        cells = [c.strip() for c in line[m.end():].split("│")]
        if len(cells) < len(FIELDS) or not cells[0]:
            continue  # a group row: no numbers
        values: dict[str, float] = {}
        for field, cell in zip(FIELDS, cells):
            parts = cell.split()
            if len(parts) == 2 and parts[1] in UNITS:
                values[field] = float(parts[0]) * UNITS[parts[1]]
            elif len(parts) == 1:
                values[field] = float(parts[0])
        out["/".join(n for _, n in stack)] = values
    return out


def main() -> int:
    args = sys.argv[1:]
    field = None
    if len(args) >= 2 and args[0] == "--field":
        field, args = args[1], args[2:]
    if len(args) != 1:
        print(__doc__, file=sys.stderr)
        return 2
    table = rows(sys.stdin.read())
    row = table.get(args[0])
    if row is None:
        print(f"no row {args[0]!r}; rows: {', '.join(table) or 'none'}", file=sys.stderr)
        return 1
    if field is not None:
        print(f"{row[field]:.9g}")
    else:
        print(" ".join(f"{k}={v:.9g}" for k, v in row.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
