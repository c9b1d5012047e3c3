"""The `analytic` commands, one module each (start.py is `analytic start`).

The group (gainfarm.analytic.cli) knows every command's name, module and summary without importing
it; a command's module declares its options with click and the light options at its top, and its
function refuses what a parse or a stat can (shared.prechecked) and then imports its work,
work/NAME.py, its one import inside a function: parsing a command line, and --help, cost little
more than `import click`, and a refused option loads none of MuJoCo, Zenoh, matplotlib, pymoo.
"""
