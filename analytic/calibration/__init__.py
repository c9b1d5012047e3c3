"""Calibration: from a real arm's logs to a simulation twin (`analytic excite`, `calibrate`,
`validate`)."""
