"""Imports run one way, down the paper's layers (docs/architecture.md):

    analytic ──▶ broker, worker ──▶ cli ──▶ schemas, models

schemas/ and models/ import nothing of the project but each other; cli/ imports only them;
worker/ and broker/ never import analytic/; the contract (schemas/) imports no CLI library.
Read from the source with ast, so an import inside a function counts too.
"""

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).parents[1]
PROJECT = ("schemas", "models", "cli", "worker", "broker", "analytic")
FOLDER = {"cli": "gainfarm/cli"}  # the others keep their folders at the top level
MAY_IMPORT = {
    "schemas": {"schemas", "models"},
    "models": {"schemas", "models"},
    "cli": {"schemas", "models", "cli"},
    "worker": {"schemas", "models", "cli", "worker"},
    "broker": {"schemas", "models", "cli", "broker"},
    "analytic": set(PROJECT),
}
CLI_LIBRARIES = {"click", "rich"}


def imports(package: str) -> dict[str, set[str]]:
    """The layers (or other top-level names) each module of `package` imports: `gainfarm.worker`
    counts as `worker`."""
    found = {}
    for path in sorted((ROOT / FOLDER.get(package, package)).rglob("*.py")):
        names = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                names |= {_layer(alias.name) for alias in node.names}
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names.add(_layer(node.module))
        found[str(path.relative_to(ROOT))] = names
    return found


def _layer(module: str) -> str:
    parts = module.split(".")
    return parts[1] if parts[0] == "gainfarm" and len(parts) > 1 else parts[0]


@pytest.mark.parametrize("package", PROJECT)
def test_a_package_imports_only_the_layers_below_it(package: str) -> None:
    modules = imports(package)
    assert modules, f"{package}/ has no modules"
    wrong = {
        module: sorted(names & set(PROJECT) - MAY_IMPORT[package])
        for module, names in modules.items()
        if names & set(PROJECT) - MAY_IMPORT[package]
    }
    assert wrong == {}


def test_the_contract_imports_no_cli_library() -> None:
    wrong = {
        m: sorted(n & CLI_LIBRARIES) for m, n in imports("schemas").items() if n & CLI_LIBRARIES
    }
    assert wrong == {}
