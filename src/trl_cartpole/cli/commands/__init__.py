"""The subcommands of ``trl-cartpole`` (and of ``python scripts/NAME.py``): one module each.

Each module's docstring is its usage and its ``main(argv)`` reads ``key=value`` arguments;
:func:`trl_cartpole.cli.main.run_cli` reports bad input in one line with exit status 2.
"""
