#!/usr/bin/env python3
"""Import circles between the source files of src/ (the library's modules): prints each circle
and exits 1 when there is one. A file depends on another when it names an item of it
(`use crate::a::b::...`, `crate::a::b::...` in code, `super::x`, `self::x`, `child::x`), a
parent on its children and a child on its parent alike: a module's `mod` declarations are not
dependencies, but its `pub use child::...` re-exports are (a parent that re-exports a child which
imports the parent back is a circle). A name a module re-exports from a child (`pub use
child::Name`, `pub use child::*`) is resolved to that child, so `crate::a::Name` depends on the
child that defines `Name`, not on `a`. A file's unit tests (`#[cfg(test)] mod tests`) are left out. Run from the repository root: `python3 .ci/import_cycles.py`."""
import os
import re
import sys

ROOT = "src"


def module_of(path):
    """`src/io/node/mod.rs` -> ('io', 'node'); `src/io/msg.rs` -> ('io', 'msg')."""
    rel = os.path.relpath(path, ROOT)[:-3].split(os.sep)
    if rel[-1] in ("mod", "lib"):
        rel = rel[:-1]
    return tuple(rel)


files = {}
for d, _, names in os.walk(ROOT):
    if d.startswith(os.path.join(ROOT, "bin")):
        continue
    for n in names:
        if n.endswith(".rs"):
            p = os.path.join(d, n)
            files[module_of(p)] = p


def strip_comments(text):
    """The code of a file without its comments and its unit tests (an inline `#[cfg(test)] mod
    tests { ... }`, whose `super::*` is the file itself: tests are not the library's imports)."""
    text = re.split(r"^#\[cfg\(test\)\]\s*\nmod \w+ \{", text, maxsplit=1, flags=re.M)[0]
    return "\n".join(line.split("//")[0] for line in text.split("\n"))


def public_names(path):
    """The names a file defines publicly (`pub fn x`, `pub struct X`, ...)."""
    text = strip_comments(open(path).read())
    return set(re.findall(r"^pub(?:\([^)]*\))? (?:fn|struct|enum|const|static|type|trait|mod) (\w+)", text, re.M))


# names each module re-exports from its children: (module, name) -> child module
reexports = {}
for mod, path in files.items():
    text = strip_comments(open(path).read())
    for m in re.finditer(r"pub use (?:self::)?(\w+)::([^;]*);", text):
        child = mod + (m.group(1),)
        if child not in files:
            continue
        body = m.group(2).strip()
        if body == "*":
            names = public_names(files[child])
        else:
            body = body.strip("{}")
            names = set()
            for item in body.split(","):
                item = item.strip()
                if not item:
                    continue
                names.add(item.split(" as ")[-1].split("::")[-1].strip())
        for n in names:
            reexports[(mod, n)] = child


def resolve(parts):
    """The module a path names: its longest known module prefix, followed through re-exports."""
    for k in range(len(parts), 0, -1):
        prefix = tuple(parts[:k])
        if prefix in files:
            while k < len(parts) and (prefix, parts[k]) in reexports:
                prefix = reexports[(prefix, parts[k])]
            return prefix
    return None


edges = {m: set() for m in files}
for mod, path in files.items():
    # visibility, not a path: `pub(super)`, `pub(crate)`, `pub(in crate::x)`
    text = re.sub(r"pub\((super|crate|self|in [\w:]+)\)", "pub", strip_comments(open(path).read()))
    # expand use-groups one level: `use crate::a::{b, c::d}` -> paths
    paths = []
    for m in re.finditer(r"\b(crate|super|self)((?:::\w+)*)(::\{([^}]*)\}|::\*)?", text):
        base = [m.group(1)] + [x for x in m.group(2).split("::") if x]
        if m.group(3) == "::*" or (m.group(1) == "super" and len(base) == 1):
            paths.append(base)
            continue
        if m.group(4) is not None:
            for item in m.group(4).split(","):
                item = item.strip().split(" as ")[0]
                if item and item != "self":
                    paths.append(base + item.split("::"))
        paths.append(base)
    # `child::...` (in a `use`, a `pub use` re-export, or in code) names a submodule without a prefix
    for m in re.finditer(r"(?<![:\w])(\w+)::(\{[^}]*\}|\w+)", text):
        if mod + (m.group(1),) in files:
            rest = m.group(2)
            if rest.startswith("{"):
                for item in rest.strip("{}").split(","):
                    item = item.strip().split(" as ")[0]
                    if item and item != "self":
                        paths.append(["self", m.group(1)] + item.split("::"))
            else:
                paths.append(["self", m.group(1), rest])
    for p in paths:
        if p[0] == "crate":
            target = resolve(p[1:])
        elif p[0] == "super":
            target = resolve(list(mod[:-1]) + p[1:])
        else:  # self
            target = resolve(list(mod) + p[1:])
        if target and target != mod and target != ():
            edges[mod].add(target)

# strongly connected components (Tarjan)
index, low, stack, on, sccs = {}, {}, [], set(), []


def visit(v, counter=[0]):
    index[v] = low[v] = counter[0]
    counter[0] += 1
    stack.append(v)
    on.add(v)
    for w in edges[v]:
        if w not in index:
            visit(w)
            low[v] = min(low[v], low[w])
        elif w in on:
            low[v] = min(low[v], index[w])
    if low[v] == index[v]:
        comp = []
        while True:
            w = stack.pop()
            on.discard(w)
            comp.append(w)
            if w == v:
                break
        if len(comp) > 1:
            sccs.append(comp)


sys.setrecursionlimit(10000)
for v in sorted(edges):
    if v not in index:
        visit(v)
name = lambda m: "::".join(m) or "crate"
for comp in sccs:
    members = set(comp)
    print("import circle: " + ", ".join(sorted(name(m) for m in comp)))
    for m in sorted(comp):
        print("  " + name(m) + " -> " + ", ".join(sorted(name(t) for t in edges[m] if t in members)))
print(f"{len(files)} modules, {sum(len(e) for e in edges.values())} dependencies, {len(sccs)} circles")
sys.exit(1 if sccs else 0)
