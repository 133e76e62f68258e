"""``python scripts/render.py [key=value ...]`` is ``trl-cartpole render``, run from a clone.

``--help`` lists its keys; the code is ``trl_cartpole.commands.render``.
"""

import sys

from trl_cartpole.cli import run_script

if __name__ == "__main__":
    sys.exit(run_script("render", __file__))
