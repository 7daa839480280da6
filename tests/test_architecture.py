"""The code's structure rules (the contracts issue): no import cycle between the project's
modules, counting imports inside functions too, and no private name (leading underscore)
imported from another module. Read from the source with ast: nothing is imported."""
import ast
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("analysis", "effects", "geometry")


def _modules():
    mods = {}
    for pkg in PACKAGES:
        for p in (ROOT / pkg).rglob("*.py"):
            name = ".".join(p.relative_to(ROOT).with_suffix("").parts)
            mods[name[:-9] if name.endswith(".__init__") else name] = p
    return mods


def _imports(path, mods):
    """(module imported, names imported from it) for every import statement of ``path``."""
    out = []
    for n in ast.walk(ast.parse(path.read_text())):
        if isinstance(n, ast.ImportFrom) and n.module and n.level == 0:
            for a in n.names:
                full = n.module + "." + a.name
                if full in mods:
                    out.append((full, None))
                elif n.module in mods:
                    out.append((n.module, a.name))
        elif isinstance(n, ast.Import):
            out += [(a.name, None) for a in n.names if a.name in mods]
    return out


def _cycles(graph):
    """Strongly connected components with more than one module (Tarjan)."""
    sys.setrecursionlimit(max(sys.getrecursionlimit(), 10000))
    index, low, stack, on, found, count = {}, {}, [], set(), [], [0]

    def visit(v):
        index[v] = low[v] = count[0]
        count[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
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
                found.append(sorted(comp))

    for v in graph:
        if v not in index:
            visit(v)
    return found


def _graph(mods):
    g = {}
    for m, p in mods.items():
        deps = {d for d, _ in _imports(p, mods)}
        # a package and its own submodules (re-exports) are one unit
        g[m] = {d for d in deps if d != m and not d.startswith(m + ".")
                and not m.startswith(d + ".")}
    return g


def test_cycle_finder_finds_a_cycle():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_cycle_between_modules():
    assert _cycles(_graph(_modules())) == []


def test_no_private_name_imported_from_another_module():
    mods = _modules()
    bad = []
    for m, p in mods.items():
        for src, name in _imports(p, mods):
            if name and name.startswith("_") and not name.startswith("__") and src != m:
                bad.append("%s imports %s from %s" % (m, name, src))
    assert bad == []


def test_figures_are_drawn_only_in_plotting():
    """Compute returns results, one output layer draws them: matplotlib is imported by
    analysis/plotting/ alone."""
    bad = []
    for name, path in _modules().items():
        if name.startswith("analysis.plotting"):
            continue
        for n in ast.walk(ast.parse(path.read_text())):
            mods = ([a.name for a in n.names] if isinstance(n, ast.Import) else
                    [n.module or ""] if isinstance(n, ast.ImportFrom) else [])
            if any(m == "matplotlib" or m.startswith("matplotlib.") for m in mods):
                bad.append(name)
    assert not bad, "matplotlib imported outside analysis/plotting: %s" % sorted(set(bad))


def _unit(name, mods):
    """A module's unit: the sub-package it lies in (analysis.kinetics.model ->
    analysis.kinetics), else the module itself."""
    parts = name.split(".")
    if len(parts) > 2 and ".".join(parts[:2]) in mods:
        return ".".join(parts[:2])
    return name


def test_no_import_cycle_counting_a_package_as_one_unit():
    """A package and the modules it imports must not import each other back through any of the
    package's modules (a cycle through a package's inside is hidden from the test above, which
    drops a package's edges to its own submodules)."""
    mods = _modules()
    g = {}
    for m, p in mods.items():
        u = _unit(m, mods)
        for d, _ in _imports(p, mods):
            v = _unit(d, mods)
            if v != u:
                g.setdefault(u, set()).add(v)
    assert _cycles(g) == []
