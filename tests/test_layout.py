"""The package's shape: functions a reader can see whole, modules without import circles, and
layers that import only downwards.

The floors, lowest first (a module may import its own floor and those below, never above):

    0  jaxlc.config        the validated edge every layer reads; imports no jaxlc module but
                           jaxlc.sim.params, the declaration of its [env] keys
    0  jaxlc.paper         the paper's grid and claims, a plug-in; imports nothing outside it
    1  jaxlc.sim           the simulator
    2  jaxlc.learn         DDPG and the training grid
    3  jaxlc.study         run directory, checkpoints, tracking, the machine
    4  jaxlc.evaluation    cases, results, statistics
    5  jaxlc.report        report.md and the figures, drawn from the evaluation's records
    6  top level           the commands and the public API (``TOP_LEVEL``)
"""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent.parent / "jaxlc"
MAX_LINES = 80

FLOORS = {"config": 0, "paper": 0, "sim": 1, "learn": 2, "study": 3, "evaluation": 4}
FLOORS["report"] = 5
TOP = 6
# The package root (jaxlc/__init__.py) and the modules beside it: commands and public API only.
TOP_LEVEL = {
    "jaxlc",
    "jaxlc.evaluate",
    "jaxlc.export",
    "jaxlc.figures",
    "jaxlc.gym",
    "jaxlc.gymnax_env",
    "jaxlc.policy",
    "jaxlc.sweep",
    "jaxlc.validate",
}
# Upward imports allowed by name, each with its reason; an entry no module makes fails a test.
EXCEPTIONS = {
    ("jaxlc.study.checkpoint", "jaxlc"): "reads jaxlc.__version__ (deferred) for the metadata",
    ("jaxlc.config", "jaxlc.sim.params"): "[env] is EnvParams' declaration: one per setting",
}


def _name(path: Path) -> str:
    """Dotted module name: ``jaxlc/sim/env.py`` -> ``jaxlc.sim.env``, ``jaxlc/sim/__init__.py``
    -> ``jaxlc.sim``."""
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _trees() -> dict[str, ast.Module]:
    """Every module of the package, subpackages included."""
    return {_name(p): ast.parse(p.read_text(encoding="utf-8")) for p in PACKAGE.rglob("*.py")}


def _floor(module: str) -> int:
    parts = module.split(".")
    return FLOORS.get(parts[1], TOP) if len(parts) > 1 else TOP


def test_no_function_is_longer_than_a_screen():
    long = [
        f"{name}.{node.name}: {node.end_lineno - node.lineno + 1} lines"
        for name, tree in _trees().items()
        for node in ast.walk(tree)
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef)
        and node.end_lineno - node.lineno + 1 > MAX_LINES
    ]
    assert not long, long


def _imports(tree: ast.Module, name: str, modules: set[str]) -> set[str]:
    """jaxlc modules a module imports, at its top or inside a function (full dotted names;
    ``from jaxlc.sim import env`` is ``jaxlc.sim.env``, ``import jaxlc`` the package root)."""
    packages = {_name(p) for p in PACKAGE.rglob("__init__.py")}
    package = name if name in packages else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:  # relative: resolve against this module's package
                up = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(up + ([base] if base else []))
            for alias in node.names:
                sub = f"{base}.{alias.name}"
                found.add(sub if sub in modules else base)
        elif isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names}
    return found & modules


def _graph() -> dict[str, set[str]]:
    trees = _trees()
    modules = set(trees)
    return {m: _imports(trees[m], m, modules) - {m} for m in modules}


def test_no_import_circle():
    graph = _graph()
    done: set[str] = set()

    def visit(m: str, path: list[str]) -> None:
        if m in path:
            raise AssertionError("import circle: " + " -> ".join(path[path.index(m) :] + [m]))
        if m in done:
            return
        for n in sorted(graph[m]):
            visit(n, path + [m])
        done.add(m)

    for m in sorted(graph):
        visit(m, [])


def test_no_module_imports_a_layer_above_its_own():
    """config < sim < learn < study < evaluation < the top-level commands and API."""
    upward = [
        f"{m} (floor {_floor(m)}) imports {n} (floor {_floor(n)})"
        for m, imported in sorted(_graph().items())
        for n in sorted(imported)
        if _floor(n) > _floor(m) and (m, n) not in EXCEPTIONS
    ]
    assert not upward, upward


def test_every_exception_is_still_needed():
    graph = _graph()
    stale = [edge for edge in EXCEPTIONS if edge[1] not in graph.get(edge[0], set())]
    assert not stale, stale


def test_config_imports_no_jaxlc_module():
    """Only the env's settings, declared once in ``EnvParams``; that module imports no config
    (the circle test) and nothing of the sim but the reward's terms it names."""
    graph = _graph()
    assert graph["jaxlc.config"] == {"jaxlc.sim.params"}
    assert graph["jaxlc.sim.params"] == {"jaxlc.sim.reward"}
    assert graph["jaxlc.sim.reward"] == set()


