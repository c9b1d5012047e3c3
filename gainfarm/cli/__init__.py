"""What the three command lines (`worker`, `broker`, `analytic`) share: one error line and exit
status for bad input, a group that imports only the command run (app.py), the options several
commands take (options.py), and scores printed for a person.

The edge of every role: it imports of the project only what lies below it (schemas/, models/,
the plug-in registry, edges/), and that inside the functions that use it, so that a command line
is parsed at the cost of `import click`.
"""
