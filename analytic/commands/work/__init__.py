"""What each `analytic` command does once it runs, one module per command (work/start.py is
`analytic start`'s) and two they share: common.py (the options made into the contract's objects,
light) and tuning.py (the farm and a run's progress, heavy).

analytic/commands/NAME.py declares the command's options and imports work/NAME.py when the
command runs, its one import inside a function: the command line is parsed, and --help shown,
at the cost of `import click`; a bad option is refused before MuJoCo, Zenoh, pymoo or
matplotlib load.
"""
