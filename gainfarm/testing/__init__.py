"""The conformance kit: pytest-ready checks a plug-in's author runs on what it adds to gainfarm
(docs/plugins.md, "Checking your plug-in"), and gainfarm runs on its own built-ins. They need
pytest (gainfarm's `test` extra); nothing of gainfarm imports them.

    algorithms      an optimiser (gainfarm.algorithms): determinism, ask and tell's shape and
                    bounds, a checkpoint's round trip that continues identically
    trajectories    a trajectory kind (gainfarm.trajectories): determinism, the flange path's
                    shape, finiteness and rests, feasibility of a sensible spec, the one-line
                    refusal of one too fast, naming the shortest duration
    objectives      an objective (gainfarm.objectives): its declaration (name, unit, direction),
                    deterministic and finite on real episodes, a fallen arm scored worse, the
                    no-episode score worse still
    robots          a robot (gainfarm.robots): its name, limits, model (rigid and flexible), that
                    its default gains hold it, its gravity model against MuJoCo's, its workspace
    experiments     an experiment (gainfarm.experiments): its declaration, its options' refusals,
                    a tiny run's files, deterministic
"""
