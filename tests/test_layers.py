"""Imports run one way, down the layers (docs/architecture.md), bottom to top:

    schemas            the contract: imports nothing of the project, no CLI library, no Zenoh
    plugins            the registry of plug-ins (gainfarm/plugins.py): the standard library only
    models             the robots: may import schemas, and plugins (a plant's robot is one)
    edges              Zenoh sessions, asking the broker, files (gainfarm/edges/): schemas, models
    cli                what the command lines share (gainfarm/cli/): all of the above
    worker, broker     the layers below, never analytic nor each other
    analytic           everything (but the kits); inside it, floors one way down:
                       commands -> experiments -> calibration -> data -> compose -> view -> tuning
                       -> evaluators (compose: the module analytic/compose.py, `tune`)
    testing            the conformance kit for plug-ins (gainfarm/testing/): everything; nothing
                       of the package imports it

`gainfarm/__init__.py` names only `gainfarm.analytic`, and loads it lazily. Read from the source
with ast, so an import inside a function counts too, and so does `import_module("...")`.
"""

import ast
import subprocess
import sys
from importlib.util import resolve_name
from pathlib import Path

import pytest

ROOT = Path(__file__).parents[1]
# Each layer's source, bottom to top: a folder, or one module.
WHERE = {
    "schemas": "schemas",
    "plugins": "gainfarm/plugins.py",
    "models": "models",
    "edges": "gainfarm/edges",
    "cli": "gainfarm/cli",
    "worker": "worker",
    "broker": "broker",
    "analytic": "analytic",
    "testing": "gainfarm/testing",
}
LAYERS = tuple(WHERE)
MAY_IMPORT = {
    "schemas": set(),
    "plugins": set(),
    "models": {"schemas", "plugins"},
    "edges": {"schemas", "models"},
    "cli": {"schemas", "models", "plugins", "edges"},
    "worker": {"schemas", "models", "plugins", "edges", "cli"},
    "broker": {"schemas", "models", "plugins", "edges", "cli"},
    "analytic": set(LAYERS) - {"testing"},
    "testing": set(LAYERS),
}
FACE = "gainfarm/__init__.py"  # the public face: `import gainfarm`, `from gainfarm import tune`
CONTRACT_MAY_NOT = {"click", "rich", "zenoh"}
# analytic/'s floors, top to bottom: subpackages, and compose.py (the composition root, `tune`);
# its other own modules (cli.py, __init__.py, __main__.py) are the face and the entry, above all.
FLOORS = (
    "commands",
    "experiments",
    "calibration",
    "data",
    "compose",
    "view",
    "tuning",
    "evaluators",
)
# Known upward arrows, each to be deleted the moment it is cut (a stale entry fails too).
UPWARD: set[tuple[str, str]] = set()


def _sources(where: str) -> list[Path]:
    path = ROOT / where
    if path.suffix == ".py":
        return [path] if path.is_file() else []
    return sorted(path.rglob("*.py"))


