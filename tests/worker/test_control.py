import numpy as np

from gainfarm.schemas import PDGains
from gainfarm.worker.control import PDController

LIMITS = np.array([320, 320, 176, 176, 110, 40, 40.0])


def controller() -> PDController:
    return PDController.from_gains(
        PDGains(kp=(100, 200, 300, 400, 500, 600, 700), kd=(1, 2, 3, 4, 5, 6, 7)), LIMITS
    )


def test_pd_law_by_hand():
    pd = controller()
    q, qd = np.zeros(7), np.zeros(7)
    q_des, qd_des = np.full(7, 0.01), np.full(7, 0.5)
    expected = np.array([100, 200, 300, 400, 500, 600, 700]) * 0.01 + np.arange(1, 8) * 0.5
    np.testing.assert_allclose(pd.torque(q, qd, q_des, qd_des), expected)


def test_torque_saturates_at_the_limits():
    pd = controller()
    tau = pd.torque(np.zeros(7), np.zeros(7), np.full(7, 10.0), np.zeros(7))
    np.testing.assert_array_equal(tau, LIMITS)
    tau = pd.torque(np.zeros(7), np.zeros(7), np.full(7, -10.0), np.zeros(7))
    np.testing.assert_array_equal(tau, -LIMITS)


def test_folded_form_equals_the_law_on_an_elastic_state():
    pd = controller()
    rng = np.random.default_rng(0)
    link_map = np.kron(np.eye(7), np.ones((1, 2)))  # q_i = motor_i + spring_i
    qpos, qvel = rng.normal(size=14) * 0.1, rng.normal(size=14)
    q_des, qd_des = rng.normal(size=7) * 0.1, rng.normal(size=7)
    kp_state, kd_state = pd.state_gains(link_map)
    folded = pd.reference_term(q_des, qd_des) - kp_state @ qpos - kd_state @ qvel
    np.testing.assert_allclose(
        folded, pd.kp * (q_des - link_map @ qpos) + pd.kd * (qd_des - link_map @ qvel)
    )
