#!/usr/bin/env python3
"""Functions longer than LIMIT lines (default 150), longest first, from the repository's root:

    python3 tools/long_functions.py [LIMIT]     exit 1 when one is found
    python3 tools/long_functions.py --top N     the N longest, whatever their length
    python3 tools/long_functions.py --lines     Rust lines per crate: code, tests, examples

Lines run from the `fn` line to its closing brace, found by counting braces outside string and
character literals and line comments. Test code is left out: files under a `tests/` folder,
`tests.rs` files and whatever follows a top-level `#[cfg(test)]` (docs/design.md 4); `--lines`
counts it apart."""
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


def rust_files():
    """Each .rs file outside target/ and .git/: (path, its lines, where its tests begin or None
    when the whole file is test code)."""
    for folder, dirs, files in os.walk("."):
        dirs[:] = sorted(d for d in dirs if d not in ("target", ".git"))
        for name in sorted(files):
            if not name.endswith(".rs"):
                continue
            path = os.path.join(folder, name)[2:]
            lines = open(path, encoding="utf-8").read().split("\n")
            if lines and lines[-1] == "":
                lines.pop()
            if name == "tests.rs" or "tests" in path.split(os.sep)[:-1]:
                yield path, lines, None
                continue
            cut = next((k for k, l in enumerate(lines) if l.startswith("#[cfg(test)]")), len(lines))
            yield path, lines, cut


def functions():
    for path, lines, cut in rust_files():
        if cut is not None:
            yield from ((n, path, f, at) for n, f, at in spans(lines[:cut]))


def lines_per_crate():
    rows = {}
    for path, lines, cut in rust_files():
        crate = path.split(os.sep)[0]
        row = rows.setdefault(crate, [0, 0, 0])
        if "examples" in path.split(os.sep)[:-1]:
            row[2] += len(lines)
        elif cut is None:
            row[1] += len(lines)
        else:
            row[0] += cut
            row[1] += len(lines) - cut
    print("crate       code  tests  examples")
    for crate, (src, tests, examples) in sorted(rows.items()):
        print(f"{crate:10s} {src:5d}  {tests:5d}  {examples:8d}")
    total = [sum(r[k] for r in rows.values()) for k in range(3)]
    print(f"{'all':10s} {total[0]:5d}  {total[1]:5d}  {total[2]:8d}")


def main():
    args = sys.argv[1:]
    if args == ["--lines"]:
        return lines_per_crate()
    found = sorted(functions(), reverse=True)
    if args[:1] == ["--top"]:
        shown, fail = found[: int(args[1])], False
    else:
        limit = int(args[0]) if args else 150
        shown = [f for f in found if f[0] > limit]
        fail = bool(shown)
    for n, path, f, at in shown:
        print(f"{n:5d} {path}:{at} {f}")
    sys.exit(1 if fail else 0)


main()
