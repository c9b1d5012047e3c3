"""The `analytic` commands, one module each (start.py is `analytic start`).

The group (gainfarm.analytic.cli) knows every command's name, module and summary without importing
it; a command's module imports click and the light options at its top and the rest inside its
function, so that parsing (and refusing) a command line costs little more than `import click`.
"""
