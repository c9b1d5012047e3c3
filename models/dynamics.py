"""Models of the iiwa 14's joint dynamics as data, and their evaluation: the worker's feed-forward.

A `DynamicsModel` maps one joint-space state and a third signal to another, in bulk ((n, 7)
arrays, a whole reference at once):
- target "inverse": (q, q̇, q̈) → the motor torque u that produces them, N·m;
- target "forward": (q, q̇, u) → the link acceleration q̈ it produces, rad/s².
u is the motors' whole torque (a dataset's u_motor): behind KUKA's FRI, the command and the
robot's own gravity model together, which is why the worker's feed-forward there subtracts the
latter (worker/episode.py `compensation`).

Kinds:
- "rigid": the physics prior. MuJoCo's dynamics of the rigid arm of `spec` (its inertial set, the
  rotor inertias as armature, no friction): `mj_inverse`, or `mj_forward` with u applied;
- "linear": linear-in-parameters identification, τ = Y(q, q̇, q̈)·π. Y is Pinocchio's joint torque
  regressor of the same arm (10 inertial parameters a link), beside per-joint columns for the
  rotor inertia (q̈), viscous friction (q̇) and Coulomb-like friction (tanh(q̇ / 0.05)). Inverse
  only: the identified π need not make a positive-definite mass matrix to invert;
- "mlp": a feed-forward network, evaluated here with numpy;
- "residual": the rigid prior plus a network trained on what the prior leaves out;
- "plant": the simulated plant's own dynamics (`true_model`), the anchor no learned model can
  beat: the rigid arm as it really is (its payload and true link masses too) with the rotors as
  armature, plus the motors' friction at the given velocity, as the plant applies it. Not learnt:
  an oracle for the comparisons (analytic/experiments/feedforward.py) that any model file's user
  can run like a learned one. Its spec is the plant's dynamic part (`plant_spec`), not the
  nominal arm the other kinds start from, so a learned model's prior never sees the truth.

A model file is an uncompressed .npz: a JSON header (a uint8 array) and float64 arrays, no pickle,
so hostile bytes can be refused but never run (`from_bytes`). Jobs name a model by the SHA-256 of
its file (`digest`); `to_bytes` is deterministic, so one model always has one digest. Training is
analytic/learning.py's. Pinocchio is imported only where a linear model is built or evaluated: a
worker that never runs one needs no Pinocchio.
"""

import io
import json
import math
import tempfile
import zipfile
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import lru_cache
from hashlib import sha256
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal, get_args

import mujoco
import numpy as np
from numpy.lib import format as npy_format
from pydantic import ValidationError

from gainfarm.models.robots import build_spec, compile_model, resolve
from gainfarm.schemas.robot import JOINT_NAMES, N_JOINTS, Friction, PlantSpec

if TYPE_CHECKING:
    import pinocchio  # for annotations only; imported at run time by _pinocchio()

Kind = Literal["rigid", "linear", "mlp", "residual", "plant"]
Target = Literal["inverse", "forward"]
Activation = Literal["relu", "tanh"]
KINDS: tuple[str, ...] = get_args(Kind)
TARGETS: tuple[str, ...] = get_args(Target)
ACTIVATIONS: tuple[str, ...] = get_args(Activation)

FORMAT = "gainfarm.dynamics"
VERSION = 1
INPUTS = 3 * N_JOINTS  # (q, q̇, q̈) or (q, q̇, u)
# Per link, Pinocchio's dynamic parameters: m, m·c (3), inertia about the joint frame's origin (6).
LINK_PARAMETERS = 10
# π's blocks, in order: links' inertials, rotor inertias, viscous and Coulomb-like friction.
LINEAR_PARAMETERS = (LINK_PARAMETERS + 3) * N_JOINTS
# rad/s: the plant's friction model (schemas.robot.Friction) smooths its Coulomb part so.
COULOMB_SMOOTHING = 0.05
# A file larger than this is not a model of seven joints (a (128,128,128) network is 0.3 MB);
# checked before anything is decompressed or allocated.
MAX_FILE_BYTES = 64 * 2**20
MODEL_FILE = "model.npz"  # the model's file in a directory `analytic learn --out` writes
_EPOCH = (1980, 1, 1, 0, 0, 0)  # zip entries' timestamp: fixed, so the same model, the same bytes


class BadDynamicsModel(ValueError):
    """Bytes or a file that are not a usable dynamics model; the message is one line."""


class WrongTarget(ValueError):
    """An inverse model asked for accelerations, or a forward one for torques."""


