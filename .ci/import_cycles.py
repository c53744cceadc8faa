#!/usr/bin/env python3
"""Import circles between the source files of src/ (the library's modules): prints each circle
and exits 1 when there is one. A file depends on another when it names an item of it
(`use crate::a::b::...`, `crate::a::b::...` in code, `super::x`, `self::x` of a sibling); a
module's `mod` declarations and its `pub use child::...` re-exports (a facade over its own
children) are not dependencies. Run from the repository root: `python3 .ci/import_cycles.py`."""
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


def resolve(parts):
    """The longest known module prefix of a path."""
    for k in range(len(parts), 0, -1):
        if tuple(parts[:k]) in files:
            return tuple(parts[:k])
    return None


def strip_comments(text):
    return "\n".join(line.split("//")[0] for line in text.split("\n"))


edges = {m: set() for m in files}
for mod, path in files.items():
    # visibility, not a path: `pub(super)`, `pub(crate)`, `pub(in crate::x)`
    text = re.sub(r"pub\((super|crate|self|in [\w:]+)\)", "pub", strip_comments(open(path).read()))
    # a facade's re-exports of its own children are not dependencies
    text = re.sub(r"pub use (self::)?(\w+)::[^;]*;", lambda m: "" if mod + (m.group(2),) in files else m.group(0), text)
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
    # `use child::...` names a submodule without a prefix (not a re-export: those went above)
    for m in re.finditer(r"\buse (\w+)::", text):
        if mod + (m.group(1),) in files:
            paths.append(["self", m.group(1)])
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
