"""The trl-cartpole command: the entry point, exit codes, one-line errors, and one module per
subcommand.
"""
