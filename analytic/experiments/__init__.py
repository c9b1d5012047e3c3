"""The experiments, one module each, and what they share.

An experiment is a module holding an `ExperimentSpec` named EXPERIMENT: its name, its own
options, and the function that runs it, computes its table and draws its figure. They are the
plug-in group `gainfarm.experiments` (registry: the declaration and its lookup by name), and
share the runner of their tuning runs (runner), the normalised space their hypervolumes are taken
in (normalisation), the findings every experiment states alike (findings), their statistics
(statistics) and the frame of their reports and figures (report).
"""
