"""The ``trl-cartpole`` command and the plumbing its subcommands share.

``trl-cartpole train|evaluate|render|export|tune|plot key=value ...`` runs
``trl_cartpole.cli.commands.<name>.main``; ``python scripts/<name>.py`` (a clone's way) runs
the same function. Every subcommand takes ``key=value`` arguments and ``--help``.

Bad input (an unknown key, a wrong type, an impossible value, an unknown env, a bad
checkpoint) ends the program with one line on stderr and exit status 2, before any training.
An interrupted run exits with 128 + the signal (130 for Ctrl-C) after one line saying how to
resume (a second signal ends the process at once by the signal's default action, keeping the
newest complete checkpoint); a numerical fault exits with 1; a full disk exits with 74
(``EX_IOERR``) after one line naming the path, the space needed and the resume command; a lost
Ray actor exits with 75 (``EX_TEMPFAIL``) after a checkpoint and one line naming the actor and
the resume command. Set ``HYDRA_FULL_ERROR=1`` to get the full traceback instead.
"""

from __future__ import annotations

import contextlib
import errno
import gc
import os
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NoReturn

from hydra.errors import HydraException
from omegaconf.errors import OmegaConfBaseException

from trl_cartpole.config.messages import explain
from trl_cartpole.errors import (
    ConfigError,
    DiskFull,
    TrainingFailed,
    TrainingInterrupted,
    WorkerLost,
)
from trl_cartpole.report.console import command, quiet_libraries, set_scripts_dir
from trl_cartpole.run.signals import install_unbreakable_console, second_signal_ends_process

__all__ = [
    "COMMANDS",
    "main",
    "one_line",
    "run_cli",
    "run_script",
    "split_resume",
]

EXIT_BAD_INPUT = 2
EXIT_FAILED = 1
EXIT_KEYBOARD_INTERRUPT = 130
EXIT_DISK_FULL = 74  # sysexits.h's EX_IOERR
EXIT_WORKER_LOST = 75  # sysexits.h's EX_TEMPFAIL: resuming is the retry


_NOISE = (
    "To append to your config",
    "full_key:",
    "object_type=",
    "reference_type=",
    "Config search path",
    "provider=",
)


def one_line(error: BaseException) -> str:
    """Join the informative lines of ``error`` and its causes into one line.

    A chain of causes may loop (OmegaConf's errors can name each other): each is read once.
    """
    parts: list[str] = []
    seen: set[int] = set()
    current: BaseException | None = error
    while current is not None and id(current) not in seen:
        seen.add(id(current))
        for line in str(current).splitlines():
            line = line.strip().rstrip(".:")
            if line and not line.startswith(_NOISE) and line not in parts:
                parts.append(line)
        current = current.__cause__
    return ": ".join(parts) if parts else type(error).__name__


def split_resume(argv: Sequence[str]) -> tuple[str | None, list[str]]:
    """Take ``resume=PATH`` out of the overrides: ``(PATH or None, the other overrides)``."""
    resume = [arg.split("=", 1)[1] for arg in argv if arg.startswith("resume=")]
    others = [arg for arg in argv if not arg.startswith("resume=")]
    if len(resume) > 1:
        raise ConfigError("resume= is given more than once; pass one run directory")
    return (resume[0] if resume else None), others


