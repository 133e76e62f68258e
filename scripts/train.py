"""``python scripts/train.py [key=value ...]`` is ``trl-cartpole train``, run from a clone.

``--help`` lists its keys; the code is ``trl_cartpole.cli.commands.train``.
"""

from trl_cartpole.cli.main import exit_process, run_script

if __name__ == "__main__":
    exit_process(run_script("train", __file__))
