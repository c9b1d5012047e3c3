"""Print a variant's MJCF: `python -m models [flexible|rigid]`, e.g. for MuJoCo's viewer."""

import sys

from models.iiwa14 import build_spec
from schemas.robot import ModelSpec

if __name__ == "__main__":
    joints = sys.argv[1] if len(sys.argv) > 1 else "flexible"
    if joints not in ("flexible", "rigid"):
        sys.exit(f"error: variant must be 'flexible' or 'rigid', not {joints!r}")
    print(build_spec(ModelSpec(joints=joints)).to_xml())
