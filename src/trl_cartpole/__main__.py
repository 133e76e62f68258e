"""``python -m trl_cartpole COMMAND [key=value ...]``: the ``trl-cartpole`` command."""

import sys

from trl_cartpole.cli import main

sys.exit(main())
