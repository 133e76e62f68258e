"""``python scripts/train.py [key=value ...]`` is ``trl-cartpole train``, run from a clone.

``--help`` lists its keys; the code is ``trl_cartpole.commands.train``.
"""

import sys

from trl_cartpole.cli import run_script

if __name__ == "__main__":
    sys.exit(run_script("train", __file__))
