"""Gains files: what `--gains` reads, and its refusals in the user's words."""

import json

import pytest
import yaml

from gainfarm.models.ur5e import JOINT_NAMES as UR5E_JOINT_NAMES
from gainfarm.schemas.controller import (
    BadGains,
    Controller,
    Member,
    Source,
    read_controller,
    read_gains,
)
from gainfarm.schemas.gains import DEFAULT_GAINS, PDGains
from gainfarm.schemas.robot import JOINT_NAMES, PlantSpec
from gainfarm.schemas.trajectory import TrajectorySpec

GAINS = DEFAULT_GAINS.model_dump()
SOFT = PDGains(kp=(100.0,) * 7, kd=(1.0,) * 7)


# The UR5e's joints, as ur_description names them: a 6-joint arm's.
UR5E = UR5E_JOINT_NAMES


def exported(gains: PDGains, joints: tuple[str, ...] = JOINT_NAMES, robot: str = "iiwa14") -> dict:
    """A controller as `analytic export` writes it, of the arm `robot` of `joints`."""
    return json.loads(
        Controller(
            joints=joints,
            kp=gains.kp,
            kd=gains.kd,
            member=Member(selected="knee", row=3, rule="r", f_acc=0.01, f_t=0.1, diverged=False),
            source=Source(
                run_id="ab" * 16,
                directory="runs/x",
                config_sha256="0" * 64,
                front_sha256="1" * 64,
                trajectories=(TrajectorySpec(),),
                plant="realistic",
                model=PlantSpec(robot=robot),
                population=30,
                algorithm="nsga2",
                seed=0,
                stopped="3 generations",
            ),
        ).model_dump_json()
    )


def test_a_controller_a_list_and_a_bare_object_are_all_gains() -> None:
    assert read_gains(json.dumps(exported(SOFT)).encode()) == [SOFT]
    # The list `analytic batch --gains` has always read, and controllers in a list.
    assert read_gains(json.dumps([GAINS, exported(SOFT)]).encode()) == [DEFAULT_GAINS, SOFT]
    assert read_gains(json.dumps(GAINS).encode()) == [DEFAULT_GAINS]


@pytest.mark.parametrize(
    ("document", "says"),
    [
        ([], "the list of candidates is empty"),
        ([GAINS, 7], 'candidate 2: expected an object with "kp" and "kd", got int'),
        ({**GAINS, "kp": [1, 2]}, "kp: 2 gains given, 7 needed (A1..A7)"),
        (
            {**GAINS, "kd": [1, 1, 1, 1, 1, 1, -2]},
            "kd of A7: -2 is negative (gains are at least 0)",
        ),
        (
            {**GAINS, "kp": [1, 1, -1, 1, 1, 1, -2]},
            "kp of A3: -1 is negative (gains are at least 0) (and 1 more problem)",
        ),
        ({"kd": GAINS["kd"]}, "kp missing: 7 gains needed (A1..A7)"),
        ({**GAINS, "kp": "fast"}, "kp: expected a list of 7 numbers, got 'fast'"),
        ({**GAINS, "ki": [0] * 7}, "unknown field 'ki'"),
        ({**exported(SOFT), "format": "gainfarm-controller/2"}, "format 'gainfarm-controller/2'"),
        ({**exported(SOFT), "kp": [1] * 6}, "kp: 6 gains given, 7 needed"),
    ],
)
def test_a_bad_gains_file_says_which_candidate_which_gain_and_what(
    document: object, says: str
) -> None:
    with pytest.raises(BadGains) as refused:
        read_gains(json.dumps(document).encode())
    assert str(refused.value) == says or str(refused.value).startswith(says)
    assert "Input should" not in str(refused.value)  # not pydantic's words


