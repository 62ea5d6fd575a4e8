"""The package's layering (docs/architecture.md): imports point one way, no import circles, no paper model imports
another paper's model. Every import counts, also the late ones inside functions (an ``ast`` walk over each file).

Each module belongs to the layer of its longest matching prefix in ``LAYERS``; a module may import its own layer
(without circles) and the layers below, never a layer above.
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

from dualtalker_lite.models import registry

PACKAGE = Path(__file__).resolve().parents[1] / "dualtalker_lite"

LAYERS = [  # lowest first
    ("foundations", ("seeding", "checks", "files", "processes", "console", "utils", "face", "audio", "prosody_features", "recogniser",
                     "front_ends", "export", "provenance", "deprecation", "ears.model", "choices")),
    ("data and blocks", ("data", "blocks", "ears")),  # ears: the student's data (reads audio, recogniser, data)
    ("models and losses", ("models", "losses")),
    ("training and evaluation", ("train", "checkpoints", "metrics")),
    ("applications", ("experiments", "inference", "streaming", "live", "commands")),
    ("visualisation", ("viz",)),
    ("front ends", ("cli", "parsers", "demo", "viz.widgets", "experiments.__main__")),
]
# the modules of the registered models (dualtalker_lite.models.registry): no one of them imports another
PAPERS = tuple(sorted({e.model_cls.__module__.partition(".")[2] for e in registry.entries().values()
                       if e.model_cls.__module__.startswith("dualtalker_lite.models.")}))


def modules(root: Path) -> dict[str, Path]:
    """Dotted name relative to the package (``models.corrtalk``; ``""`` for the package itself) -> file."""
    out = {}
    for f in sorted(root.rglob("*.py")):
        parts = f.relative_to(root).with_suffix("").parts
        out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = f
    return out


def imports(root: Path) -> dict[str, set[str]]:
    """Module -> the package modules it imports (module level or inside functions)."""
    mods, pkg = modules(root), root.name
    edges: dict[str, set[str]] = {m: set() for m in mods}
    for name, f in mods.items():
        here = name.split(".") if f.name == "__init__.py" else name.split(".")[:-1]
        here = [p for p in here if p]
        for node in ast.walk(ast.parse(f.read_text(), str(f))):
            if isinstance(node, ast.ImportFrom):
                if node.level:
                    base = here[: len(here) - node.level + 1]
                    target = ".".join(base + ([node.module] if node.module else []))
                elif (node.module or "").split(".")[0] == pkg:
                    target = node.module.partition(".")[2]
                else:
                    continue
                cands = [f"{target}.{a.name}".strip(".") for a in node.names] or [target]
                targets = [c if c in mods else target for c in cands]
            elif isinstance(node, ast.Import):
                targets = [a.name.partition(".")[2] for a in node.names if a.name.split(".")[0] == pkg]
            else:
                continue
            for t in targets:
                while t not in mods and "." in t:
                    t = t.rsplit(".", 1)[0]
                if t in mods and t != name and t != "" and not name.startswith(t + "."):
                    edges[name].add(t)
    return edges


def layer_of(module: str) -> int:
    """Index in ``LAYERS`` of the longest prefix naming ``module``; the package's __init__ is a foundation."""
    best, depth = None, -1
    for i, (_, prefixes) in enumerate(LAYERS):
        for p in prefixes:
            if (module == p or module.startswith(p + ".")) and p.count(".") > depth:
                best, depth = i, p.count(".")
    if module == "":
        return 0
    if best is None:
        raise KeyError(f"module {module!r} is in no layer: add it to LAYERS and docs/architecture.md")
    return best


def cycles(edges: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]

    def visit(v):
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
                out.append(sorted(comp))

    for v in sorted(edges):
        if v not in index:
            visit(v)
    return out


def violations(root: Path) -> list[str]:
    """Every upward import, import circle and import between two paper models of the package at ``root``."""
    edges = imports(root)
    found = []
    for a, targets in sorted(edges.items()):
        for b in sorted(targets):
            if layer_of(b) > layer_of(a):
                found.append(f"upward import: {a} ({LAYERS[layer_of(a)][0]}) imports {b} ({LAYERS[layer_of(b)][0]})")
            if a.startswith(PAPERS) and b.startswith(PAPERS) and a.split(".")[:2] != b.split(".")[:2]:
                found.append(f"paper model imports another paper's model: {a} imports {b}")
    found += [f"import circle: {' <-> '.join(c)}" for c in cycles(edges)]
    return found


def test_the_package_keeps_its_layers():
    assert violations(PACKAGE) == []


def test_every_module_has_a_layer():
    for name in modules(PACKAGE):
        layer_of(name)


def _fake_package(tmp_path: Path, files: dict[str, str]) -> Path:
    root = tmp_path / "dualtalker_lite"
    for rel, text in {"__init__.py": "", "models/__init__.py": "", "blocks/__init__.py": "", **files}.items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_text(text)
    return root


