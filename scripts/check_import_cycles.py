#!/usr/bin/env python3
"""Check that the Rust modules under a folder import each other in no circle (issue 40: src/recon).

Usage: ``python3 scripts/check_import_cycles.py [ROOT] [--module PATH] [--print]``

ROOT (default ``src/recon``) is a module folder; PATH its module path below the crate root (default: the
parts of ROOT after ``src``, e.g. ``recon``). Every ``.rs`` file is a node (``mod.rs`` is its folder's
module). An edge A → B is a reference in A's code to an item of B: ``use`` statements (braces expanded) and
paths written inline (``super::gap::gap(..)``), through ``crate::``, ``super::`` and ``self::``. A name that a
module only re-exports (``pub use x::Name``) resolves to the module that defines it, so a facade such as
``recon/mod.rs`` is no hub; ``mod`` declarations are containment, not imports. Comments, strings and inline
``mod name { .. }`` blocks (the unit tests, whose ``super`` is their own file) are left out.

Exit status 0 with no circle, 1 with one (each circle printed, ``a.rs → b.rs → a.rs``), 2 for a usage error.
``--print`` lists every edge. Run by tests/recon_import_graph.rs.
"""
import os
import re
import sys


def strip_code(text):
    """The code of a Rust file without comments, string/char literals and inline `mod x { .. }` blocks."""
    out = []
    i, n = 0, len(text)
    while i < n:
        c = text[i]
        if text.startswith("//", i):
            j = text.find("\n", i)
            i = n if j < 0 else j
        elif text.startswith("/*", i):
            depth, i = 1, i + 2
            while i < n and depth:
                if text.startswith("/*", i):
                    depth, i = depth + 1, i + 2
                elif text.startswith("*/", i):
                    depth, i = depth - 1, i + 2
                else:
                    i += 1
        elif c == "r" and re.match(r'r#*"', text[i:i + 10]) and (i == 0 or not (text[i - 1].isalnum() or text[i - 1] == "_")):
            m = re.match(r'r(#*)"', text[i:])
            end = text.find('"' + m.group(1), i + len(m.group(0)))
            out.append('""')
            i = n if end < 0 else end + 1 + len(m.group(1))
        elif c == '"':
            i += 1
            while i < n and text[i] != '"':
                i += 2 if text[i] == "\\" else 1
            out.append('""')
            i += 1
        elif c == "'" and re.match(r"'(\\.|[^\\'])'", text[i:i + 4]) or text.startswith("'\\u{", i):
            j = text.find("'", i + 1 + (1 if text[i + 1] == "\\" else 0))
            out.append("' '")
            i = j + 1
        else:
            out.append(c)
            i += 1
    code = "".join(out)
    # Inline modules (`mod tests { .. }`): removed with their braces.
    while True:
        m = re.search(r"\bmod\s+\w+\s*\{", code)
        if not m:
            return code
        depth, j = 0, m.end() - 1
        while j < len(code):
            depth += {"{": 1, "}": -1}.get(code[j], 0)
            j += 1
            if depth == 0:
                break
        code = code[:m.start()] + code[j:]


def expand_use(tree):
    """`a::{b, c::{d, e@f}}` → [(['a','b'], 'b'), (['a','c','d'], 'd'), (['a','c','e@f'], 'e@f')] (`@`: an alias, split by the caller)."""
    tree = re.sub(r"\s+", "", tree)
    if "{" not in tree:
        parts = tree.split("::")
        return [(parts, parts[-1])]
    k = tree.index("{")
    prefix = [p for p in tree[:k].split("::") if p]
    inner = tree[k + 1:tree.rindex("}")]
    items, depth, cur = [], 0, ""
    for ch in inner:
        if ch == "," and depth == 0:
            items.append(cur)
            cur = ""
            continue
        depth += {"{": 1, "}": -1}.get(ch, 0)
        cur += ch
    items.append(cur)
    res = []
    for it in items:
        if not it:
            continue
        for path, name in expand_use(it):
            res.append((prefix + path if path != ["self"] else prefix, name if path != ["self"] else prefix[-1]))
    return res


def use_statements(code):
    """(is_pub, expanded paths) of every `use` statement (aliases `x as y` keep the alias as the name)."""
    res = []
    for m in re.finditer(r"\b(pub(?:\([^)]*\))?\s+)?use\s+([^;]+);", code):
        body = re.sub(r"\s+as\s+(\w+)", r"@\1", m.group(2))
        pairs = []
        for path, name in expand_use(body):
            last = path[-1]
            if "@" in last:
                last, alias = last.split("@", 1)
                path = path[:-1] + [last]
                name = alias
            pairs.append((path, name))
        res.append((bool(m.group(1)), pairs))
    return res


def module_of(rel, base):
    parts = rel[:-3].split(os.sep)
    if parts[-1] == "mod":
        parts = parts[:-1]
    return tuple(base + parts)


