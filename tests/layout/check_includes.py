#!/usr/bin/python3
"""Checks every product file's includes against docs/ARCHITECTURE.md's table "Folders and what
each may include": a folder may include itself, the folders listed for it and, through them, what
those may include. Prints each include that reaches further (file:line, the include, the folder
and what it may include) and exits 1; exits 0 when there is none.

    tests/layout/check_includes.py [SOURCE_DIR]
"""
import os
import re
import sys

ROOT = sys.argv[1] if len(sys.argv) > 1 else os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
# Where an include "x/y.hpp" is looked up, in the order the build's include paths give.
INCLUDE_ROOTS = ["shared_model/include", "common", "firmware_rt", "host_viz"]
PRODUCT = ["shared_model", "common", "firmware_rt", "host_viz"]


def table():
    text = open(os.path.join(ROOT, "docs/ARCHITECTURE.md"), encoding="utf-8").read()
    section = text.split("## Folders and what each may include", 1)[1].split("\n## ", 1)[0]
    rows = {}
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) != 3 or not cells[0].startswith("`"):
            continue
        folder = cells[0].strip("`").rstrip("/")
        # Names in backticks; a bare "anything in `host_viz/`" allows the whole tree.
        allowed = [n.rstrip("/") for n in re.findall(r"`([^`]+)`", cells[2])]
        rows[folder] = (allowed, "anything in" in cells[2])
    return rows


def resolve(name, rows):
    """A name as the table writes it ("haptics", "common/config", "firmware_rt/servo") → folder."""
    if name in rows:
        return name
    matches = [f for f in rows if f.endswith("/" + name)]
    return matches[0] if len(matches) == 1 else None


def closure(folder, rows, seen=None):
    seen = set() if seen is None else seen
    if folder in seen:
        return seen
    seen.add(folder)
    allowed, anything = rows[folder]
    for name in allowed:
        if anything and name in ("host_viz", "common"):
            for f in rows:
                if f.startswith(name):
                    closure(f, rows, seen)
            continue
        target = resolve(name, rows)
        if target is None:
            raise SystemExit("docs/ARCHITECTURE.md: %s may include `%s`, which names no folder of the table" % (folder, name))
        closure(target, rows, seen)
    return seen


def folder_of(path, rows):
    best = None
    for f in rows:
        if path == f or path.startswith(f + "/"):
            if best is None or len(f) > len(best):
                best = f
    return best


def target_of(include, rows):
    for root in INCLUDE_ROOTS:
        candidate = os.path.join(root, include)
        if os.path.exists(os.path.join(ROOT, candidate)):
            return folder_of(candidate, rows)
    return None  # a system or third-party header


def main():
    rows = table()
    if not rows:
        raise SystemExit("docs/ARCHITECTURE.md: no table of folders found")
    problems = []
    for top in PRODUCT:
        for dirpath, _, files in os.walk(os.path.join(ROOT, top)):
            for name in files:
                if not name.endswith((".cpp", ".hpp")):
                    continue
                path = os.path.relpath(os.path.join(dirpath, name), ROOT)
                here = folder_of(path, rows)
                if here is None:
                    problems.append("%s: in no folder of docs/ARCHITECTURE.md's table" % path)
                    continue
                allowed = closure(here, rows)
                for n, line in enumerate(open(os.path.join(ROOT, path), encoding="utf-8", errors="replace"), 1):
                    m = re.match(r'\s*#\s*include\s+"([^"]+)"', line)
                    if not m:
                        continue
                    there = target_of(m.group(1), rows)
                    if there is not None and there not in allowed:
                        problems.append('%s:%d: #include "%s" is in %s/, which %s/ may not include (it may: %s)'
                                        % (path, n, m.group(1), there, here, ", ".join(sorted(allowed))))
    for p in problems:
        print(p)
    print("check_includes: %d include(s) outside the table" % len(problems))
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
