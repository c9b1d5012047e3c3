"""Dynamics models (models/dynamics.py): the physics is the plant's, the file is safe and exact.

Real MuJoCo episodes and real Pinocchio; networks here have random weights (training is
tests/analytic/data/test_learning.py's)."""

import io
import itertools
import json
import tracemalloc
import zipfile
from pathlib import Path

import mujoco
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.lib import format as npy_format

from gainfarm.models import compile_model, resolve
from gainfarm.models.dynamics import (
    LINEAR_PARAMETERS,
    BadDynamicsModel,
    DynamicsModel,
    Network,
    WrongTarget,
    digest,
    from_bytes,
    load,
    physical_parameters,
    pinocchio_model,
    plant_spec,
    rigid_prior,
    rigid_spec,
    to_bytes,
    true_model,
)
from gainfarm.schemas.robot import (
    IDEAL_PLANT,
    POSITION_LIMITS,
    REALISTIC_PLANT,
    PlantSpec,
    Sensors,
)
from gainfarm.schemas.trajectory import CONTROL_PERIOD
from tests.learning_data import episode

RIGID_IDEAL = IDEAL_PLANT.model_copy(update={"joints": "rigid"})
# The realistic plant carrying what the nominal arm does not know (a payload, heavier links), on
# rigid joints fed back from exact sensors without delay: its log's u is the motors' whole torque
# at the very state logged, so the plant's own model can be checked against it tick by tick.
LOADED = REALISTIC_PLANT.model_copy(
    update={
        "joints": "rigid",
        "payload": 5.0,
        "mass_scale": (1.1,) * 7,
        "delay": 0,
        "sensors": Sensors(exact=True),
        "feedback": "link",
        "interface": "torque",
        "substeps": 1,
    }
)


def _nmse(predicted: np.ndarray, measured: np.ndarray) -> np.ndarray:
    return ((predicted - measured) ** 2).mean(axis=0) / measured.var(axis=0)


def _dataset_rows(plant: PlantSpec) -> tuple[np.ndarray, ...]:
    """(q, q̇, q̈, u) of a 2 s episode on `plant`, q̈ as the dataset defines it."""
    log = episode(plant, 0, 2.0)
    qdd = np.diff(log.qd, axis=0) / CONTROL_PERIOD
    return log.q[:-1], log.qd[:-1], qdd, log.u[:-1]


# --- the physics prior ----------------------------------------------------------------------


def test_the_rigid_prior_is_exact_on_a_rigid_plant_stepped_once_a_tick():
    # One physics step a tick: the tick's velocity change over 2 ms is the very acceleration
    # MuJoCo integrated (no damping, so implicitfast is explicit here), and u acted alone.
    plant = RIGID_IDEAL.model_copy(update={"substeps": 1})
    q, qd, qdd, u = _dataset_rows(plant)
    assert _nmse(rigid_prior(plant).inverse(q, qd, qdd), u).max() < 1e-20
    assert _nmse(rigid_prior(plant, "forward").forward(q, qd, u), qdd).max() < 1e-20


def test_the_rigid_prior_is_first_order_accurate_on_a_rigid_plant_with_substeps():
    # Two physics steps a tick: (q̇[k+1] − q̇[k]) / T is the mean of two accelerations at two
    # states, but the prior sees only the tick's first state; the error is of order the step.
    plant = RIGID_IDEAL  # substeps = 2
    q, qd, qdd, u = _dataset_rows(plant)
    inverse = _nmse(rigid_prior(plant).inverse(q, qd, qdd), u)
    forward = _nmse(rigid_prior(plant, "forward").forward(q, qd, u), qdd)
    assert inverse.max() < 1e-5, inverse
    assert forward.max() < 1e-5, forward
    assert inverse.max() > 1e-9  # not exact: the bound above is the substeps' doing


def test_the_prior_is_the_plants_rigid_arm_without_its_friction():
    prior = rigid_prior(REALISTIC_PLANT)
    assert prior.spec.joints == "rigid"
    assert prior.spec.friction is None
    assert prior.spec.inertials == REALISTIC_PLANT.inertials
    assert prior.spec.rotor_inertia == resolve(REALISTIC_PLANT).rotor_inertia
    # Plants that differ only in what the prior ignores share one prior (one file, one digest).
    noisy = REALISTIC_PLANT.model_copy(update={"delay": 3, "substeps": 4})
    assert to_bytes(rigid_prior(noisy)) == to_bytes(prior)


