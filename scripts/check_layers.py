#!/usr/bin/python3
"""The layer map of docs/ARCHITECTURE.md, checked: which room of the tree may use which.

A room is a top-level folder, or a part of one that the picture draws apart ("render/job": the
render jobs, which read a Dataset, while the renderers need only the Point record). Every
product source file (*.cc, *.h) belongs to the most specific room that names it:
"client/client" holds client/client.{h,cc}, "client/codec_tool" everything under
client/codec_tool/, "client" the rest of client/. The checks:

  - every `#include "folder/..."` of a product file names a room its own room may use;
  - every hvdb_* library that a folder's CMakeLists.txt links (target_link_libraries), and every
    source file it compiles from another folder, belongs to a room the target's room may use
    (a library's room: that of its first source file, where add_library names it);
  - no product source file is over MAX_LINES lines;
  - the table below has no cycle, every top-level folder with C++ sources is in it, and every
    room of it holds a file.

Exit status 1 with one line per violation (file:line: what), else 0 with a one-line summary.
Run by scripts/test.sh before the build and by ctest (LayerCheck).

  /usr/bin/python3 scripts/check_layers.py            # check
  /usr/bin/python3 scripts/check_layers.py --graph    # print the rooms' actual uses
"""
import os
import re
import sys

# The picture (docs/ARCHITECTURE.md): room -> the rooms it may use. A room may always use its
# own files; nothing else is implied (not the other rooms of its folder, not what its uses use).
ALLOWED = {
    "blockcode": [],                      # the cold tier's record blocks: nothing of hvdb
    "storage": ["blockcode"],
    "formats": ["storage"],
    "codec": ["storage"],
    "edit": ["storage"],
    "render": ["formats", "storage"],     # the renderers (and request.h, a request's values)
    "media": ["storage", "edit", "formats"],   # formats: jpeg_error.h, libav.h
    "protocol": ["storage", "edit", "media", "codec", "render"],  # render: request.h's values
    "formats/point_files": ["formats", "storage", "codec", "protocol"],  # hvdb_point_files
    "render/job": ["render", "formats", "storage"],                     # hvdb_render_job
    "service/requests": ["protocol", "storage", "edit", "media"],  # the request table
    "service": ["service/requests", "protocol", "storage", "edit", "media", "render/job"],
    "client/client": ["service/requests", "protocol", "storage"],  # hvdb_connection
    "client/codec_tool": ["codec", "formats", "storage"],          # hvdb-codec
    "client": ["client/client", "service", "service/requests", "protocol", "storage", "edit",
               "media", "render", "render/job", "codec", "formats", "formats/point_files"],
    "server": ["client/client", "service", "service/requests", "protocol", "storage", "edit",
               "render", "render/job"],
    "ingest": ["client", "render", "edit", "formats", "storage"],
    "python": ["client", "render", "formats", "protocol", "storage"],
}

# Top-level folders that are not product code: never scanned, and product code must not
# include from them.
NOT_PRODUCT = {"tests", "bench", "web", "examples", "docs", "scripts", "packaging", "cmake",
               "node_modules"}
MAX_LINES = 800
SOURCE_EXT = (".cc", ".h")

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
INCLUDE = re.compile(r'^\s*#\s*include\s*"([^"]+)"')


def folders():
    return sorted({r.split("/")[0] for r in ALLOWED})


def room_of(path):
    """The room of a path relative to the root ("client/client.h" -> "client/client"), or None
    when its first component is no product folder."""
    top = path.split("/")[0]
    if top not in ALLOWED:
        return None
    stem = os.path.splitext(path)[0]
    best = top
    for room in ALLOWED:
        if "/" in room and (stem == room or path.startswith(room + "/")) and len(room) > len(best):
            best = room
    return best


def may_use(user, used):
    return used == user or used in ALLOWED[user]


def product_files():
    for top in folders():
        for dirpath, dirnames, filenames in os.walk(os.path.join(ROOT, top)):
            dirnames[:] = sorted(d for d in dirnames if d != "node_modules" and
                                 not d.startswith("build"))
            for name in sorted(filenames):
                if name.endswith(SOURCE_EXT):
                    yield os.path.relpath(os.path.join(dirpath, name), ROOT)


def check_table(errors):
    for room, uses in ALLOWED.items():
        for u in uses:
            if u not in ALLOWED:
                errors.append(f"scripts/check_layers.py: {room} uses {u}, which is no room")
    # A cycle would make "downwards" meaningless.
    state = {}

    def visit(room, trail):
        if state.get(room) == "done":
            return
        if state.get(room) == "open":
            cycle = trail[trail.index(room):] + [room]
            errors.append("scripts/check_layers.py: the table has a cycle: " + " -> ".join(cycle))
            return
        state[room] = "open"
        for u in ALLOWED.get(room, []):
            visit(u, trail + [room])
        state[room] = "done"

    for room in ALLOWED:
        visit(room, [])
    # Every top-level folder with C++ sources must be a room (or declared not product code).
    for top in sorted(os.listdir(ROOT)):
        full = os.path.join(ROOT, top)
        if (not os.path.isdir(full) or top.startswith(".") or top.startswith("build") or
                top in NOT_PRODUCT or top in ALLOWED):
            continue
        for dirpath, dirnames, filenames in os.walk(full):
            dirnames[:] = [d for d in dirnames if d != "node_modules"]
            if any(f.endswith(SOURCE_EXT) for f in filenames):
                errors.append(f"{top}/: C++ sources in a folder the layer table does not know "
                              "(add it to ALLOWED in scripts/check_layers.py and to "
                              "docs/ARCHITECTURE.md)")
                break


