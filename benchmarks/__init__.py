"""Benchmarks of trl_cartpole, run from the repository root: ``python -m benchmarks <subcommand>``.

Not installed with the package: these tools import ``trl_cartpole``, never the reverse.
"""
