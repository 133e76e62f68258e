"""The trl-cartpole command: the entry point (:func:`trl_cartpole.cli.main.console_main`), exit
codes, one-line errors, and one module per subcommand.
"""
