"""The trl-cartpole command: the entry point, exit codes, one-line errors, and one module per
subcommand.
"""


def console_main() -> None:
    """``trl_cartpole.cli:console_main``, the entry point of installs made before the command
    moved to :mod:`trl_cartpole.cli.main` (a reinstall points at the new one)."""
    from trl_cartpole.cli.main import console_main as main

    main()