def test_the_true_model_is_the_plants_own_dynamics_and_the_prior_is_not():
    # The anchor: computed torque with the simulator's own arm, payload and friction. Not exact
    # (MuJoCo damps the viscous part implicitly, the Coulomb part is taken at the tick's start),
    # but six orders of magnitude nearer the plant than the nominal arm without friction.
    q, qd, qdd, u = _dataset_rows(LOADED)
    true = _nmse(true_model(LOADED).inverse(q, qd, qdd), u)
    assert true.max() < 1e-4, true
    assert _nmse(rigid_prior(LOADED).inverse(q, qd, qdd), u).max() > 0.1
    forward = _nmse(true_model(LOADED, "forward").forward(q, qd, u), qdd)
    assert forward.max() < 1e-3, forward


def test_the_true_model_keeps_what_the_plants_dynamics_depend_on_and_nothing_else():
    model = true_model(LOADED)
    assert model.kind == "plant" and model.spec == plant_spec(LOADED)
    assert (model.spec.payload, model.spec.mass_scale) == (5.0, (1.1,) * 7)
    assert model.spec.friction == resolve(LOADED).friction and model.spec.joints == "rigid"
    # The springs, sensors, delay and interface play no part: one model, one digest for them.
    elsewhere = LOADED.model_copy(update={"delay": 3, "joints": "flexible", "substeps": 2})
    assert to_bytes(true_model(elsewhere)) == to_bytes(model)
    assert to_bytes(true_model(REALISTIC_PLANT)) != to_bytes(model)


# --- Pinocchio's arm is MuJoCo's --------------------------------------------------------------


@pytest.mark.parametrize("inertials", ["open", "cad"])
def test_pinocchio_parses_the_same_arm_as_mujoco(inertials):
    import pinocchio

    spec = rigid_spec(PlantSpec(inertials=inertials))
    pin_model = pinocchio_model(spec)
    pin_data = pin_model.createData()
    mj_model = compile_model(spec)
    mj_data = mujoco.MjData(mj_model)
    rng = np.random.default_rng(1)
    mass_matrix = np.zeros((7, 7))
    for _ in range(20):
        q = rng.uniform(-1, 1, 7) * np.array(POSITION_LIMITS)
        mj_data.qpos[:], mj_data.qvel[:] = q, 0.0
        mujoco.mj_forward(mj_model, mj_data)
        gravity = pinocchio.computeGeneralizedGravity(pin_model, pin_data, q)
        np.testing.assert_allclose(gravity, mj_data.qfrc_bias, rtol=1e-6, atol=1e-6)
        mujoco.mj_fullM(mj_model, mj_data, mass_matrix)
        pin_mass = pinocchio.crba(pin_model, pin_data, q)
        pin_mass = np.triu(pin_mass) + np.triu(pin_mass, 1).T  # crba fills the upper triangle
        # Both include the rotor inertias (Pinocchio reads MuJoCo's armature).
        np.testing.assert_allclose(pin_mass, mass_matrix, rtol=1e-6, atol=1e-6)
    assert abs(mass_matrix).max() > 0.1  # the comparison compared something


def test_the_linear_model_at_the_documented_parameters_is_the_rigid_prior():
    # Y·π₀ (Pinocchio's regressor and the rotor column) against mj_inverse: the columns are
    # assembled in the order the parameters are.
    spec = rigid_spec(REALISTIC_PLANT)
    linear = DynamicsModel("linear", "inverse", spec, parameters=physical_parameters(spec))
    rng = np.random.default_rng(2)
    q = rng.uniform(-1, 1, (50, 7)) * np.array(POSITION_LIMITS)
    qd, qdd = rng.normal(size=(50, 7)), 5 * rng.normal(size=(50, 7))
    np.testing.assert_allclose(
        linear.inverse(q, qd, qdd), rigid_prior(spec).inverse(q, qd, qdd), rtol=1e-6, atol=1e-5
    )


# --- the model file ---------------------------------------------------------------------------


def _network(seed: int, hidden: tuple[int, ...] = (16, 16)) -> Network:
    rng = np.random.default_rng(seed)
    widths = (21, *hidden, 7)
    return Network(
        weights=tuple(rng.normal(size=(a, b)) / np.sqrt(a) for a, b in itertools.pairwise(widths)),
        biases=tuple(rng.normal(size=b) for b in widths[1:]),
        input_mean=rng.normal(size=21),
        input_scale=rng.uniform(0.5, 2.0, 21),
        output_mean=rng.normal(size=7),
        output_scale=rng.uniform(0.5, 2.0, 7),
        activation="relu",
    )


