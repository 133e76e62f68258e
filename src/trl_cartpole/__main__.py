"""``python -m trl_cartpole COMMAND [key=value ...]``: the ``trl-cartpole`` command."""

from trl_cartpole.cli.main import console_main

console_main()
