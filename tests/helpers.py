"""Constants the tests share."""

from schemas import PDGains

TRACKING_GAINS = PDGains(kp=(2000, 2000, 1200, 1200, 400, 200, 100), kd=(60, 60, 40, 40, 10, 5, 2))
SOFT_GAINS = PDGains(kp=(200, 200, 120, 120, 40, 20, 10), kd=(20, 20, 12, 12, 4, 2, 1))
WEAK_GAINS = PDGains(kp=(5,) * 7, kd=(1,) * 7)  # too soft to hold the arm up
