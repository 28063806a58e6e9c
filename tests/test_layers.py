"""The layer order of docs/architecture.md, enforced: every import in mocapfix/ (function-level ones
too) goes down the document's list of layers or stays in its folder, and no module reaches
itself again through its imports. The order is read from the document itself (its "Layers"
list), so the two cannot drift apart: to change the order, change the document.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "mocapfix"
# Beside the list: the package itself (its version) under everything, the shipped models'
# registry (pretrained/: names and files, it imports nothing of mocapfix) usable from any layer,
# and `python -m mocapfix` over the commands.
BOTTOM, TOP = {"mocapfix", "pretrained"}, {"__main__"}


def documented_layers(doc: Path = PACKAGE / "docs" / "architecture.md") -> list[str]:
    """The folders of the document's Layers list, lowest first, as the document lists them."""
    text = doc.read_text()
    block = text[text.index("Imports go down this list") :].split("\n\n", 2)[1]  # the indented list
    return re.findall(r"^      (\w+)/ ", block, flags=re.M)


def ranks() -> dict[str, int]:
    order = documented_layers()
    return {**{name: -1 for name in BOTTOM}, **{name: i for i, name in enumerate(order)}, **dict.fromkeys(TOP, 99)}


# Lightning belongs to the data module, the training modules and the commands: models/ are plain
# nn.Modules, and fills/, evaluation/ and fix/ run without it.
LIGHTNING = ("lightning", "pytorch_lightning")
LIGHTNING_LAYERS = {"data", "training", "apps"}
# Below in rank but still not to be imported: models/ know nothing of the training data.
FORBIDDEN = {("models", "data")}
# Cycles tolerated while they are taken apart (none now: fix/clips.py <-> fix/jitter_clips.py went
# with issue 46's fix/, where the jitter remover's clips borrow from report.py and joints.py).
KNOWN_CYCLES: dict[frozenset, str] = {}


def layer(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else parts[0]


def modules(package: Path = PACKAGE) -> dict[str, Path]:
    """Every module of the package by dotted name (a package by its __init__)."""
    found = {}
    for path in sorted(package.rglob("*.py")):
        parts = list(path.relative_to(package.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        found[".".join(parts)] = path
    return found


def imports(module: str, path: Path, known: dict[str, Path]) -> list[tuple[str, int]]:
    """(imported name, line) for every import statement in a module, at any depth: a mocapfix
    module resolved to the module it names (`from mocapfix.io import npz` is mocapfix.io.npz),
    anything else as its top-level package."""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    out = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out += [(a.name, node.lineno) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:  # relative: from the package, up level - 1
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(anchor + ([node.module] if node.module else []))
            for a in node.names:
                sub = f"{base}.{a.name}"
                out.append((sub if sub in known else base, node.lineno))
    named = [(name if name.split(".")[0] == "mocapfix" else name.split(".")[0], line) for name, line in out]
    return list(dict.fromkeys(named))  # `from x import a, b`: one import


def graph(package: Path = PACKAGE) -> dict[str, list[tuple[str, int]]]:
    known = modules(package)
    return {m: [(n, line) for n, line in imports(m, p, known) if n in known] for m, p in known.items()}


def wrong_way_imports(package: Path = PACKAGE) -> list[str]:
    known, bad, rank = modules(package), [], ranks()
    for m, path in known.items():
        rel = path.relative_to(package.parent)
        if layer(m) not in rank:
            bad.append(f"{rel}: mocapfix/{layer(m)}/ is in no layer (add it to docs/architecture.md's Layers)")
            continue
        for name, line in imports(m, path, known):
            if name in LIGHTNING and layer(m) not in LIGHTNING_LAYERS:
                bad.append(f"{rel}:{line} {m} imports {name} (Lightning only in {sorted(LIGHTNING_LAYERS)})")
            elif name.startswith("mocapfix") and name in known:
                if rank.get(layer(name), 99) > rank[layer(m)]:
                    bad.append(f"{rel}:{line} {m} ({layer(m)}) imports {name} ({layer(name)}), a higher layer")
                elif (layer(m), layer(name)) in FORBIDDEN:
                    never = f"{layer(m)}/ never imports {layer(name)}/"
                    bad.append(f"{rel}:{line} {m} ({layer(m)}) imports {name}: {never}")
    return bad


def cycles(package: Path = PACKAGE) -> list[list[str]]:
    """The import graph's strongly connected components with more than one module (Tarjan)."""
    edges = {m: sorted({n for n, _ in targets}) for m, targets in graph(package).items()}
    index, low, on_stack, stack, found, counter = {}, {}, set(), [], [], [0]

    def visit(v):
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on_stack.add(v)
        for w in edges[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1 or v in edges[v]:
                found.append(sorted(component))

    for v in edges:
        if v not in index:
            visit(v)
    return found


def test_imports_go_down_the_layers():
    bad = wrong_way_imports()
    assert not bad, "wrong-way imports (docs/architecture.md, Layers):\n  " + "\n  ".join(bad)


def test_no_import_cycle():
    found = [c for c in cycles() if frozenset(c) not in KNOWN_CYCLES]
    assert not found, "import cycles (function-level imports count):\n  " + "\n  ".join(" <-> ".join(c) for c in found)


def test_the_document_lists_every_folder_of_the_package_once():
    order = documented_layers()
    folders = {p.name for p in PACKAGE.iterdir() if p.is_dir() and any(p.glob("*.py"))} - BOTTOM
    assert len(order) == len(set(order)) and set(order) == folders, (order, sorted(folders))


def test_the_checker_names_a_wrong_way_import_and_a_cycle(tmp_path):
    """The checker itself, on a package made for it: an import inside a function and a relative
    one are read, a wrong-way import is named with its line, a circle of modules is found."""
    root = tmp_path / "mocapfix"
    for folder in ("models", "fix", "core"):
        (root / folder).mkdir(parents=True)
        (root / folder / "__init__.py").write_text("")
    (root / "models" / "m.py").write_text("def f():\n    from mocapfix.fix import fixers\n\nfrom ..core import a\n")
    (root / "fix" / "fixers.py").write_text("import lightning\n")
    (root / "core" / "a.py").write_text("from mocapfix.core.b import x\n")
    (root / "core" / "b.py").write_text("from . import a\n")
    bad = wrong_way_imports(root)
    assert bad == [
        "mocapfix/fix/fixers.py:1 mocapfix.fix.fixers imports lightning"
        " (Lightning only in ['apps', 'data', 'training'])",
        "mocapfix/models/m.py:2 mocapfix.models.m (models) imports mocapfix.fix.fixers (fix), a higher layer",
    ]
    assert cycles(root) == [["mocapfix.core.a", "mocapfix.core.b"]]
