"""``python scripts/export.py [key=value ...]`` is ``trl-cartpole export``, run from a clone.

``--help`` lists its keys; the code is ``trl_cartpole.cli.commands.export``.
"""

from trl_cartpole.cli.main import exit_process, run_script

if __name__ == "__main__":
    exit_process(run_script("export", __file__))
