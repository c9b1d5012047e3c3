"""What the three command lines (`worker`, `broker`, `analytic`) share: one error line and exit
status for bad input, a group that imports only the command run (app.py), the options several
commands take (options.py: light, what a command's module declares them with) and what their
values are made into (values.py: the contract's objects, loaded when a command runs), and scores
printed for a person.

The edge of every role: it imports of the project only what lies below it (schemas/, models/,
the plug-in registry, edges/), so that a command line is parsed at the cost of `import click`.
"""