def run_cli(main: Callable[[list[str]], Any], argv: Sequence[str] | None = None) -> int:
    """Run ``main(argv)``; report bad input, interrupts and faults in one line with its code."""
    argv = list(sys.argv[1:] if argv is None else argv)
    # for the rest of the process: the messages below and Python's last flush at exit too
    install_unbreakable_console()
    try:
        # a second stop signal ends the run whatever it is doing (docs/reliability.md)
        with quiet_libraries(), second_signal_ends_process():
            main(argv)
    except (ConfigError, HydraException, OmegaConfBaseException) as error:
        if os.environ.get("HYDRA_FULL_ERROR") == "1":
            raise
        line = one_line(error)
        if not isinstance(error, ConfigError):  # Hydra's words: the project's where it has them
            line = explain(line, command("train"), argv) or line
        print(f"error: {line}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except TrainingInterrupted as interrupted:
        print(str(interrupted), file=sys.stderr)
        return interrupted.exit_code
    except TrainingFailed as failure:
        print(f"error: {failure}", file=sys.stderr)
        return EXIT_FAILED
    except DiskFull as full:
        print(f"error: {full}", file=sys.stderr)
        return EXIT_DISK_FULL
    except WorkerLost as lost:
        print(f"error: {lost}", file=sys.stderr)
        return EXIT_WORKER_LOST
    except OSError as error:
        if error.errno != errno.ENOSPC:
            raise
        where = "" if error.filename is None else f" writing {error.filename}"
        print(
            f"error: no space left on the disk{where}; free some space, then resume the run "
            f"from its newest checkpoint: {command('train')} resume=RUN_DIR",
            file=sys.stderr,
        )
        return EXIT_DISK_FULL
    except KeyboardInterrupt:
        print("interrupted: exited at once", file=sys.stderr)
        return EXIT_KEYBOARD_INTERRUPT
    return 0


# subcommand: what it does (the modules are imported only when chosen, so --help is instant)
COMMANDS = {
    "train": "train DQN until it solves its env (CartPole-v1 by default)",
    "evaluate": "evaluate a trained policy greedily over many episodes",
    "render": "watch a trained agent: greedy episodes as a GIF/MP4, or live in a window",
    "export": "export a trained policy as an ONNX model or a torch.export program",
    "tune": "tune hyperparameters with Optuna and write the best trial as a preset",
    "plot": "compare runs: eval return against frames and seconds, per config",
}
USAGE = "usage: trl-cartpole COMMAND [key=value ...]   (trl-cartpole COMMAND --help for its keys)"


def _command_main(name: str) -> Callable[[list[str]], Any]:
    import importlib

    return importlib.import_module(f"trl_cartpole.cli.commands.{name}").main


def main(argv: Sequence[str] | None = None) -> int:
    """``trl-cartpole COMMAND [key=value ...]``: the installed command (``[project.scripts]``)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    listing = "\n".join(f"  {name:<9} {text}" for name, text in COMMANDS.items())
    if not argv or argv[0] in ("-h", "--help"):
        print(f"{USAGE}\n\ncommands:\n{listing}", file=sys.stdout if argv else sys.stderr)
        return 0 if argv else EXIT_BAD_INPUT
    name, rest = argv[0], argv[1:]
    if name not in COMMANDS:
        print(
            f"error: {name!r} is not a trl-cartpole command; choose one of {list(COMMANDS)}",
            file=sys.stderr,
        )
        return EXIT_BAD_INPUT
    set_scripts_dir(None)
    return run_cli(_command_main(name), rest)


def console_main() -> NoReturn:
    """The ``trl-cartpole`` executable: :func:`main`, then :func:`exit_process`."""
    exit_process(main())


def freeze_imported_objects() -> None:
    """Keep the objects alive now out of the cyclic garbage collector's scans (``gc.freeze``).

    Once torch, TorchRL and the rest are imported a process holds about 460 000 objects, and
    every full collection the training loop's allocations trigger walks them all (0.3 s each,
    measured). They live as long as the process, so a command freezes them before it trains;
    objects made afterwards are collected as usual.
    """
    gc.collect()
    gc.freeze()


def exit_process(status: int) -> NoReturn:
    """End the process with ``status`` as ``sys.exit`` does, without the interpreter's teardown.

    Python's exit first does what a finished command needs: it joins the non-daemon threads
    (after the hooks that tell pools to stop), runs the ``atexit`` functions (Ray's shutdown,
    multiprocessing's children, logging's flush) and flushes stdout and stderr. Then it frees
    every module and object one by one: about 1.4 s once torch and TorchRL are imported, for
    nothing anyone reads (docs/results/speed.md). This does the first part, with the same
    private hooks the interpreter calls (``compat.run_exit_steps``), and ends with ``os._exit``;
    a command that never imported torch exits as usual (its teardown is quick). For a
    command's end only: in a process that goes on (a test, a notebook) call the command's
    function instead.
    """
    if "torch" not in sys.modules:
        sys.exit(status)
    from trl_cartpole.compat import run_exit_steps  # imports torch, as the command did

    run_exit_steps()
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(OSError, ValueError):  # a closed pipe: nothing more to say
            stream.flush()
    os._exit(status)


def run_script(name: str, script: str | Path, argv: Sequence[str] | None = None) -> int:
    """``python scripts/NAME.py ...``: subcommand ``name``, its printed commands naming scripts.

    ``argv`` defaults to the process's own arguments.
    """
    set_scripts_dir(Path(script).resolve().parent)
    return run_cli(_command_main(name), argv)