def check_includes(files, errors, uses):
    for path in files:
        user = room_of(path)
        with open(os.path.join(ROOT, path), encoding="utf-8", errors="replace") as f:
            lines = f.readlines()
        if len(lines) > MAX_LINES:
            errors.append(f"{path}:{len(lines)}: {len(lines)} lines, over {MAX_LINES}: split it "
                          "by concept")
        for n, line in enumerate(lines, 1):
            m = INCLUDE.match(line)
            if not m:
                continue
            target = m.group(1)
            top = target.split("/")[0]
            if "/" in target and top in NOT_PRODUCT:
                errors.append(f"{path}:{n}: includes {target}: product code must not use {top}/")
                continue
            used = room_of(target)
            if used is None:
                continue
            uses.setdefault((user, used), f"{path}:{n}")
            if not may_use(user, used):
                errors.append(f"{path}:{n}: {user} must not include {target} ({used}; "
                              f"{user} may use: {', '.join(ALLOWED[user]) or 'nothing'})")


def cmake_commands(text):
    """(name, [args], line) of each command of a CMake file, comments stripped."""
    text = re.sub(r"#[^\n]*", "", text)
    for m in re.finditer(r"\b([A-Za-z_][A-Za-z0-9_]*)\s*\(", text):
        depth, i = 1, m.end()
        while i < len(text) and depth:
            depth += {"(": 1, ")": -1}.get(text[i], 0)
            i += 1
        yield m.group(1).lower(), text[m.end():i - 1].split(), text.count("\n", 0, m.start()) + 1


TARGET_COMMANDS = {"add_library": {"STATIC", "SHARED", "MODULE", "OBJECT", "INTERFACE",
                                   "EXCLUDE_FROM_ALL"},
                   "add_executable": {"WIN32", "MACOSX_BUNDLE", "EXCLUDE_FROM_ALL"},
                   "pybind11_add_module": {"MODULE", "SHARED", "EXCLUDE_FROM_ALL", "THIN_LTO",
                                           "NO_EXTRAS", "OPT_SIZE", "WITHOUT_SOABI"}}


def source_path(folder, src):
    """A source argument of a target in `folder` as a path from the root, or None (a variable,
    a generated file)."""
    if src.startswith("${CMAKE_SOURCE_DIR}/"):
        return src[len("${CMAKE_SOURCE_DIR}/"):]
    if src.startswith("${CMAKE_CURRENT_SOURCE_DIR}/"):
        src = src[len("${CMAKE_CURRENT_SOURCE_DIR}/"):]
    if "$" in src or src.startswith("/"):
        return None
    return folder + "/" + src


def check_links(errors, uses):
    targets = {}  # name -> (room, cmake file, line)
    links = []    # (cmake file, line, target, [items])
    sources = []  # (cmake file, line, target, source path)
    for top in folders():
        cmake_files = []
        for dirpath, dirnames, filenames in os.walk(os.path.join(ROOT, top)):
            dirnames[:] = sorted(d for d in dirnames if d != "node_modules")
            cmake_files += [os.path.relpath(os.path.join(dirpath, f), ROOT) for f in filenames
                            if f == "CMakeLists.txt" or f.endswith(".cmake")]
        for cm in sorted(cmake_files):
            with open(os.path.join(ROOT, cm), encoding="utf-8") as f:
                text = f.read()
            folder = os.path.dirname(cm)
            for cmd, args, line in cmake_commands(text):
                if cmd in TARGET_COMMANDS and args:
                    name = args[0]
                    srcs = [s for s in args[1:] if s not in TARGET_COMMANDS[cmd]]
                    paths = [source_path(folder, s) for s in srcs]
                    first = next((p for p in paths if p), None)
                    targets[name] = (room_of(first) if first else top, cm, line)
                    sources += [(cm, line, name, p) for p in paths if p]
                elif cmd == "target_link_libraries" and args:
                    links.append((cm, line, args[0], args[1:]))
    for cm, line, name, path in sources:
        user, used = targets[name][0], room_of(path)
        if used is not None and not may_use(user, used):
            errors.append(f"{cm}:{line}: {name} ({user}) compiles {path} ({used})")
    for cm, line, name, items in links:
        if name not in targets:
            continue
        user = targets[name][0]
        for item in items:
            if not re.fullmatch(r"hvdb_[A-Za-z0-9_]+", item):
                continue
            if item not in targets:
                errors.append(f"{cm}:{line}: {name} links {item}, which no product folder "
                              "defines")
                continue
            used = targets[item][0]
            uses.setdefault((user, used), f"{cm}:{line}")
            if not may_use(user, used):
                errors.append(f"{cm}:{line}: {name} ({user}) must not link {item} ({used}; "
                              f"{user} may use: {', '.join(ALLOWED[user]) or 'nothing'})")
    return targets


def main():
    errors, uses = [], {}
    check_table(errors)
    files = list(product_files())
    # A room of the table that no file is in (renamed, moved) would check nothing.
    for room in sorted(set(ALLOWED) - {room_of(f) for f in files}):
        errors.append(f"scripts/check_layers.py: no product file is in the room {room}")
    check_includes(files, errors, uses)
    targets = check_links(errors, uses)
    if "--graph" in sys.argv[1:]:
        for (user, used), where in sorted(uses.items()):
            if user != used:
                print(f"{user:20} -> {used:20} (first: {where})")
    if errors:
        for e in errors:
            print(e)
        print(f"check_layers: {len(errors)} violation(s) of the layer map "
              "(docs/ARCHITECTURE.md; the table in scripts/check_layers.py)", file=sys.stderr)
        return 1
    print(f"check_layers: ok: {len(files)} files in {len(ALLOWED)} rooms, {len(targets)} CMake "
          f"targets; includes and links follow the layer map, no file over {MAX_LINES} lines")
    return 0


if __name__ == "__main__":
    sys.exit(main())
