"""``python scripts/render.py [key=value ...]`` is ``trl-cartpole render``, run from a clone.

``--help`` lists its keys; the code is ``trl_cartpole.cli.commands.render``.
"""

from trl_cartpole.cli.main import exit_process, run_script

if __name__ == "__main__":
    exit_process(run_script("render", __file__))
