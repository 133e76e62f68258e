"""``python scripts/tune.py [key=value ...]`` is ``trl-cartpole tune``, run from a clone.

``--help`` lists its keys; the code is ``trl_cartpole.cli.commands.tune``.
"""

from trl_cartpole.cli.main import exit_process, run_script

if __name__ == "__main__":
    exit_process(run_script("tune", __file__))