def test_the_paper_imports_nothing_outside_it():
    graph = _graph()
    paper = {m for m in graph if m.startswith("jaxlc.paper")}
    assert paper and all(graph[m] <= paper for m in paper), {m: graph[m] for m in paper}


def test_the_import_graph_sees_every_form_of_import():
    """The checks above are only as good as the graph: known edges of each form are in it."""
    graph = _graph()
    assert "jaxlc.sim.env" in graph["jaxlc"]  # from jaxlc.sim.env import ...
    assert "jaxlc.sim.reward" in graph["jaxlc.sim.env"]  # from jaxlc.sim import reward
    assert "jaxlc.config" in graph["jaxlc.sim.env"]  # from jaxlc import config (in a function)
    assert "jaxlc.sim.env" in graph["jaxlc.learn.train"]
    assert "jaxlc.learn.tree" in graph["jaxlc.evaluation.engine"]  # from jaxlc.learn import tree
    assert "jaxlc.report.report" in graph["jaxlc.evaluate"]  # deferred, in a function
    assert "jaxlc" in graph["jaxlc.study.checkpoint"]  # import jaxlc


def test_the_top_level_is_the_commands_and_the_public_api():
    """Everything else lives in a layer folder; a new folder needs its floor in ``FLOORS``."""
    assert {m for m in _trees() if _floor(m) == TOP} == TOP_LEVEL


def test_every_layer_is_a_package_that_says_what_it_may_import():
    trees = _trees()
    for layer in FLOORS.keys() - {"config"}:
        doc = ast.get_docstring(trees[f"jaxlc.{layer}"]) or ""
        assert "Imports:" in doc, layer
        assert any(m.startswith(f"jaxlc.{layer}.") for m in trees), f"{layer} has no modules"
    folders = {p.parent for p in PACKAGE.rglob("*.py")}
    assert all((d / "__init__.py").is_file() for d in folders), folders


# The command modules: the library and the benchmarks never import them; each parses its
# arguments and calls into the library, in at most COMMAND_LINES.
COMMANDS = {"jaxlc.sweep", "jaxlc.evaluate", "jaxlc.figures", "jaxlc.export", "jaxlc.validate"}
COMMAND_LINES = 200


def test_commands_are_thin():
    path = {m: PACKAGE.parent / (m.replace(".", "/") + ".py") for m in COMMANDS}
    sizes = {m: len(p.read_text(encoding="utf-8").splitlines()) for m, p in path.items()}
    assert all(n <= COMMAND_LINES for n in sizes.values()), sizes


def test_nothing_imports_a_command():
    graph = _graph()
    users = {m: graph[m] & COMMANDS for m in graph if graph[m] & COMMANDS}
    assert not users, users
    modules = set(graph)
    for path in sorted((PACKAGE.parent / "benchmarks").rglob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"))
        found = _imports(tree, "benchmarks." + path.stem, modules | COMMANDS)
        assert not found & COMMANDS, f"{path.name} imports {found & COMMANDS}"


# benchmarks/: a package of scripts, each ``python -m benchmarks.NAME``; the folders beside
# them are evidence and hold no code. Helpers that are not commands, by name.
BENCHMARKS = PACKAGE.parent / "benchmarks"
BENCHMARK_HELPERS = {"__init__"}


def _edits_sys_path(tree: ast.Module) -> bool:
    """Whether a module touches the import path (``sys`` ``.path``) in code; a mention in a
    string does not count."""
    return any(
        isinstance(node, ast.Attribute)
        and node.attr == "path"
        and isinstance(node.value, ast.Name)
        and node.value.id == "sys"
        for node in ast.walk(tree)
    )


def test_the_benchmarks_are_a_package_with_no_code_in_their_evidence():
    scripts = sorted(BENCHMARKS.glob("*.py"))
    assert (BENCHMARKS / "__init__.py").is_file()  # tables/: a namespace package
    code = sorted(BENCHMARKS.rglob("*.py"))
    in_evidence = [p for p in code if p.parent not in (BENCHMARKS, BENCHMARKS / "tables")]
    assert not in_evidence, in_evidence
    commands = [p for p in scripts if p.stem not in BENCHMARK_HELPERS]
    for path in commands:
        text = path.read_text(encoding="utf-8")
        assert 'if __name__ == "__main__":' in text and "argparse" in text, path.name


def test_no_script_or_test_edits_sys_path():
    paths = [*BENCHMARKS.rglob("*.py"), *(PACKAGE.parent / "tests").rglob("*.py")]
    edits = [p.name for p in paths if _edits_sys_path(ast.parse(p.read_text(encoding="utf-8")))]
    assert not edits, edits
    # the check sees one (spelt in two parts so that a text search of tests/ finds no edit)
    assert _edits_sys_path(ast.parse("import sys\nsys" + ".path.insert(0, 'x')"))