@dataclass(frozen=True, eq=False)
class Network:
    """A fully connected network on standardised signals: h_{i+1} = act(h_i W_i + b_i), the
    last layer linear.

    `input_mean`/`input_scale` standardise the 21 inputs, `output_mean`/`output_scale` undo the
    standardisation of the 7 outputs."""

    weights: tuple[np.ndarray, ...]  # (21, h1), (h1, h2), ..., (hL, 7)
    biases: tuple[np.ndarray, ...]  # (h1,), ..., (7,)
    input_mean: np.ndarray  # (21,)
    input_scale: np.ndarray  # (21,), positive
    output_mean: np.ndarray  # (7,)
    output_scale: np.ndarray  # (7,), positive
    activation: Activation = "relu"

    def __call__(self, x: np.ndarray) -> np.ndarray:
        h = (x - self.input_mean) / self.input_scale
        act = _ACTIVATION[self.activation]
        for weights, biases in zip(self.weights[:-1], self.biases[:-1], strict=True):
            h = act(h @ weights + biases)
        return (h @ self.weights[-1] + self.biases[-1]) * self.output_scale + self.output_mean


_ACTIVATION: dict[str, Callable[[np.ndarray], np.ndarray]] = {
    "relu": lambda x: np.maximum(x, 0.0),
    "tanh": np.tanh,
}


