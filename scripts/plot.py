"""``python scripts/plot.py [key=value ...]`` is ``trl-cartpole plot``, run from a clone.

``--help`` lists its keys; the code is ``trl_cartpole.cli.commands.plot``.
"""

from trl_cartpole.cli.main import exit_process, run_script

if __name__ == "__main__":
    exit_process(run_script("plot", __file__))
