"""JSON Schema files for every wire message, generated from the pydantic models.

    python -m gainfarm.schemas.json_schema          # rewrite schemas/json/ from the models
    python -m gainfarm.schemas.json_schema --check  # exit 1 if stale (the tests do this)

The models are the source of truth; the files are for whoever talks to the farm from another
language, and for review: a change to the wire shows up as a diff here.
"""

import json
import sys
from pathlib import Path

from gainfarm.schemas.wire import MESSAGES

DIRECTORY = Path(__file__).parent / "json"


def rendered() -> dict[str, str]:
    """File name → content, one file per message."""
    return {
        f"{message.__name__}.schema.json": json.dumps(message.model_json_schema(), indent=2) + "\n"
        for message in MESSAGES
    }


def stale() -> list[str]:
    """Names of the files that are missing, different, or left over."""
    expected = rendered()
    present = {path.name for path in DIRECTORY.glob("*.schema.json")}
    wrong = [
        name
        for name, content in expected.items()
        if not (DIRECTORY / name).is_file() or (DIRECTORY / name).read_text() != content
    ]
    return sorted(wrong + list(present - set(expected)))


def write() -> None:
    DIRECTORY.mkdir(exist_ok=True)
    for path in DIRECTORY.glob("*.schema.json"):
        path.unlink()
    # Plain writes: a developer's tool over files in the source tree, which --check reads back;
    # the contract runs no I/O edge of its own (gainfarm.edges.files is above it).
    for name, content in rendered().items():
        (DIRECTORY / name).write_text(content)


if __name__ == "__main__":
    if sys.argv[1:] == ["--check"]:
        outdated = stale()
        if outdated:
            print(
                f"stale JSON schemas: {', '.join(outdated)}; "
                "run python -m gainfarm.schemas.json_schema"
            )
            sys.exit(1)
    else:
        write()