def test_non_finite_gains_and_files_that_are_neither_json_nor_yaml_are_refused() -> None:
    with pytest.raises(BadGains, match=r"kp of A1: inf is not finite"):
        read_gains(b'{"kp": [1e999, 1, 1, 1, 1, 1, 1], "kd": [1, 1, 1, 1, 1, 1, 1]}')
    expected = (
        'expected a controller from `analytic export` or a list of {"kp": [a number per '
        'joint], "kd": [a number per joint]}'
    )
    for raw, says in (
        (b'{"kp": [1,', f"not JSON (Expecting value at line 1 column 11); {expected}"),
        (
            b"kp: [1\n",
            "not JSON or YAML (expected ',' or ']', but got '<stream end>' at line 2 column 1); "
            + expected,
        ),
        (b"\xff\xfe", "not JSON or YAML text (binary data)"),
        (b"", f"empty; {expected}"),
        (b"fast", f"a lone value ('fast'), not gains; {expected}"),
        (b"kp: [1]", "kp: 1 gains given, 7 needed (A1..A7) (and 1 more problem)"),  # YAML
    ):
        with pytest.raises(BadGains) as refused:
            read_gains(raw)
        assert str(refused.value) == says
    with pytest.raises(BadGains, match=r"a run's front\.csv, not a controller"):
        read_gains(b"kp1,kp2,kp3\n")


def test_a_yaml_controller_is_the_same_controller_as_its_json() -> None:
    document = exported(SOFT)
    as_yaml = yaml.safe_dump(document, allow_unicode=True, sort_keys=False).encode()
    assert read_gains(as_yaml) == read_gains(json.dumps(document).encode()) == [SOFT]
    assert read_controller(as_yaml) == read_controller(json.dumps(document).encode())
    assert read_controller(as_yaml) is not None
    listed = yaml.safe_dump([GAINS, document]).encode()
    assert read_gains(listed) == [DEFAULT_GAINS, SOFT]


def test_a_controller_is_read_for_its_own_arm_and_refused_for_another_in_one_line() -> None:
    six = PDGains(kp=(1000.0, 1000.0, 1000.0, 187.0, 187.0, 187.0), kd=(10.0,) * 3 + (1.87,) * 3)
    ur5e = json.dumps(exported(six, UR5E, "ur5e")).encode()
    assert read_gains(ur5e, UR5E) == [six]  # the UR5e's, for the UR5e
    assert read_controller(ur5e).robot == "ur5e"  # type: ignore[union-attr]
    refusals = {
        # The UR5e's controller for the iiwa (the default joints), and the iiwa's for the UR5e.
        (ur5e, JOINT_NAMES): "a controller of ur5e's 6 joints ('shoulder_pan_joint'.."
        "'wrist_3_joint'), not of this arm's 7 (A1..A7)",
        (json.dumps(exported(SOFT)).encode(), UR5E): "a controller of iiwa14's 7 joints ('A1'.."
        "'A7'), not of this arm's 6 (shoulder_pan_joint..wrist_3_joint)",
        # Another arm of as many joints (a Gen3's 7): refused by its names, not let by its count.
        (
            json.dumps(
                [GAINS, exported(SOFT, tuple(f"joint_{k}" for k in range(1, 8)), "gen3")]
            ).encode(),
            JOINT_NAMES,
        ): "candidate 2: a controller of gen3's 7 joints ('joint_1'..'joint_7'), not of this "
        "arm's 7 (A1..A7)",
        # Bare gains: counted against the arm's joints.
        (json.dumps(GAINS).encode(), UR5E): "kp: 7 gains given, 6 needed (shoulder_pan_joint.."
        "wrist_3_joint) (and 1 more problem)",
    }
    for (raw, joints), says in refusals.items():
        with pytest.raises(BadGains) as refused:
            read_gains(raw, joints)
        assert str(refused.value) == says


def test_a_controller_naming_its_arm_oddly_is_not_echoed() -> None:
    document = exported(PDGains(kp=(1.0,) * 6, kd=(1.0,) * 6), UR5E, "ur5e")
    document["source"]["model"]["robot"] = "<script>" * 20
    with pytest.raises(BadGains) as refused:
        read_gains(json.dumps(document).encode())
    assert str(refused.value).startswith("a controller of another arm's 6 joints (")
    assert "<script>" not in str(refused.value)