@dataclass(frozen=True, eq=False)
class DynamicsModel:
    """One dynamics model (module docstring). `spec` is the rigid arm whose kinematics and
    inertials the physics (rigid prior, Pinocchio regressor) uses: `rigid_spec` of the plant, or
    for the plant kind `plant_spec` (the true arm and its friction).
    `about` is free provenance (what it was trained on), JSON-serialisable, stored in the file."""

    kind: Kind
    target: Target
    spec: PlantSpec
    parameters: np.ndarray | None = None  # linear: π, (LINEAR_PARAMETERS,)
    network: Network | None = None  # mlp, residual
    about: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        _check(self)

    def inverse(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
        """(n, 7) motor torques, N·m, that move the arm with (q, q̇, q̈), each (n, 7)."""
        if self.target != "inverse":
            raise WrongTarget(
                "this is a forward-dynamics model: it gives q̈ from (q, q̇, u); call .forward"
            )
        return self.predict(q, qd, qdd)

    def forward(self, q: np.ndarray, qd: np.ndarray, u: np.ndarray) -> np.ndarray:
        """(n, 7) link accelerations, rad/s², that motor torques u cause at (q, q̇), each (n, 7)."""
        if self.target != "forward":
            raise WrongTarget(
                "this is an inverse-dynamics model: it gives u from (q, q̇, q̈); call .inverse"
            )
        return self.predict(q, qd, u)

    def predict(self, q: np.ndarray, qd: np.ndarray, third: np.ndarray) -> np.ndarray:
        """The model's own target from (q, q̇, q̈) if inverse, (q, q̇, u) if forward."""
        third_name = "qdd" if self.target == "inverse" else "u"
        q, qd, third = _rows(q=q, qd=qd, **{third_name: third})
        if self.kind == "linear":
            return linear_torque(self.spec, self.parameters, q, qd, third)  # type: ignore[arg-type]
        if self.kind == "plant":
            return plant_dynamics(self.spec, self.target, q, qd, third)
        prior = 0.0
        if self.kind in ("rigid", "residual"):
            physics = rigid_inverse if self.target == "inverse" else rigid_forward
            prior = physics(self.spec, q, qd, third)
        if self.network is None:
            return prior  # type: ignore[return-value]
        return prior + self.network(np.hstack([q, qd, third]))


def rigid_spec(plant: PlantSpec) -> PlantSpec:
    """The rigid arm of `plant` that a physics prior uses: its inertial set, rotor inertias (as
    armature) and the load the robot is told (known, as the set is), rigid joints, no friction.
    Fields that play no part (sensors, delay, springs,
    physics step) are left at their defaults, so plants differing only there share one prior."""
    plant = resolve(plant)
    return PlantSpec(
        robot=plant.robot,
        joints="rigid",
        inertials=plant.inertials,
        rotor_inertia=plant.rotor_inertia,
        friction=None,
        substeps=1,
        load=None if plant.load is None else plant.load.told,
    )


def rigid_prior(spec: PlantSpec, target: Target = "inverse") -> DynamicsModel:
    """The rigid-body physics of `spec`'s arm (`rigid_spec`) as a model; no training."""
    return DynamicsModel(kind="rigid", target=target, spec=rigid_spec(spec))


def plant_spec(plant: PlantSpec) -> PlantSpec:
    """What of `plant` its true dynamics depend on: the inertial set, the true link masses
    (`mass_scale`), the payload and the load as truly held, the rotor inertias and the friction,
    on rigid joints. Springs are left out: at the reference the link and motor move alike, and
    what a spring's deflection does is the controller's to compensate, not the model's
    (bench/true_feedforward.py)."""
    plant = resolve(plant)
    return PlantSpec(
        robot=plant.robot,
        joints="rigid",
        inertials=plant.inertials,
        rotor_inertia=plant.rotor_inertia,
        friction=plant.friction,
        mass_scale=plant.mass_scale,
        payload=plant.payload,
        load=plant.load,
        substeps=1,
    )


def true_model(plant: PlantSpec, target: Target = "inverse") -> DynamicsModel:
    """The simulated `plant`'s own dynamics as a model (kind "plant"): computed torque with
    the very arm, payload and friction the simulator runs; no training."""
    return DynamicsModel(kind="plant", target=target, spec=plant_spec(plant))


def friction_torque(friction: Friction | None, velocity: np.ndarray) -> np.ndarray:
    """The motors' friction torque at motor velocities `velocity` (schemas.robot.Friction):
    viscous·θ̇ + coulomb·tanh(θ̇ / smoothing), opposing the motion; what the plant applies."""
    if friction is None:
        return np.zeros_like(velocity)
    coulomb = np.asarray(friction.coulomb) * np.tanh(velocity / friction.smoothing)
    return np.asarray(friction.viscous) * velocity + coulomb


def plant_dynamics(
    spec: PlantSpec, target: Target, q: np.ndarray, qd: np.ndarray, third: np.ndarray
) -> np.ndarray:
    """The plant kind's prediction: inverse, the true arm's torque plus the friction the
    motors must overcome at q̇; forward, the acceleration of what is left of u once friction
    has taken its part."""
    spec = resolve(spec)
    arm = compile_model(spec.model_copy(update={"friction": None}))
    friction = friction_torque(spec.friction, qd)
    if target == "inverse":
        return _mj_inverse(arm, q, qd, third) + friction
    return _mj_forward(arm, q, qd, third - friction)


# --- physics: MuJoCo's rigid arm ---------------------------------------------------------------


def rigid_inverse(spec: PlantSpec, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
    """(n, 7) generalised forces of MuJoCo's inverse dynamics (mj_inverse) of `spec`'s rigid arm.

    One MjData per call, so concurrent calls share nothing (its cost, some 50 µs, is nothing
    beside the rows'); a row costs a few µs."""
    return _mj_inverse(compile_model(rigid_spec(spec)), q, qd, qdd)


def rigid_forward(spec: PlantSpec, q: np.ndarray, qd: np.ndarray, u: np.ndarray) -> np.ndarray:
    """(n, 7) accelerations of `spec`'s rigid arm (mj_forward) with torques u on its joints.

    u goes in as applied joint forces, not as the motors' controls: a log's u is already the
    clamped torque, and the motors would clamp it again."""
    return _mj_forward(compile_model(rigid_spec(spec)), q, qd, u)


def _mj_inverse(
    model: mujoco.MjModel, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray
) -> np.ndarray:
    data = mujoco.MjData(model)
    torque = np.empty_like(q)
    inverse, qpos, qvel, qacc, result = (
        mujoco.mj_inverse,
        data.qpos,
        data.qvel,
        data.qacc,
        data.qfrc_inverse,
    )
    for k in range(len(q)):
        qpos[:], qvel[:], qacc[:] = q[k], qd[k], qdd[k]
        inverse(model, data)
        torque[k] = result
    return torque


def _mj_forward(model: mujoco.MjModel, q: np.ndarray, qd: np.ndarray, u: np.ndarray) -> np.ndarray:
    data = mujoco.MjData(model)
    acceleration = np.empty_like(q)
    forward, qpos, qvel, applied, result = (
        mujoco.mj_forward,
        data.qpos,
        data.qvel,
        data.qfrc_applied,
        data.qacc,
    )
    for k in range(len(q)):
        qpos[:], qvel[:], applied[:] = q[k], qd[k], u[k]
        forward(model, data)
        acceleration[k] = result
    return acceleration


# --- physics: Pinocchio's regressor (linear kind) ----------------------------------------------


@lru_cache(maxsize=4)
def pinocchio_model(spec: PlantSpec) -> "pinocchio.Model":
    """Pinocchio's model of `spec`'s rigid arm, parsed from the MJCF that MuJoCo's model is
    compiled from (one source: the two cannot drift apart; tests/models/test_dynamics.py checks
    their gravity torques and mass matrices agree). Its joints are A1..A7 in order."""
    pinocchio = _pinocchio()
    xml = build_spec(rigid_spec(spec)).to_xml()
    # Pinocchio's MJCF parser reads files only.
    with tempfile.TemporaryDirectory() as directory:
        path = Path(directory) / "iiwa14.xml"
        path.write_text(xml)
        model = pinocchio.buildModelFromMJCF(str(path))
    if tuple(model.names)[1:] != JOINT_NAMES or model.nv != N_JOINTS:
        raise AssertionError(f"Pinocchio parsed joints {list(model.names)}, not A1..A7")
    return model


def _pinocchio() -> Any:
    """The pinocchio module, imported here only: a worker without it runs every other kind."""
    try:
        import pinocchio  # optional extra: learn (a worker without it runs every other kind)
    except ImportError:
        raise ImportError(
            "a linear dynamics model needs Pinocchio: pip install 'gainfarm[learn]'"
        ) from None
    return pinocchio


def physical_parameters(spec: PlantSpec) -> np.ndarray:
    """π of `spec`'s rigid arm as documented (models/README.md): its links' inertials, its rotor
    inertias, no friction. What identification starts from (analytic/learning.py)."""
    spec = resolve(spec)
    model = pinocchio_model(spec)
    links = [model.inertias[j].toDynamicParameters() for j in range(1, N_JOINTS + 1)]
    friction = np.zeros(2 * N_JOINTS)
    return np.concatenate([*links, np.asarray(spec.rotor_inertia), friction])


def inconsistencies(parameters: np.ndarray) -> list[str]:
    """What makes identified π no physical arm: a link whose pseudo-inertia is not positive
    definite (a mass at most zero, or second moments no body has: Wensing et al., RA-L 2018, the
    condition Pinocchio's PseudoInertia states), whose rotational inertia about its centre of
    mass breaks the triangle inequality, or a negative rotor inertia, viscous or Coulomb term.
    Empty if π is physically consistent."""
    pinocchio = _pinocchio()
    found = []
    links = LINK_PARAMETERS * N_JOINTS
    for index, joint in enumerate(JOINT_NAMES):
        link = np.asarray(parameters[index * LINK_PARAMETERS : (index + 1) * LINK_PARAMETERS])
        if link[0] <= 0:
            found.append(f"link {joint}: mass {link[0]:.3g} kg")
            continue
        pseudo = pinocchio.PseudoInertia.FromDynamicParameters(link).toMatrix()
        if np.linalg.eigvalsh(pseudo).min() <= 0:
            found.append(f"link {joint}: pseudo-inertia not positive definite")
        moments = np.linalg.eigvalsh(pinocchio.Inertia.FromDynamicParameters(link).inertia)
        if moments.min() <= 0 or moments[2] > moments[0] + moments[1] + 1e-12:
            found.append(
                f"link {joint}: principal moments {', '.join(f'{m:.3g}' for m in moments)} "
                "kg·m² break the triangle inequality"
            )
    names = ("rotor inertia", "viscous friction", "Coulomb friction")
    for name, values in zip(names, parameters[links:].reshape(3, N_JOINTS), strict=True):
        for joint, value in zip(JOINT_NAMES, values, strict=True):
            if value < 0:
                found.append(f"{joint}: {name} {value:.3g}")
    return found


def consistent_coordinates(parameters: np.ndarray) -> np.ndarray:
    """θ with `from_consistent(θ)` = π, for a physically consistent π (`inconsistencies` empty,
    friction and rotor inertia positive): each link's log-Cholesky parameters (Rucker and
    Wensing, RA-L 2022: the pseudo-inertia J = U Uᵀ, U upper triangular with a positive
    diagonal, as Pinocchio's LogCholeskyParameters), then softplus⁻¹ of the rest."""
    links = LINK_PARAMETERS * N_JOINTS
    theta = []
    exchange = np.eye(4)[::-1]
    pinocchio = _pinocchio()
    for index in range(N_JOINTS):
        link = parameters[index * LINK_PARAMETERS : (index + 1) * LINK_PARAMETERS]
        pseudo = pinocchio.PseudoInertia.FromDynamicParameters(np.asarray(link)).toMatrix()
        # The upper-triangular factor: the lower Cholesky factor of J with rows and columns
        # reversed, reversed back.
        upper = exchange @ np.linalg.cholesky(exchange @ pseudo @ exchange) @ exchange
        alpha = upper[3, 3]
        unit = upper / alpha
        diagonal = np.log(np.diag(unit)[:3])
        theta += [np.log(alpha), *diagonal, unit[0, 1], unit[1, 2], unit[0, 2], *unit[:3, 3]]
    rest = np.asarray(parameters[links:], dtype=float)
    return np.concatenate([theta, rest + np.log(-np.expm1(-rest))])  # softplus⁻¹


def nearest_consistent(parameters: np.ndarray, floor: float = 1e-3) -> np.ndarray:
    """A physically consistent π near `parameters`: each link's pseudo-inertia with its
    eigenvalues raised to at least `floor` times its largest, friction and rotor inertia to at
    least `floor`. A start for a constrained fit, not a fit."""
    pinocchio = _pinocchio()
    links = LINK_PARAMETERS * N_JOINTS
    result = np.array(parameters, dtype=float)
    for index in range(N_JOINTS):
        part = slice(index * LINK_PARAMETERS, (index + 1) * LINK_PARAMETERS)
        pseudo = pinocchio.PseudoInertia.FromDynamicParameters(result[part]).toMatrix()
        values, vectors = np.linalg.eigh(pseudo)
        values = np.maximum(values, floor * max(values.max(), floor))
        raised = pinocchio.PseudoInertia.FromMatrix(vectors @ np.diag(values) @ vectors.T)
        result[part] = raised.toDynamicParameters()
    result[links:] = np.maximum(result[links:], floor)
    return result


def from_consistent(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """π and its Jacobian dπ/dθ for coordinates θ (`consistent_coordinates`): every θ gives a
    physically consistent arm."""
    pinocchio = _pinocchio()
    links = LINK_PARAMETERS * N_JOINTS
    parameters = np.empty(LINEAR_PARAMETERS)
    jacobian = np.zeros((LINEAR_PARAMETERS, LINEAR_PARAMETERS))
    for index in range(N_JOINTS):
        part = slice(index * LINK_PARAMETERS, (index + 1) * LINK_PARAMETERS)
        coordinates = pinocchio.LogCholeskyParameters(np.asarray(theta[part], dtype=float))
        parameters[part] = coordinates.toDynamicParameters()
        jacobian[part, part] = coordinates.calculateJacobian()
    rest = np.asarray(theta[links:], dtype=float)
    parameters[links:] = np.logaddexp(0.0, rest)  # softplus: positive, never stuck at zero
    jacobian[links:, links:] = np.diag(1.0 / (1.0 + np.exp(-rest)))
    return parameters, jacobian


def regressor(spec: PlantSpec, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> np.ndarray:
    """(n, 7, LINEAR_PARAMETERS) Y with τ = Y·π: Pinocchio's joint torque regressor of the links,
    then diagonal columns q̈ (rotor inertia), q̇ (viscous), tanh(q̇ / 0.05) (Coulomb-like)."""
    pinocchio = _pinocchio()
    model = pinocchio_model(spec)
    data = model.createData()
    n = len(q)
    links = LINK_PARAMETERS * N_JOINTS
    y = np.zeros((n, N_JOINTS, LINEAR_PARAMETERS))
    torque_regressor = pinocchio.computeJointTorqueRegressor
    for k in range(n):
        y[k, :, :links] = torque_regressor(model, data, q[k], qd[k], qdd[k])
    diagonal = np.arange(N_JOINTS)
    for block, signal in enumerate((qdd, qd, np.tanh(qd / COULOMB_SMOOTHING))):
        y[:, diagonal, links + block * N_JOINTS + diagonal] = signal
    return y


def linear_torque(
    spec: PlantSpec, parameters: np.ndarray, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray
) -> np.ndarray:
    """(n, 7) Y(q, q̇, q̈)·π, row by row (the whole (n, 7, 91) Y of a long reference is not kept)."""
    pinocchio = _pinocchio()
    model = pinocchio_model(spec)
    data = model.createData()
    links = LINK_PARAMETERS * N_JOINTS
    inertial = parameters[:links]
    rotor, viscous, coulomb = parameters[links:].reshape(3, N_JOINTS)
    torque = rotor * qdd + viscous * qd + coulomb * np.tanh(qd / COULOMB_SMOOTHING)
    torque_regressor = pinocchio.computeJointTorqueRegressor
    for k in range(len(q)):
        torque[k] += torque_regressor(model, data, q[k], qd[k], qdd[k]) @ inertial
    return torque


# --- the file ----------------------------------------------------------------------------------


def to_bytes(model: DynamicsModel) -> bytes:
    """The model file: deterministic, so equal models have equal bytes and digests."""
    header = {
        "format": FORMAT,
        "version": VERSION,
        "kind": model.kind,
        "target": model.target,
        "spec": json.loads(model.spec.model_dump_json()),
        "activation": model.network.activation if model.network is not None else None,
        "layers": len(model.network.weights) if model.network is not None else 0,
        "about": model.about,
    }
    text = json.dumps(header, sort_keys=True, separators=(",", ":"), allow_nan=False)
    arrays = {"header": np.frombuffer(text.encode(), dtype=np.uint8)}
    arrays |= _arrays(model)
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_STORED) as archive:
        for name, array in arrays.items():
            entry = io.BytesIO()
            np.lib.format.write_array(entry, np.ascontiguousarray(array), allow_pickle=False)
            archive.writestr(zipfile.ZipInfo(f"{name}.npy", date_time=_EPOCH), entry.getvalue())
    return buffer.getvalue()


def from_bytes(raw: bytes) -> DynamicsModel:
    """The model in `raw`. Raises BadDynamicsModel, one line, for anything that is not a whole,
    well-formed model; never unpickles (hostile bytes are refused, never run)."""
    try:
        return _from_bytes(raw)
    except BadDynamicsModel:
        raise
    except Exception as error:  # not expected past the checks below; a last line of defence
        reason = f"{type(error).__name__}: {_one_line(error)}"
        raise BadDynamicsModel(f"not a dynamics model file (undecodable: {reason})") from None


def _from_bytes(raw: bytes) -> DynamicsModel:
    if len(raw) > MAX_FILE_BYTES:
        raise BadDynamicsModel(f"{len(raw):,} bytes is too large for a dynamics model")
    try:
        with zipfile.ZipFile(io.BytesIO(raw)) as archive:
            entries = archive.infolist()
    except Exception:  # BadZipFile, OSError, EOFError, NotImplementedError (its zip version)...
        raise BadDynamicsModel("not a dynamics model file (not an .npz archive)") from None
    if sum(entry.file_size for entry in entries) > MAX_FILE_BYTES:
        raise BadDynamicsModel("the archive unpacks to more than a dynamics model can hold")
    arrays = _load_arrays(raw)
    header = _header(arrays.pop("header", None))
    kind, target = header["kind"], header["target"]
    try:
        spec = PlantSpec.model_validate(header["spec"])
    except ValidationError as error:
        first = error.errors()[0]
        where = ".".join(str(part) for part in first["loc"]) or "spec"
        raise BadDynamicsModel(f"the model's spec is invalid: {where}: {first['msg']}") from None
    expected = _expected_names(kind, header["layers"])
    if set(arrays) != expected:
        missing, extra = sorted(expected - set(arrays)), sorted(set(arrays) - expected)
        raise BadDynamicsModel(
            f"a {kind} model's arrays are wrong: missing {missing or 'none'}, "
            f"unexpected {extra or 'none'}"
        )
    network = None
    if kind in ("mlp", "residual"):
        layers = header["layers"]
        network = Network(
            weights=tuple(arrays[f"layer{i}_weights"] for i in range(layers)),
            biases=tuple(arrays[f"layer{i}_biases"] for i in range(layers)),
            input_mean=arrays["input_mean"],
            input_scale=arrays["input_scale"],
            output_mean=arrays["output_mean"],
            output_scale=arrays["output_scale"],
            activation=header["activation"],
        )
    return DynamicsModel(
        kind=kind,
        target=target,
        spec=spec,
        parameters=arrays.get("parameters"),
        network=network,
        about=header["about"],
    )


def feedforward_from_bytes(raw: bytes) -> DynamicsModel:
    """`from_bytes`, for a feed-forward: the model must be an inverse-dynamics one (a torque for
    the reference), else BadDynamicsModel, one line."""
    model = from_bytes(raw)
    if model.target != "inverse":
        raise BadDynamicsModel(
            f"a {model.target}-dynamics model; a feed-forward needs an inverse-dynamics one "
            "(analytic learn --target inverse)"
        )
    return model


def digest(raw: bytes) -> str:
    """SHA-256 of a model file, hex: how jobs name the model (EpisodeSpec.feedforward)."""
    return sha256(raw).hexdigest()


def load(path: Path) -> DynamicsModel:
    """The model in the file at `path`; BadDynamicsModel, one line, if it is missing or bad."""
    try:
        raw = Path(path).read_bytes()
    except OSError as error:
        raise BadDynamicsModel(f"{str(path)!r}: cannot read: {error.strerror}") from None
    try:
        return from_bytes(raw)
    except BadDynamicsModel as error:
        raise BadDynamicsModel(f"{str(path)!r}: {error}") from None


def _arrays(model: DynamicsModel) -> dict[str, np.ndarray]:
    arrays: dict[str, np.ndarray] = {}
    if model.parameters is not None:
        arrays["parameters"] = model.parameters
    if model.network is not None:
        net = model.network
        for i, (weights, biases) in enumerate(zip(net.weights, net.biases, strict=True)):
            arrays[f"layer{i}_weights"], arrays[f"layer{i}_biases"] = weights, biases
        arrays |= {
            "input_mean": net.input_mean,
            "input_scale": net.input_scale,
            "output_mean": net.output_mean,
            "output_scale": net.output_scale,
        }
    return arrays


def _load_arrays(raw: bytes) -> dict[str, np.ndarray]:
    arrays = {}
    _check_declared_sizes(raw)
    try:
        with np.load(io.BytesIO(raw), allow_pickle=False) as npz:
            for name in npz.files:
                value = npz[name]  # a member not named .npy comes back as raw bytes
                if not isinstance(value, np.ndarray):
                    raise BadDynamicsModel(f"the archive's member {name!r} is not an array")
                arrays[name] = value
    except ValueError as error:
        if "allow_pickle" in str(error) or "pickle" in str(error).lower():
            raise BadDynamicsModel(
                "the file holds a pickled object array: refused, as loading it could run code"
            ) from None
        raise BadDynamicsModel(f"an array in the file is unreadable: {_one_line(error)}") from None
    except (OSError, EOFError, zipfile.BadZipFile, KeyError, TypeError) as error:
        raise BadDynamicsModel(f"an array in the file is unreadable: {_one_line(error)}") from None
    return arrays


def _check_declared_sizes(raw: bytes) -> None:
    """Refuse an array whose .npy header claims more bytes than its member holds: numpy allocates
    what the header claims before it reads (a 200-byte file can ask for terabytes)."""
    with zipfile.ZipFile(io.BytesIO(raw)) as archive:
        for entry in archive.infolist():
            if not entry.filename.endswith(".npy"):
                continue  # np.load hands it back as bytes, of its (bounded) size
            try:
                shape, dtype = _declared(archive, entry)
            except BadDynamicsModel:
                raise
            except Exception as error:  # bad magic, header, compression, CRC: whatever it is
                reason = f"{type(error).__name__}: {_one_line(error)}"
                raise BadDynamicsModel(f"{entry.filename!r:.80}: unreadable ({reason})") from None
            if dtype.hasobject:
                raise BadDynamicsModel(
                    "the file holds a pickled object array: refused, as loading it could run code"
                )
            if any(size < 0 for size in shape):
                raise BadDynamicsModel(f"{entry.filename!r:.80}: a negative shape {shape!s:.60}")
            claimed = math.prod(shape) * dtype.itemsize
            if claimed > entry.file_size:
                raise BadDynamicsModel(
                    f"{entry.filename!r:.80}: its header claims {claimed:,} bytes of data, "
                    f"more than the member's {entry.file_size:,}"
                )


def _declared(archive: zipfile.ZipFile, entry: zipfile.ZipInfo) -> tuple[tuple[int, ...], np.dtype]:
    """The shape and dtype a .npy member's header declares, read without its data."""
    with archive.open(entry) as member:
        version = npy_format.read_magic(member)
        if version == (1, 0):
            shape, _, dtype = npy_format.read_array_header_1_0(member)
        elif version == (2, 0):
            shape, _, dtype = npy_format.read_array_header_2_0(member)
        else:
            raise BadDynamicsModel(f"{entry.filename!r:.80}: .npy format {version} is not read")
    return shape, dtype


def _header(array: np.ndarray | None) -> dict[str, Any]:
    if array is None or array.dtype != np.uint8 or array.ndim != 1:
        raise BadDynamicsModel("not a dynamics model file (no header)")
    try:
        header = json.loads(array.tobytes().decode())
    except (UnicodeDecodeError, json.JSONDecodeError):
        raise BadDynamicsModel("the model's header is not JSON") from None
    if not isinstance(header, dict) or header.get("format") != FORMAT:
        raise BadDynamicsModel(f"not a dynamics model file (its header's format is not {FORMAT})")
    if header.get("version") != VERSION:
        raise BadDynamicsModel(
            f"model file version {header.get('version')!r}; this gainfarm reads version {VERSION}"
        )
    if header.get("kind") not in KINDS:
        raise BadDynamicsModel(f"unknown kind {header.get('kind')!r}: one of {', '.join(KINDS)}")
    if header.get("target") not in TARGETS:
        raise BadDynamicsModel(
            f"unknown target {header.get('target')!r}: one of {', '.join(TARGETS)}"
        )
    layers = header.get("layers")
    if not isinstance(layers, int) or isinstance(layers, bool) or not 0 <= layers <= 64:
        raise BadDynamicsModel(f"the header's layer count {layers!r} is not one of 0..64")
    if header["kind"] in ("mlp", "residual") and header.get("activation") not in ACTIVATIONS:
        raise BadDynamicsModel(
            f"unknown activation {header.get('activation')!r}: one of {', '.join(ACTIVATIONS)}"
        )
    if not isinstance(header.get("about", {}), dict) or not isinstance(header.get("spec"), dict):
        raise BadDynamicsModel("the model's header has no spec or a malformed 'about'")
    header.setdefault("about", {})
    return header


def _expected_names(kind: str, layers: int) -> set[str]:
    if kind == "linear":
        return {"parameters"}
    if kind in ("mlp", "residual"):
        names = {"input_mean", "input_scale", "output_mean", "output_scale"}
        return names | {f"layer{i}_{part}" for i in range(layers) for part in ("weights", "biases")}
    return set()


def _check(model: DynamicsModel) -> None:
    """Raise BadDynamicsModel, one line, unless the parts make one evaluable model."""
    if model.kind not in KINDS:
        raise BadDynamicsModel(f"unknown kind {model.kind!r}: one of {', '.join(KINDS)}")
    if model.target not in TARGETS:
        raise BadDynamicsModel(f"unknown target {model.target!r}: one of {', '.join(TARGETS)}")
    if model.kind == "plant" and model.spec != plant_spec(model.spec):
        raise BadDynamicsModel("a plant model's spec must be the plant's dynamics (plant_spec)")
    if model.kind != "plant" and model.spec != rigid_spec(model.spec):
        raise BadDynamicsModel("the model's spec must be a rigid arm's (rigid_spec of the plant)")
    if model.kind == "linear" and model.target != "inverse":
        raise BadDynamicsModel("a linear model is inverse only: its π need not invert")
    if (model.parameters is not None) != (model.kind == "linear"):
        raise BadDynamicsModel(f"a {model.kind} model has parameters only if linear")
    if model.parameters is not None:
        _check_array("parameters", model.parameters, (LINEAR_PARAMETERS,))
    if (model.network is not None) != (model.kind in ("mlp", "residual")):
        raise BadDynamicsModel(f"a {model.kind} model has a network only if mlp or residual")
    if model.network is not None:
        _check_network(model.network)
    try:
        json.dumps(model.about, allow_nan=False)
    except (TypeError, ValueError):
        raise BadDynamicsModel("the model's 'about' is not plain JSON") from None


def _check_network(net: Network) -> None:
    if net.activation not in ACTIVATIONS:
        raise BadDynamicsModel(f"unknown activation {net.activation!r}")
    if not net.weights or len(net.weights) != len(net.biases):
        raise BadDynamicsModel("a network needs as many bias vectors as weight matrices, >= 1")
    width = INPUTS
    for i, (weights, biases) in enumerate(zip(net.weights, net.biases, strict=True)):
        last = i == len(net.weights) - 1
        _check_array(f"layer{i}_weights", weights, getattr(weights, "shape", ()))
        if weights.ndim != 2 or weights.shape[0] != width or (last and weights.shape[1] != 7):
            want = f"({width}, {N_JOINTS if last else 'any'})"
            raise BadDynamicsModel(f"layer{i}_weights has shape {weights.shape}, not {want}")
        _check_array(f"layer{i}_biases", biases, (weights.shape[1],))
        width = weights.shape[1]
    _check_array("input_mean", net.input_mean, (INPUTS,))
    _check_array("input_scale", net.input_scale, (INPUTS,), positive=True)
    _check_array("output_mean", net.output_mean, (N_JOINTS,))
    _check_array("output_scale", net.output_scale, (N_JOINTS,), positive=True)


def _check_array(name: str, array: object, shape: tuple[int, ...], positive: bool = False) -> None:
    if not isinstance(array, np.ndarray) or array.dtype != np.float64:
        kind = getattr(array, "dtype", type(array).__name__)
        raise BadDynamicsModel(f"{name} is {kind}, not a float64 array")
    if array.shape != shape:
        raise BadDynamicsModel(f"{name} has shape {array.shape}, not {shape}")
    if not np.isfinite(array).all():
        raise BadDynamicsModel(f"{name} holds NaN or infinite values")
    if positive and not (array > 0).all():
        raise BadDynamicsModel(f"{name} must be positive")


def _rows(**signals: np.ndarray) -> list[np.ndarray]:
    """The signals as float64 (n, 7) arrays of one n; ValueError naming the first that is not."""
    arrays = [np.asarray(value, dtype=np.float64) for value in signals.values()]
    n = len(arrays[0]) if arrays[0].ndim else -1
    for name, array in zip(signals, arrays, strict=True):
        if array.ndim != 2 or array.shape != (n, N_JOINTS):
            raise ValueError(f"{name} has shape {array.shape}; every input must be (n, 7), one n")
    return arrays


def _one_line(error: BaseException) -> str:
    text = " ".join(str(error).split())
    return text[:200] if text else type(error).__name__
