"""How a dataset names its arm to others: LeRobot's `robot_type` and the card's words.

The shipped arms have the names their makers give them; a user's own arm (a robot description
file) is named by its plug-in name, as `--robot` gave it."""

from collections.abc import Sequence

# LeRobot's info.json `robot_type` of each shipped arm: the maker and the model, lower case.
ROBOT_TYPES = {
    "iiwa14": "kuka_iiwa14",
    "panda": "franka_panda",
    "ur5e": "universal_robots_ur5e",
    "gen3": "kinova_gen3",
}
TITLES = {
    "iiwa14": "KUKA LBR iiwa 14",
    "panda": "Franka Emika Panda",
    "ur5e": "Universal Robots UR5e",
    "gen3": "Kinova Gen3",
}


def robot_type(robot: str) -> str:
    """LeRobot's `robot_type` of `robot` (a gainfarm.robots name): the maker's model, or the name
    itself for an arm of one's own."""
    return ROBOT_TYPES.get(robot, robot)


def title(robot: str) -> str:
    """The arm as a card names it: 'KUKA LBR iiwa 14', or `my_arm` for an arm of one's own."""
    return TITLES.get(robot, f"`{robot}` (a robot description of one's own)")


def joint_range(joints: Sequence[str]) -> str:
    """A per-joint column family's suffixes as the card writes them: A1..A7, or each joint."""
    if len(joints) > 2 and all(joint == f"A{i}" for i, joint in enumerate(joints, start=1)):
        return f"{joints[0]}..{joints[-1]}"
    return "{" + ",".join(joints) + "}"