def _models() -> dict[str, DynamicsModel]:
    spec = rigid_spec(REALISTIC_PLANT)
    rng = np.random.default_rng(3)
    parameters = physical_parameters(spec) + 0.01 * rng.normal(size=LINEAR_PARAMETERS)
    return {
        "rigid inverse": rigid_prior(spec),
        "rigid forward": rigid_prior(spec, "forward"),
        "linear": DynamicsModel("linear", "inverse", spec, parameters=parameters),
        "mlp": DynamicsModel("mlp", "inverse", spec, network=_network(4), about={"seed": 4}),
        "mlp forward": DynamicsModel("mlp", "forward", spec, network=_network(5)),
        "residual": DynamicsModel("residual", "inverse", spec, network=_network(6)),
        "residual forward": DynamicsModel("residual", "forward", spec, network=_network(7)),
        "plant": true_model(LOADED),
        "plant forward": true_model(LOADED, "forward"),
    }


MODELS = _models()


def _inputs(n: int = 40) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    rng = np.random.default_rng(8)
    return rng.uniform(-1, 1, (n, 7)), rng.normal(size=(n, 7)), 5 * rng.normal(size=(n, 7))


@pytest.mark.parametrize("name", MODELS)
def test_a_model_file_round_trips_exactly(name, tmp_path):
    model = MODELS[name]
    raw = to_bytes(model)
    again = from_bytes(raw)
    assert (again.kind, again.target, again.spec, again.about) == (
        model.kind,
        model.target,
        model.spec,
        model.about,
    )
    inputs = _inputs()
    np.testing.assert_array_equal(again.predict(*inputs), model.predict(*inputs))
    # One model, one file, one digest: the bytes do not depend on when they were written.
    assert to_bytes(again) == raw
    assert digest(raw) == digest(to_bytes(model)) == digest(bytes(raw))
    assert len(digest(raw)) == 64
    (tmp_path / "model.npz").write_bytes(raw)
    np.testing.assert_array_equal(
        load(tmp_path / "model.npz").predict(*inputs), again.predict(*inputs)
    )


def test_a_model_answers_only_its_own_target():
    q, qd, third = _inputs(3)
    with pytest.raises(WrongTarget, match="forward-dynamics model"):
        MODELS["mlp forward"].inverse(q, qd, third)
    with pytest.raises(WrongTarget, match="inverse-dynamics model"):
        MODELS["rigid inverse"].forward(q, qd, third)
    assert MODELS["mlp forward"].forward(q, qd, third).shape == (3, 7)


def test_inputs_must_be_rows_of_seven_joints():
    q, qd, qdd = _inputs(3)
    with pytest.raises(ValueError, match=r"qdd has shape \(3, 6\)"):
        MODELS["rigid inverse"].inverse(q, qd, qdd[:, :6])
    with pytest.raises(ValueError, match=r"qd has shape \(2, 7\)"):
        MODELS["mlp"].inverse(q, qd[:2], qdd)


def test_a_linear_forward_model_cannot_be_made():
    spec = rigid_spec(REALISTIC_PLANT)
    with pytest.raises(BadDynamicsModel, match="inverse only"):
        DynamicsModel("linear", "forward", spec, parameters=physical_parameters(spec))


# --- bad and hostile bytes ---------------------------------------------------------------------


def _arrays(raw: bytes) -> dict[str, np.ndarray]:
    with np.load(io.BytesIO(raw), allow_pickle=False) as npz:
        return {name: npz[name] for name in npz.files}


def _npz(arrays: dict[str, np.ndarray]) -> bytes:
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    return buffer.getvalue()


def _with_header(raw: bytes, **changes: object) -> bytes:
    arrays = _arrays(raw)
    header = json.loads(arrays["header"].tobytes()) | changes
    arrays["header"] = np.frombuffer(json.dumps(header).encode(), dtype=np.uint8)
    return _npz(arrays)


def _with_array(raw: bytes, name: str, value: np.ndarray | None) -> bytes:
    arrays = _arrays(raw)
    if value is None:
        del arrays[name]
    else:
        arrays[name] = value
    return _npz(arrays)


MLP_BYTES = to_bytes(MODELS["mlp"])
LINEAR_BYTES = to_bytes(MODELS["linear"])
PLANT_BYTES = to_bytes(MODELS["plant"])
NAN_WEIGHTS = np.full((21, 16), np.nan)

