#!/usr/bin/env python3
"""Worst-case stack depth of the anchor core's entry points from GCC call-graph files.

    python3 tools/stack_depth.py [--limit BYTES] [--prefix pfdoa_anchor_] DIR/*.ci

Reads the `-fcallgraph-info=su` output of every core object (VCG graphs with each
function's static frame size), then takes the deepest path from each public function
whose name starts with the prefix (`pfdoa_anchor_*`, the anchor's API; `pfdoa_beacon_`
for the beacon). The core has no recursion and no dynamic stack (-Wvla); a
cycle or a dynamic frame is reported as an error. Indirect calls are the HAL callbacks:
their own stack comes on top and is the board's to bound. Library calls without a graph
(memcpy, memset, libgcc division) are listed and counted as 0.
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

NODE = re.compile(r'node: \{ title: "([^"]+)" label: "([^"]*)"')
EDGE = re.compile(r'edge: \{ sourcename: "([^"]+)" targetname: "([^"]+)"')
SIZE = re.compile(r"\\n(\d+) bytes \((static|dynamic[^)]*)\)")
# Entry points that must be among those found (the anchor's main-loop calls).
REQUIRED = ("pfdoa_anchor_init", "pfdoa_anchor_on_radio", "pfdoa_anchor_poll",
            "pfdoa_anchor_on_uart_rx", "pfdoa_anchor_on_can_rx")


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--limit", type=int, default=0, help="fail above this many bytes")
    ap.add_argument("--prefix", default="pfdoa_anchor_", help="entry points: public functions named so")
    ap.add_argument("files", nargs="+", type=Path)
    a = ap.parse_args()
    size: dict[str, int] = {}
    calls: dict[str, set[str]] = {}
    errors = []
    for f in a.files:
        text = f.read_text()
        for title, label in NODE.findall(text):
            m = SIZE.search(label)
            if m:
                if m.group(2) != "static":
                    errors.append(f"{title}: {m.group(2)} stack frame")
                size[title] = int(m.group(1))
        for src, dst in EDGE.findall(text):
            calls.setdefault(src, set()).add(dst)

    unknown: set[str] = set()

    def depth(fn: str, path: tuple[str, ...]) -> tuple[int, tuple[str, ...]]:
        if fn in path:
            errors.append("recursion: " + " -> ".join(path + (fn,)))
            return 0, path
        if fn not in size:
            if fn != "__indirect_call":
                unknown.add(fn)
            return 0, path + (fn,)
        best = (0, path + (fn,))
        for callee in sorted(calls.get(fn, ())):
            d = depth(callee, path + (fn,))
            if d[0] > best[0]:
                best = d
        return size[fn] + best[0], best[1]

    worst = 0
    entries = sorted(t for t in size if t.startswith(a.prefix) and ":" not in t)
    required = REQUIRED if a.prefix == "pfdoa_anchor_" else ()
    errors += [f"entry point {e} not found" for e in required if e not in size]
    if not entries:
        errors.append(f"no entry point named {a.prefix}*")
    for e in entries:
        d, chain = depth(e, ())
        worst = max(worst, d)
        names = [c.rsplit(":", 1)[-1] for c in chain]
        print(f"{e:32s} {d:4d} bytes  " + " -> ".join(f"{n}({size.get(c, 0)})" for n, c in zip(names, chain)))
    if unknown:
        print("counted as 0 (no call graph): " + ", ".join(sorted(unknown)))
    print(f"worst case: {worst} bytes + the deepest HAL callback")
    for err in errors:
        print("ERROR: " + err)
    if errors or (a.limit and worst > a.limit):
        if a.limit and worst > a.limit:
            print(f"FAIL: over the {a.limit}-byte stack budget")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