def test_the_check_catches_an_upward_late_import(tmp_path):
    root = _fake_package(tmp_path, {"blocks/decoder.py": "def f():\n    from ..train import train\n",
                                    "train.py": "from .blocks.decoder import f\n"})
    found = violations(root)
    assert "upward import: blocks.decoder (data and blocks) imports train (training and evaluation)" in found
    assert "import circle: blocks.decoder <-> train" in found


def test_the_check_catches_one_paper_importing_another(tmp_path):
    root = _fake_package(tmp_path, {"models/corrtalk.py": "from .dualtalker import DualTalker\n",
                                    "models/dualtalker.py": "import dualtalker_lite.blocks\n"})
    assert violations(root) == ["paper model imports another paper's model: models.corrtalk imports "
                                "models.dualtalker"]


def test_a_module_outside_the_layers_is_named(tmp_path):
    root = _fake_package(tmp_path, {"misc.py": ""})
    with pytest.raises(KeyError, match="module 'misc' is in no layer"):
        [layer_of(m) for m in modules(root)]


def test_the_mp4_writer_sits_below_the_commands_that_use_it():
    """The mp4 writer and its mesh renderer are exports (``export.video``, ``export.render``: foundations), so
    ``inference`` writes videos without importing the visualisation layer, which sits above the applications (its
    notebook helpers import ``inference``): ``inference -> viz`` would be an upward import."""
    edges = imports(PACKAGE)
    assert "export.video" in edges["inference"]
    assert not any(t == "viz" or t.startswith("viz.") for t in edges["inference"])
    assert edges["export.video"] <= {"files", "export.render"} and edges["export.render"] == set()
    assert layer_of("viz.animate") > layer_of("inference") > layer_of("export.video")


def test_the_check_catches_inference_importing_the_visualisation(tmp_path):
    root = _fake_package(tmp_path, {"inference.py": "from .viz.animate import render_video\n",
                                    "viz/__init__.py": "", "viz/animate.py": ""})
    assert violations(root) == ["upward import: inference (applications) imports viz.animate (visualisation)"]


def test_papers_come_from_the_registry():
    assert {"models.dualtalker", "models.corrtalk", "models.emoface", "models.faceformer",
            "models.baselines"} == set(PAPERS)


# ------------------------------------------------------------------ one idea per screen (issue 46, "Done when")
MAX_FUNCTION, MAX_CLI_FUNCTION, MAX_CLI_LINES, MAX_MODULE_DOCSTRING = 60, 40, 350, 40


def _sizes(path: Path) -> tuple[list[tuple[str, int]], int]:
    """(function name, lines from ``def`` to its last line) for every function of ``path``, and its module
    docstring's lines (0 without one)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    functions = [(f"{path.relative_to(path.parents[1])}:{n.lineno} {n.name}", n.end_lineno - n.lineno + 1)
                 for n in ast.walk(tree) if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))]
    doc = ast.get_docstring(tree, clean=False)
    return functions, 0 if doc is None else doc.count("\n") + 1


def test_one_idea_per_screen():
    """No function over 60 lines (40 in cli.py), cli.py at most 350 lines, no module docstring over 40 lines:
    measurement logs belong in docs/ or results/ (docs/design-notes.md), command logic below the command line."""
    long_functions, long_docstrings = [], []
    for path in sorted(PACKAGE.rglob("*.py")):
        functions, doc_lines = _sizes(path)
        limit = MAX_CLI_FUNCTION if path.name == "cli.py" and path.parent == PACKAGE else MAX_FUNCTION
        long_functions += [f"{name} ({n} lines > {limit})" for name, n in functions if n > limit]
        if doc_lines > MAX_MODULE_DOCSTRING:
            long_docstrings.append(f"{path.relative_to(PACKAGE.parent)} ({doc_lines} lines)")
    assert long_functions == [] and long_docstrings == []
    assert len((PACKAGE / "cli.py").read_text(encoding="utf-8").splitlines()) <= MAX_CLI_LINES


def test_the_contract_is_the_only_door():
    """Outside models/, nothing probes a model with getattr/hasattr or reads a method's signature: optional
    abilities are read through ``models.contract.hook`` (and ``contract.conditions``)."""
    probes = ("getattr(model", "hasattr(model", "inspect.signature")
    found = [f"{p.relative_to(PACKAGE.parent)}:{i}" for p in sorted(PACKAGE.rglob("*.py"))
             if "models" not in p.relative_to(PACKAGE).parts[:1]
             for i, line in enumerate(p.read_text(encoding="utf-8").splitlines(), 1) if any(s in line for s in probes)]
    assert found == []


def test_the_size_check_counts_a_long_function(tmp_path):
    """The size check itself: a 61-line function and a 41-line module docstring are counted as such."""
    path = tmp_path / "probe.py"
    path.write_text('"""' + "\n" * 40 + '"""\n\n\ndef f():\n' + "    x = 1\n" * 60, encoding="utf-8")
    functions, doc_lines = _sizes(path)
    assert [n for _, n in functions] == [61] and doc_lines == 41
