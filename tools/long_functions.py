#!/usr/bin/env python3
"""Functions longer than LIMIT lines (default 150), longest first: `python3 tools/long_functions.py [LIMIT]`
from the repository's root. Lines run from the `fn` line to its closing brace, found by counting
braces outside string and character literals and line comments; files under a `tests/` folder,
`tests.rs` files and whatever follows a top-level `#[cfg(test)]` are left out (docs/design.md 4)."""
import os
import re
import sys

FN = re.compile(r"\s*(pub(\([^)]*\))?\s+)?(async\s+)?(const\s+)?(unsafe\s+)?fn\s+(\w+)")


def code(line):
    line = re.sub(r'"([^"\\]|\\.)*"', '""', line)
    line = re.sub(r"'([^'\\]|\\.)'", "''", line)
    return line.split("//")[0]


def spans(lines):
    for i, line in enumerate(lines):
        m = FN.match(line)
        if not m:
            continue
        depth, opened = 0, False
        for j in range(i, len(lines)):
            c = code(lines[j])
            depth += c.count("{") - c.count("}")
            opened = opened or "{" in c
            if (opened and depth <= 0) or (not opened and c.rstrip().endswith(";")):
                break
        yield j - i + 1, m.group(6), i + 1


def main():
    limit = int(sys.argv[1]) if len(sys.argv) > 1 else 150
    found = []
    for folder, dirs, files in os.walk("."):
        dirs[:] = [d for d in dirs if d not in ("target", ".git", "tests")]
        for name in files:
            if not name.endswith(".rs") or name == "tests.rs":
                continue
            path = os.path.join(folder, name)[2:]
            lines = open(path, encoding="utf-8").read().split("\n")
            cut = next((k for k, l in enumerate(lines) if l.startswith("#[cfg(test)]")), len(lines))
            found += [(n, path, f, at) for n, f, at in spans(lines[:cut]) if n > limit]
    for n, path, f, at in sorted(found, reverse=True):
        print(f"{n:5d} {path}:{at} {f}")


main()