def _module_name(path: Path) -> str:
    """The dotted name `path` installs as: schemas/keys.py is gainfarm.schemas.keys."""
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[0] != "gainfarm":
        parts.insert(0, "gainfarm")
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imported(path: Path) -> set[str]:
    """Every module `path` imports, as dotted names: `from a import b` counts as `a.b` (b may be
    a module: `from gainfarm import plugins` is the registry, not the face), relative imports
    resolved, literal `import_module("...")` calls included."""
    name = _module_name(path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            module = resolve_name("." * node.level + (node.module or ""), package)
            found |= {module if a.name == "*" else f"{module}.{a.name}" for a in node.names}
        elif (
            isinstance(node, ast.Call)
            and getattr(node.func, "id", getattr(node.func, "attr", None)) == "import_module"
            and node.args
            and isinstance(node.args[0], ast.Constant)
            and isinstance(node.args[0].value, str)
        ):
            found.add(node.args[0].value)
    return found


def layer(module: str) -> str | None:
    """The project layer `module` belongs to, None if it is not the project's. The face
    (`gainfarm` itself, `gainfarm.tune`) is analytic's."""
    parts = module.split(".")
    if parts[0] != "gainfarm":
        return None
    return parts[1] if len(parts) > 1 and parts[1] in LAYERS else "analytic"


def floor(module: str) -> str | None:
    """The analytic floor of `module`; "" for analytic's face and entry; None outside it."""
    parts = module.split(".")
    if parts[:2] != ["gainfarm", "analytic"]:
        return None
    return parts[2] if len(parts) > 2 and parts[2] in FLOORS else ""


def _relative(path: Path) -> str:
    return str(path.relative_to(ROOT))


def test_every_module_of_the_package_is_in_one_layer() -> None:
    """A new folder or module cannot slip past the rules: each belongs to a layer or is the
    face."""
    roots = [ROOT / "gainfarm", *(ROOT / where for where in WHERE.values() if "/" not in where)]
    everything = {_relative(path) for root in roots for path in root.rglob("*.py")}
    placed = {_relative(path) for where in WHERE.values() for path in _sources(where)}
    assert everything - placed == {FACE}


@pytest.mark.parametrize("name", LAYERS)
def test_a_layer_imports_only_the_layers_below_it(name: str) -> None:
    sources = _sources(WHERE[name])
    assert sources, f"{WHERE[name]} has no modules"
    wrong = {}
    for path in sources:
        layers = {layer(module) for module in imported(path)} - {None, name}
        if layers - MAY_IMPORT[name]:
            wrong[_relative(path)] = sorted(layers - MAY_IMPORT[name])
    assert wrong == {}


def test_the_contract_imports_no_cli_library_and_no_zenoh() -> None:
    wrong = {}
    for path in _sources(WHERE["schemas"]):
        libraries = {module.split(".")[0] for module in imported(path)} & CONTRACT_MAY_NOT
        if libraries:
            wrong[_relative(path)] = sorted(libraries)
    assert wrong == {}


def test_the_plugin_registry_needs_only_the_standard_library() -> None:
    """Entry points and workers read it before anything heavy is loaded."""
    sources = _sources(WHERE["plugins"])
    assert sources, f"no {WHERE['plugins']}"
    (path,) = sources
    outside = {m for m in imported(path) if m.split(".")[0] not in sys.stdlib_module_names}
    assert outside == set()


def test_the_face_names_only_analytic_and_loads_it_lazily(tmp_path: Path) -> None:
    names = {module for module in imported(ROOT / FACE) if layer(module)}
    assert names and {module.split(".")[1] for module in names} == {"analytic"}
    loaded = subprocess.run(
        [
            sys.executable,
            "-c",
            "import sys, gainfarm; print(*(m for m in sys.modules if m.startswith('gainfarm')))",
        ],
        capture_output=True,
        text=True,
        check=True,
        cwd=tmp_path,  # the installed package, not this checkout's folders
    ).stdout.split()
    assert loaded == ["gainfarm"]


def test_analytic_floors_import_one_way_down() -> None:
    upward = set()
    for path in _sources(WHERE["analytic"]):
        parts = path.relative_to(ROOT / WHERE["analytic"]).parts
        assert len(parts) == 1 or parts[0] in FLOORS, f"{_relative(path)} is on no floor"
        mine = floor(_module_name(path))
        if not mine:
            continue  # analytic's face and entry may import every floor
        for module in imported(path):
            theirs = floor(module)
            if theirs is not None and (theirs == "" or FLOORS.index(theirs) < FLOORS.index(mine)):
                upward.add((_relative(path), theirs or "analytic's face"))
    assert upward - UPWARD == set(), "an import runs up analytic's floors"
    assert UPWARD - upward == set(), "an arrow listed in UPWARD is gone: delete its entry"


# --- a command's module imports only what it runs -------------------------------------------------

# What a command line must not load to parse its arguments, show its help or refuse a bad value:
# each costs more than `import click` itself (numpy 0.2 s, pydantic with the contract 0.6 s).
HEAVY = (
    "numpy",
    "pydantic",
    "mujoco",
    "zenoh",
    "pymoo",
    "matplotlib",
    "rich",
    "cryptography",
    "pyarrow",
    "optuna",
    "bokeh",
)
COMMAND_MODULES = [
    "gainfarm.analytic.cli",
    *(
        f"gainfarm.analytic.commands.{path.stem}".removesuffix(".__init__")
        for path in sorted((ROOT / "analytic/commands").glob("*.py"))
    ),
    "gainfarm.worker.cli",
    "gainfarm.broker.cli",
]


def _loaded_after(script: str, cwd: Path) -> dict[str, list[str]]:
    """Run `script` in a fresh interpreter; what it printed as `label: module module ...`."""
    ran = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, cwd=cwd, timeout=120
    )
    assert ran.returncode == 0, ran.stderr
    return {
        label: modules.split()
        for label, _, modules in (line.partition(":") for line in ran.stdout.splitlines())
    }


REPORT = f"""
import sys
def report(label):
    heavy = {HEAVY!r}
    found = sorted({{m.split(".")[0] for m in sys.modules}} & set(heavy))
    commands = sorted(m for m in sys.modules if m.startswith("gainfarm.analytic.commands."))
    print(label + ":", *found, *commands)
"""


@pytest.mark.parametrize("module", COMMAND_MODULES)
def test_a_command_s_module_imports_only_what_it_runs(module: str, tmp_path: Path) -> None:
    """Importing a command's module loads no heavy library: its command imports them inside,
    when it runs; the click types, choices and defaults load theirs when they are used."""
    found = _loaded_after(f"{REPORT}\nimport {module}\nreport('imported')", tmp_path)
    heavy = [name for name in found["imported"] if "." not in name]
    assert heavy == [], f"{module} loads {heavy} on import: move the import into the function"


def test_analytic_help_loads_no_command_and_a_refused_option_nothing_heavy(
    tmp_path: Path,
) -> None:
    script = f"""{REPORT}
import click
from gainfarm.analytic.cli import app
def parse(*arguments):
    try:
        app.main(list(arguments), "analytic", standalone_mode=False)
    except (click.exceptions.Exit, click.UsageError):
        pass
parse("--help")
report("help")
parse("start", "--pop", "0")
report("refused")
"""
    found = _loaded_after(script, tmp_path)
    assert found["help"] == []  # no heavy library, and not one command's module
    assert found["refused"] == [
        "gainfarm.analytic.commands.shared",
        "gainfarm.analytic.commands.start",
    ]
