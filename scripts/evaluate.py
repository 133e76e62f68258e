"""``python scripts/evaluate.py [key=value ...]`` is ``trl-cartpole evaluate``, run from a clone.

``--help`` lists its keys; the code is ``trl_cartpole.cli.commands.evaluate``.
"""

from trl_cartpole.cli.main import exit_process, run_script

if __name__ == "__main__":
    exit_process(run_script("evaluate", __file__))
