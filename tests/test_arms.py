"""Nothing assumes the iiwa 14 where any arm runs: its numbers (schemas/robot.py's JOINT_NAMES,
N_JOINTS, the limits; schemas/gains.py's DEFAULT_GAINS) are read only as a default (a parameter's
or a field's: the iiwa 14 is the default robot) or where the iiwa is meant, each file here with
its reason. Everything else takes the robot's (`gainfarm.models.robot_of`). Read from the source
with ast, so a new reading anywhere fails here, naming its line.
"""

import ast
from pathlib import Path

ROOT = Path(__file__).parents[1]
PACKAGES = ("analytic", "worker", "broker", "schemas", "models", "gainfarm")
IIWA_ONLY = {
    "N_JOINTS",
    "JOINT_NAMES",
    "TORQUE_LIMITS",
    "SPEED_LIMITS",
    "POSITION_LIMITS",
    "ACCELERATION_LIMITS",
    "DEFAULT_GAINS",
}
# Files where the iiwa 14 is meant, with why.
MEANT = {
    "models/iiwa14.py": "the iiwa 14's plug-in declares them",
    "models/described.py": "a description's torque-scaled rule scales the iiwa 14's numbers",
    "analytic/data/dataset_columns.py": "a dataset written before datasets named their arm",
    "analytic/experiments/dataset_value.py": "runs on the iiwa 14 alone (refuses another arm)",
    "analytic/experiments/feedforward.py": "runs on the iiwa 14 alone (refuses another arm)",
    "analytic/tuning/records.py": "a header of no kp1..kpN form: read as the iiwa 14's, refused",
}


def _as_defaults(tree: ast.AST) -> set[int]:
    """ids of the nodes inside a default: a parameter's, or a class field's (dataclass,
    pydantic)."""
    inside: set[int] = set()
    for node in ast.walk(tree):
        defaults: list[ast.AST] = []
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda):
            defaults = [*node.args.defaults, *(d for d in node.args.kw_defaults if d is not None)]
        elif isinstance(node, ast.ClassDef):
            defaults = [
                item.value
                for item in node.body
                if isinstance(item, ast.AnnAssign) and item.value is not None
            ]
        for default in defaults:
            inside |= {id(sub) for sub in ast.walk(default)}
    return inside


def _imported(tree: ast.AST) -> set[str]:
    """The iiwa 14's names the module imports from the contract (another arm's module may name
    its own numbers alike)."""
    return {
        alias.asname or alias.name
        for node in ast.walk(tree)
        if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("gainfarm.schemas")
        for alias in node.names
        if alias.name in IIWA_ONLY
    }


def _readings(path: Path) -> list[str]:
    tree = ast.parse(path.read_text())
    defaults, names = _as_defaults(tree), _imported(tree)
    return [
        f"{path.relative_to(ROOT)}:{node.lineno} {node.id}"
        for node in ast.walk(tree)
        if isinstance(node, ast.Name) and node.id in names and id(node) not in defaults
    ]


def test_the_iiwas_numbers_are_read_only_as_defaults_or_where_the_iiwa_is_meant():
    found = [
        reading
        for package in PACKAGES
        for path in sorted((ROOT / package).rglob("*.py"))
        if str(path.relative_to(ROOT)) not in MEANT and "testing" not in path.parts
        for reading in _readings(path)
    ]
    assert found == [], "read the robot's numbers (gainfarm.models.robot_of) instead"


def test_each_file_where_the_iiwa_is_meant_still_reads_its_numbers():
    stale = [file for file in MEANT if not _readings(ROOT / file)]
    assert stale == [], "no longer reads the iiwa 14's numbers: drop it from MEANT"