BAD = {
    "empty": (b"", "not an .npz archive"),
    "random bytes": (np.random.default_rng(9).bytes(4000), "not an .npz archive"),
    "truncated": (MLP_BYTES[: len(MLP_BYTES) // 2], "not an .npz archive"),
    "no header": (_with_array(MLP_BYTES, "header", None), "no header"),
    "header not JSON": (
        _with_array(MLP_BYTES, "header", np.frombuffer(b"\xff{", dtype=np.uint8)),
        "not JSON",
    ),
    "another format": (_with_header(MLP_BYTES, format="other"), "format"),
    "unknown kind": (_with_header(MLP_BYTES, kind="gaussian-process"), "unknown kind"),
    "unknown target": (_with_header(MLP_BYTES, target="sideways"), "unknown target"),
    "unknown activation": (_with_header(MLP_BYTES, activation="swish"), "unknown activation"),
    "future version": (_with_header(MLP_BYTES, version=99), "version 99"),
    "bad spec": (_with_header(MLP_BYTES, spec={"joints": "wobbly"}), "spec is invalid"),
    "flexible spec": (
        _with_header(MLP_BYTES, spec={"joints": "flexible"}),
        "must be a rigid arm",
    ),
    # The nominal arm a learned model starts from never carries the plant's hidden truth.
    "prior with a payload": (
        _with_header(MLP_BYTES, spec={"joints": "rigid", "payload": 5.0}),
        "must be a rigid arm",
    ),
    "plant with springs": (
        _with_header(PLANT_BYTES, spec={"joints": "flexible", "payload": 5.0}),
        "must be the plant's dynamics",
    ),
    "plant with parameters": (
        _with_array(PLANT_BYTES, "parameters", np.zeros(LINEAR_PARAMETERS)),
        "unexpected ['parameters']",
    ),
    "missing layer": (_with_header(MLP_BYTES, layers=4), "missing"),
    "extra array": (
        _with_array(MLP_BYTES, "surprise", np.zeros(3)),
        "unexpected ['surprise']",
    ),
    "wrong weight shape": (
        _with_array(MLP_BYTES, "layer0_weights", np.zeros((20, 16))),
        "layer0_weights has shape",
    ),
    "wrong bias shape": (
        _with_array(MLP_BYTES, "layer1_biases", np.zeros(15)),
        "layer1_biases has shape",
    ),
    "NaN weights": (_with_array(MLP_BYTES, "layer0_weights", NAN_WEIGHTS), "NaN"),
    "zero scale": (_with_array(MLP_BYTES, "output_scale", np.zeros(7)), "positive"),
    "integer parameters": (
        _with_array(LINEAR_BYTES, "parameters", np.zeros(LINEAR_PARAMETERS, dtype=np.int64)),
        "not a float64 array",
    ),
    "short parameters": (_with_array(LINEAR_BYTES, "parameters", np.zeros(10)), "shape (10,)"),
    "parameters on a network": (
        _with_array(MLP_BYTES, "parameters", np.zeros(LINEAR_PARAMETERS)),
        "unexpected ['parameters']",
    ),
}


@pytest.mark.parametrize("case", BAD)
def test_bad_bytes_are_refused_in_one_line(case):
    raw, message = BAD[case]
    with pytest.raises(BadDynamicsModel) as caught:
        from_bytes(raw)
    assert message in str(caught.value)
    assert "\n" not in str(caught.value)


class _Exploit:
    """Unpickling this runs code: it touches the file named by its argument."""

    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return (exec, (f"import pathlib; pathlib.Path({str(self.marker)!r}).touch()",))


def test_a_pickled_object_array_is_refused_and_never_run(tmp_path):
    marker = tmp_path / "ran"
    exploit = np.empty(1, dtype=object)
    exploit[0] = _Exploit(marker)
    raw = _with_array(MLP_BYTES, "layer0_weights", exploit)  # np.savez pickles object arrays
    with pytest.raises(BadDynamicsModel, match="pickled object array") as caught:
        from_bytes(raw)
    assert "\n" not in str(caught.value)
    assert not marker.exists()


def test_a_member_that_is_not_an_array_is_refused():
    buffer = io.BytesIO(MLP_BYTES)
    with zipfile.ZipFile(buffer, "a") as archive:
        archive.writestr("notes.txt", b"hello")
    with pytest.raises(BadDynamicsModel, match="not an array"):
        from_bytes(buffer.getvalue())


def test_load_names_a_missing_or_bad_file_in_one_line(tmp_path):
    with pytest.raises(BadDynamicsModel, match="cannot read") as caught:
        load(tmp_path / "absent.npz")
    assert "absent.npz" in str(caught.value) and "\n" not in str(caught.value)
    (tmp_path / "bad.npz").write_bytes(b"PK\x03\x04 nonsense")
    with pytest.raises(BadDynamicsModel, match=r"bad\.npz"):
        load(tmp_path / "bad.npz")


# --- bytes that lie about their sizes, and any bytes at all ------------------------------------


def _npy(header: dict, data: bytes = b"", version: tuple[int, int] = (1, 0)) -> bytes:
    """A .npy member whose header says what it likes."""
    buffer = io.BytesIO()
    write = (
        npy_format.write_array_header_1_0
        if version == (1, 0)
        else npy_format.write_array_header_2_0
    )
    write(buffer, {"descr": "<f8", "fortran_order": False, "shape": (1,)} | header)
    return buffer.getvalue() + data


def _archive(members: dict[str, bytes], compression: int = zipfile.ZIP_STORED) -> bytes:
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", compression) as archive:
        for name, content in members.items():
            archive.writestr(name, content)
    return buffer.getvalue()


LIARS = {
    "a terabyte of parameters": (
        _archive({"parameters.npy": _npy({"shape": (10**12,)})}),
        "'parameters.npy': its header claims 8,000,000,000,000 bytes of data, more than the "
        "member's 128",
    ),
    "2**62 squared": (
        _archive({"header.npy": _npy({"shape": (2**62, 2**62), "descr": "|u1"}, b"x" * 64)}),
        "'header.npy': its header claims 21,267,647,932,558,653,966,460,912,964,485,513,216 bytes",
    ),
    "a string of 2 GB": (
        _archive({"header.npy": _npy({"descr": "<U500000000"})}, zipfile.ZIP_DEFLATED),
        "'header.npy': its header claims 2,000,000,000 bytes of data",
    ),
    "a negative shape": (
        _archive({"parameters.npy": _npy({"shape": (-1, 3)})}),
        "'parameters.npy': a negative shape (-1, 3)",
    ),
    "an object array": (
        _archive({"parameters.npy": _npy({"descr": "|O"}, b"\x80")}),
        "pickled object array: refused",
    ),
    "a format 2 header": (
        _archive({"parameters.npy": _npy({"shape": (10**9,)}, version=(2, 0))}),
        "its header claims 8,000,000,000 bytes",
    ),
    "a format 9 header": (
        _archive({"parameters.npy": b"\x93NUMPY\x09\x00" + b"\x00" * 64}),
        "'parameters.npy': .npy format (9, 0) is not read",
    ),
    "no header at all": (
        _archive({"parameters.npy": b"\x93NUMPY\x01\x00\xff\xff{'descr'"}),
        "'parameters.npy': unreadable (",
    ),
    "a name across lines": (
        _archive({"a\nb.npy": _npy({"shape": (10**6,)})}),
        "'a\\nb.npy': its header claims 8,000,000 bytes",
    ),
}


@pytest.mark.parametrize("case", LIARS)
def test_a_file_lying_about_its_sizes_is_refused_before_anything_is_allocated(case: str) -> None:
    raw, reason = LIARS[case]
    assert len(raw) < 400  # the red team's was 192 bytes
    tracemalloc.start()
    try:
        with pytest.raises(BadDynamicsModel) as caught:
            from_bytes(raw)
        allocated = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert reason in str(caught.value) and "\n" not in str(caught.value)
    assert allocated < 2**20


def _loads_or_refuses(raw: bytes) -> None:
    try:
        from_bytes(raw)
    except BadDynamicsModel as error:
        assert str(error) and "\n" not in str(error)


@given(raw=st.binary(max_size=4096))
@settings(max_examples=300, deadline=None)
def test_any_bytes_are_a_model_or_refused_in_one_line(raw: bytes) -> None:
    _loads_or_refuses(raw)
    _loads_or_refuses(b"PK\x03\x04" + raw)  # past the first test of a zip


@given(data=st.data())
@settings(max_examples=300, deadline=None)
def test_a_real_file_truncated_or_altered_is_a_model_or_refused_in_one_line(data) -> None:
    honest = data.draw(st.sampled_from([MLP_BYTES, LINEAR_BYTES]))
    _loads_or_refuses(honest[: data.draw(st.integers(0, len(honest) - 1))])
    altered = bytearray(honest)
    for _ in range(data.draw(st.integers(1, 8))):
        altered[data.draw(st.integers(0, len(honest) - 1))] = data.draw(st.integers(0, 255))
    _loads_or_refuses(bytes(altered))


def test_every_truncation_of_a_real_file_is_refused_in_one_line() -> None:
    for end in range(len(LINEAR_BYTES)):
        with pytest.raises(BadDynamicsModel):
            from_bytes(LINEAR_BYTES[:end])