def absolute(path, here, is_dir_module):
    """The absolute module path of a `crate::`/`super::`/`self::` path written in module `here`."""
    if not path:
        return None
    if path[0] == "crate":
        return list(path[1:])
    if path[0] in ("super", "self"):
        cur = list(here)
        i = 0
        while i < len(path) and path[i] in ("super", "self"):
            if path[i] == "super":
                cur = cur[:-1]
            i += 1
        return cur + list(path[i:])
    return None


def main(argv):
    args = [a for a in argv if not a.startswith("--")]
    show = "--print" in argv
    module = None
    if "--module" in argv:
        k = argv.index("--module")
        if k + 1 >= len(argv):
            print("--module needs a module path, e.g. recon", file=sys.stderr)
            return 2
        module = argv[k + 1]
        args = [a for a in args if a != module]
    root = args[0] if args else "src/recon"
    if not os.path.isdir(root):
        print(f"{root}: not a folder", file=sys.stderr)
        return 2
    if module is None:
        parts = os.path.normpath(os.path.abspath(root)).split(os.sep)
        if "src" not in parts:
            print(f"{root}: not below a src/ folder; give --module", file=sys.stderr)
            return 2
        module = "::".join(parts[len(parts) - 1 - parts[::-1].index("src") + 1:])
    base = [p for p in module.split("::") if p]
    files = {}
    for d, _, names in os.walk(root):
        for f in names:
            if f.endswith(".rs"):
                p = os.path.join(d, f)
                files[module_of(os.path.relpath(p, root), base)] = p
    code = {m: strip_code(open(p, encoding="utf-8").read()) for m, p in files.items()}
    uses = {m: use_statements(c) for m, c in code.items()}
    # Re-exports: module → {name: absolute path of the item}.
    reexports = {}
    for m, stmts in uses.items():
        table = {}
        for is_pub, pairs in stmts:
            if not is_pub:
                continue
            for path, name in pairs:
                a = absolute(path, m, True)
                if a is None and path and path[0] not in ("std", "core", "alloc"):
                    a = list(m) + list(path)  # `pub use solver::X` inside a module: relative (2018 edition)
                if a:
                    table[name] = a
        reexports[m] = table

    def resolve(a, depth=0):
        """The module (a key of `files`) defining the item at absolute path `a`, or None outside ROOT."""
        for k in range(len(a), 0, -1):
            m = tuple(a[:k])
            if m in files:
                rest = a[k:]
                if rest and depth < 16 and rest[0] in reexports.get(m, {}):
                    target = reexports[m][rest[0]] + rest[1:]
                    if target != list(a):
                        return resolve(target, depth + 1)
                return m
        return None

    edges = {m: set() for m in files}
    for m, c in code.items():
        paths = []
        for is_pub, pairs in uses[m]:
            for path, _ in pairs:
                a = absolute(path, m, True)
                if a is None and path and path[0] not in ("std", "core", "alloc") and tuple(list(m) + [path[0]]) in files:
                    a = list(m) + list(path)  # `use child::X` (relative to this module)
                if a is not None:
                    paths.append(a)
        no_use = re.sub(r"\b(pub(?:\([^)]*\))?\s+)?use\s+[^;]+;", "", c)
        for ref in re.finditer(r"\b((?:crate|super|self)(?:\s*::\s*\w+)+)", no_use):
            segs = [s.strip() for s in ref.group(1).split("::")]
            a = absolute(segs, m, True)
            if a is not None:
                paths.append(a)
        for a in paths:
            t = resolve(a)
            if t is not None and t != m:
                edges[m].add(t)

    def name(m):
        return os.path.relpath(files[m], os.path.dirname(os.path.normpath(root)))

    if show:
        for m in sorted(edges):
            for t in sorted(edges[m]):
                print(f"{name(m)} -> {name(t)}")
    # Tarjan's strongly connected components: a component of two or more files is an import circle.
    index, low, stack, on, comps, counter = {}, {}, [], set(), [], [0]

    def strong(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(edges[v]):
            if w not in index:
                strong(w)
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
            comps.append(comp)

    sys.setrecursionlimit(10000)
    for v in sorted(edges):
        if v not in index:
            strong(v)
    circles = [c for c in comps if len(c) > 1]
    n_edges = sum(len(e) for e in edges.values())
    if not circles:
        print(f"{root}: {len(files)} modules, {n_edges} import edges, no circle")
        return 0
    for comp in circles:
        members = set(comp)
        # One concrete circle through the component: a path back to its first member.
        start = sorted(comp)[0]
        prev, queue, seen = {}, [start], {start}
        found = None
        while queue and found is None:
            v = queue.pop(0)
            for w in sorted(edges[v]):
                if w == start:
                    found = v
                    break
                if w in members and w not in seen:
                    seen.add(w)
                    prev[w] = v
                    queue.append(w)
        cyc = [start]
        v = found
        while v is not None and v != start:
            cyc.insert(1, v)
            v = prev.get(v)
        print("import circle: " + " → ".join(name(x) for x in cyc + [start]))
    print(f"{root}: {len(circles)} import circle(s) among {len(files)} modules")
    return 1


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
