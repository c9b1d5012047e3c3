"""Print a variant's MJCF, or the numbers models/README.md quotes.

python -m gainfarm.models [flexible|rigid] [menagerie|cad|open]   the MJCF, e.g. for a viewer
python -m gainfarm.models modes                          elastic modes and substeps of each preset
python -m gainfarm.models inertia                        mass-matrix diagonals of the inertial sets
"""

import sys

import mujoco
import numpy as np

from gainfarm.models.iiwa14 import (
    CAD_INERTIALS,
    READY_POSTURE,
    UPRIGHT_POSTURE,
    build_spec,
    effective_inertias,
    elastic_modes,
    min_substeps,
)
from gainfarm.schemas.robot import STIFFNESS_PRESETS, PlantSpec

INERTIALS = ("menagerie", "open", "cad")


def print_modes() -> None:
    """Per preset and inertial set: modes at the ready and upright postures, substeps needed."""
    for preset, stiffness in STIFFNESS_PRESETS.items():
        for inertials in INERTIALS:
            spec = PlantSpec(inertials=inertials, stiffness=stiffness)
            ready = _join(elastic_modes(spec, READY_POSTURE), "{:.0f}")
            upright = _join(elastic_modes(spec, UPRIGHT_POSTURE), "{:.0f}")
            damping = np.asarray(spec.spring_damping)
            zeta = damping / (2 * np.sqrt(np.asarray(stiffness) * effective_inertias(spec)))
            print(
                f"{preset:6s} {inertials:9s} substeps >= {min_substeps(spec)}; modes, Hz: "
                f"ready {ready}; upright {upright}; "
                f"spring damping ratio A1..A7 {_join(zeta, '{:.2f}')}"
            )


def print_inertia() -> None:
    """Link-side mass-matrix diagonal (no rotor inertia) per inertial set, and how much of the
    CAD set's change Menagerie's re-oriented axes make on their own (with the open masses)."""
    rigid = {"joints": "rigid", "rotor_inertia": (0.0,) * 7}
    open_axes_only = build_spec(PlantSpec(inertials="open", **rigid))
    for body, (_, orientation) in CAD_INERTIALS.items():
        if orientation is not None:
            open_axes_only.body(body).iquat = orientation
    models = {
        "open": build_spec(PlantSpec(inertials="open", **rigid)).compile(),
        "cad": build_spec(PlantSpec(inertials="cad", **rigid)).compile(),
        "open masses, Menagerie's axes": open_axes_only.compile(),
    }
    for posture, q in (("q = 0", UPRIGHT_POSTURE), ("ready", READY_POSTURE)):
        diagonals = {name: _mass_diagonal(model, q) for name, model in models.items()}
        print(f"{posture}: open, kg·m²: {_join(diagonals['open'], '{:.4g}')}")
        for name, diagonal in diagonals.items():
            if name != "open":
                change = 100 * (diagonal / diagonals["open"] - 1)
                print(f"{posture}: {name} vs open, %: {_join(change, '{:+.0f}')}")


def _mass_diagonal(model: mujoco.MjModel, q: tuple[float, ...]) -> np.ndarray:
    data = mujoco.MjData(model)
    data.qpos[:] = q
    mujoco.mj_forward(model, data)
    full = np.zeros((model.nv, model.nv))
    mujoco.mj_fullM(model, data, full)
    return np.diag(full)


def _join(values: np.ndarray, form: str) -> str:
    return ", ".join(form.format(v) for v in values)


if __name__ == "__main__":
    args = sys.argv[1:]
    if args == ["modes"]:
        print_modes()
    elif args == ["inertia"]:
        print_inertia()
    else:
        joints = args[0] if args else "flexible"
        inertials = args[1] if len(args) > 1 else PlantSpec().inertials
        if joints not in ("flexible", "rigid") or inertials not in INERTIALS or len(args) > 2:
            sys.exit(
                "usage: python -m gainfarm.models [flexible|rigid] [menagerie|cad|open] | modes "
                "| inertia"
            )
        print(build_spec(PlantSpec(joints=joints, inertials=inertials)).to_xml())
