"""The package's shape: no import cycles, no private names used across modules, every module importable alone."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src"


def _modules() -> dict[str, Path]:
    out = {}
    for p in sorted((SRC / "pbicrl").rglob("*.py")):
        parts = list(p.relative_to(SRC).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = p
    return out


MODULES = _modules()


def _is_type_checking(node: ast.AST) -> bool:
    return isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test)


def _imports(path: Path, *, lazy: bool) -> set[str]:
    """pbicrl modules that ``path`` imports at module level (and, with ``lazy``, inside functions too).

    ``from pbicrl.a import b`` counts as importing ``pbicrl.a.b`` where that is a module, else ``pbicrl.a``;
    ``if TYPE_CHECKING:`` blocks do not count.
    """
    found: set[str] = set()

    def visit(nodes: list[ast.stmt], in_function: bool) -> None:
        for node in nodes:
            if _is_type_checking(node):
                continue
            if isinstance(node, ast.Import):
                found.update(a.name for a in node.names if a.name in MODULES and (lazy or not in_function))
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").startswith("pbicrl"):
                if lazy or not in_function:
                    for a in node.names:
                        full = f"{node.module}.{a.name}"
                        found.add(full if full in MODULES else node.module)
            inner = in_function or isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
            for field in ("body", "orelse", "finalbody", "handlers"):
                block = getattr(node, field, None)
                if isinstance(block, list):
                    visit([b for b in block if isinstance(b, (ast.stmt, ast.excepthandler))], inner)
            if isinstance(node, ast.ExceptHandler):
                visit(node.body, inner)

    visit(ast.parse(path.read_text()).body, False)
    return found & set(MODULES)


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []

    def strong(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph[v]):
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
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            strong(v)
    return out


@pytest.mark.parametrize("lazy", [False, True], ids=["module level", "with imports inside functions"])
def test_there_are_no_import_cycles(lazy):
    graph = {m: _imports(p, lazy=lazy) - {m} - {b for a, b in FACADE_IMPORTS if a == m} for m, p in MODULES.items()}
    assert _cycles(graph) == []


# ---- layering: inference/ is the bottom stage; nothing in it imports analysis/, io/ or cli/, not even lazily

UPPER_STAGES = ("pbicrl.analysis", "pbicrl.io", "pbicrl.cli")

#: The only ways up from inference/, each inside one method or a deprecated alias: (module, module it reaches).
#: ``Posterior.table()``, ``_repr_html_``, ``to_dataframe()`` (analysis.report), ``diagnostics()``,
#: ``to_arviz()``, ``save()`` and ``load()`` are entry points kept for users: the code they run lives above and
#: never needs them, so they are not dependencies (and are left out of the cycle check above).
#: ``pbicrl.inference.results`` is the deprecated alias module of what moved out (goes in pbicrl 0.3).
FACADE_IMPORTS: set[tuple[str, str]] = {
    ("pbicrl.inference.posterior", "pbicrl.analysis.report"),
    ("pbicrl.inference.posterior", "pbicrl.analysis.diagnostics"),
    ("pbicrl.inference.posterior", "pbicrl.analysis.export"),
    ("pbicrl.inference.posterior", "pbicrl.io.runs"),
    ("pbicrl.inference.results", "pbicrl.io.outdir"),
}


def _named_modules(path: Path) -> set[str]:
    """pbicrl modules named by a string constant outside docstrings (``importlib.import_module("pbicrl.x")``)."""
    tree = ast.parse(path.read_text())
    docs = {id(n.body[0].value) for n in ast.walk(tree)
            if isinstance(n, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and n.body
            and isinstance(n.body[0], ast.Expr) and isinstance(n.body[0].value, ast.Constant)}
    return {n.value for n in ast.walk(tree)
            if isinstance(n, ast.Constant) and isinstance(n.value, str) and n.value in MODULES and id(n) not in docs}


def _upward(module: str, path: Path) -> set[tuple[str, str]]:
    used = _imports(path, lazy=True) | _named_modules(path)
    return {(module, u) for u in used if u.startswith(UPPER_STAGES)}


def test_inference_imports_nothing_above_it():
    inference = {m: p for m, p in MODULES.items() if m == "pbicrl.inference" or m.startswith("pbicrl.inference.")}
    assert len(inference) > 10  # the scan sees the stage
    up = set().union(*(_upward(m, p) for m, p in inference.items()))
    assert sorted(up - FACADE_IMPORTS) == [], "inference/ must not import analysis/, io/ or cli/"
    assert sorted(FACADE_IMPORTS - up) == []  # an entry point that is gone: drop it from the list
    at_module_level = {(m, u) for m, p in inference.items() for u in _imports(p, lazy=False) if u.startswith(UPPER_STAGES)}
    assert at_module_level == set()


def test_the_layering_check_sees_lazy_and_dynamic_imports(tmp_path):
    f = tmp_path / "m.py"
    f.write_text('"""pbicrl.analysis.plots in a docstring does not count."""\nimport importlib\n\n'
                 'def f():\n    from pbicrl.io import csv\n    return importlib.import_module("pbicrl.cli.app")\n')
    assert _upward("pbicrl.inference.x", f) == {("pbicrl.inference.x", "pbicrl.io.csv"),
                                                ("pbicrl.inference.x", "pbicrl.cli.app")}


def test_the_cycle_finder_finds_cycles():
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


def test_the_import_reader_sees_lazy_and_skips_type_checking(tmp_path):
    f = tmp_path / "m.py"
    f.write_text("from typing import TYPE_CHECKING\nfrom pbicrl import errors\nif TYPE_CHECKING:\n"
                 "    from pbicrl.inference.results import Posterior\n\ndef f():\n    from pbicrl.api import infer\n")
    assert _imports(f, lazy=False) == {"pbicrl.errors"}
    assert _imports(f, lazy=True) == {"pbicrl.errors", "pbicrl.api"}


# Private names still used across modules, in files whose owners change them later (remove an entry once
# its use is gone; the test fails on any use not listed here).
_KNOWN_PRIVATE_USES: set[tuple[str, str]] = set()


def _private(name: str) -> bool:
    return name.startswith("_") and not (name.startswith("__") and name.endswith("__"))


def _private_uses(module: str, path: Path) -> set[tuple[str, str]]:
    """``(module, "other.module._name")`` for every private name of another module that ``module`` uses."""
    tree = ast.parse(path.read_text())
    aliases: dict[str, str] = {}
    uses: set[tuple[str, str]] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").startswith("pbicrl"):
            for a in node.names:
                full = f"{node.module}.{a.name}"
                if full in MODULES:
                    aliases[a.asname or a.name] = full
                elif _private(a.name) and node.module != module:
                    uses.add((module, full))
        elif isinstance(node, ast.Import):
            aliases.update({a.asname: a.name for a in node.names if a.name in MODULES and a.asname})
    for node in ast.walk(tree):
        if (isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in aliases
                and _private(node.attr) and aliases[node.value.id] != module):
            uses.add((module, f"{aliases[node.value.id]}.{node.attr}"))
    return uses


def test_no_module_uses_another_modules_private_names():
    uses = set().union(*(_private_uses(m, p) for m, p in MODULES.items()))
    assert sorted(uses - _KNOWN_PRIVATE_USES) == []
    assert sorted(_KNOWN_PRIVATE_USES - uses) == []  # a use that is gone: drop it from the list


def test_every_module_declares_all():
    missing = [m for m, p in MODULES.items()
               if not p.name.startswith("_") and "__all__" not in p.read_text() and p.name != "__main__.py"]
    assert missing == []


@pytest.mark.slow
@pytest.mark.parametrize("module", sorted(m for m in MODULES if not m.endswith(".__main__")))  # scripts: they run
def test_every_module_imports_in_a_fresh_interpreter(module):
    """Each module alone, first in a new process: an import cycle that only bites in some order shows here."""
    proc = subprocess.run([sys.executable, "-c", f"import {module}"], capture_output=True, text=True, timeout=300)
    if proc.returncode and "needs" in proc.stderr and "pip install" in proc.stderr:
        pytest.skip(f"optional extra missing: {proc.stderr.strip().splitlines()[-1]}")
    assert proc.returncode == 0, proc.stderr


# ---- layout: the pipeline's stages are folders; old module paths still import for one release

ROOT_MODULES = {"pbicrl._moved", "pbicrl._version", "pbicrl._atomic", "pbicrl.__main__", "pbicrl.api",
                "pbicrl.config", "pbicrl.errors", "pbicrl.runs"}


def test_the_package_root_holds_only_entry_points_and_folders():
    flat = {m for m, p in MODULES.items() if m.count(".") == 1 and p.name != "__init__.py"}
    assert flat - ROOT_MODULES == set(), "a new module belongs in a stage folder (inference/, analysis/, cli/, ...)"


@pytest.mark.parametrize("old", sorted(__import__("pbicrl._moved", fromlist=["MOVED"]).MOVED))
def test_an_old_module_path_is_the_moved_module_with_a_deprecation_warning(old):
    code = ("import importlib, warnings, pbicrl\n"
            "from pbicrl._moved import MOVED\n"
            "with warnings.catch_warnings(record=True) as w:\n"
            "    warnings.simplefilter('always')\n"
            f"    old = importlib.import_module({old!r})\n"
            f"new = importlib.import_module(MOVED[{old!r}])\n"
            "assert old is new, (old, new)\n"
            "msgs = [str(x.message) for x in w if type(x.message).__name__ == 'PbicrlWarning']\n"
            f"assert any({old!r} in m and 'deprecated' in m for m in msgs), msgs\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr


def test_no_pbicrl_module_imports_an_old_path():
    from pbicrl._moved import MOVED

    for name, path in MODULES.items():
        used = _imports(path, lazy=True) | _raw_pbicrl_imports(path)
        assert not (used & set(MOVED)), f"{name} imports deprecated paths {sorted(used & set(MOVED))}"


def _raw_pbicrl_imports(path: Path) -> set[str]:
    out: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").startswith("pbicrl"):
            out.add(node.module)
            out.update(f"{node.module}.{a.name}" for a in node.names)
        elif isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
    return out


# ---- the command line: all argparse lives in pbicrl.cli (library modules take arguments, not argv)

def _imports_argparse(path: Path) -> bool:
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import) and any(a.name.split(".")[0] == "argparse" for a in node.names):
            return True
        if isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").split(".")[0] == "argparse":
            return True
    return False


def test_argparse_is_imported_only_under_pbicrl_cli(tmp_path):
    outside = sorted(m for m, p in MODULES.items() if not (m == "pbicrl.cli" or m.startswith("pbicrl.cli."))
                     and _imports_argparse(p))
    assert outside == [], "argparse code belongs in pbicrl/cli/"
    assert _imports_argparse(SRC / "pbicrl" / "cli" / "app.py")  # the check sees a real use
    lazy = tmp_path / "m.py"
    lazy.write_text("def f():\n    from argparse import ArgumentParser\n")
    assert _imports_argparse(lazy)


# ---- the library never imports its command line (only ``python -m`` scripts do): no runtime circle such as
# cli/close_loop <-> experiments/close_loop

#: Deprecated names (``pbicrl._moved.moved_to_cli``, until 0.3) that reach their new home in pbicrl.cli only when
#: used: (old module, cli module).
DEPRECATED_CLI_ALIASES = {
    ("pbicrl.experiments.close_loop", "pbicrl.cli.close_loop"),
    ("pbicrl.experiments.reproduce", "pbicrl.cli.reproduce"),
    ("pbicrl.experiments.safe_rl", "pbicrl.cli.train_safe"),
    ("pbicrl.experiments.sweep", "pbicrl.cli.sweep"),
}


def test_no_library_module_imports_pbicrl_cli():
    def is_cli(m: str) -> bool:
        return m == "pbicrl.cli" or m.startswith("pbicrl.cli.")

    up = {(m, u) for m, p in MODULES.items() if not is_cli(m) and not m.endswith("__main__") and m != "pbicrl._moved"
          for u in _imports(p, lazy=True) | _named_modules(p) if is_cli(u)}
    assert sorted(up - DEPRECATED_CLI_ALIASES) == []
    assert sorted(DEPRECATED_CLI_ALIASES - up) == []  # an alias that is gone: drop it from the list
    for old, new in DEPRECATED_CLI_ALIASES:  # and each is reached through moved_to_cli only
        assert new not in _imports(MODULES[old], lazy=True)


def test_pbicrl_data_is_the_folder_of_shipped_datasets():
    from importlib import resources

    import pbicrl.inference.data as dataset_module

    shipped = resources.files("pbicrl.data")  # raised TypeError while pbicrl.data was an alias of a module
    assert shipped.joinpath("point_mass.npz").is_file()
    assert Path(str(shipped)) == dataset_module.shipped_dir()
    code = ("import warnings, pbicrl.inference.data as new\n"
            "with warnings.catch_warnings(record=True) as w:\n"
            "    warnings.simplefilter('always')\n"
            "    from pbicrl.data import load_dataset, Dataset\n"
            "assert load_dataset is new.load_dataset and Dataset is new.Dataset\n"
            "assert any('pbicrl.data.load_dataset' in str(x.message) and 'deprecated' in str(x.message) for x in w)\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
