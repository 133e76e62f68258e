"""Export a trained policy as an ONNX model or a torch.export program.

usage: trl-cartpole export [checkpoint=]RUN_DIR output=policy.onnx

RUN_DIR is the directory training printed (its best policy is exported; before its first
evaluation, its newest training state's) or one checkpoint in it. The suffix of output picks
the format: .onnx (needs the export extra) or .pt2.
The model maps observations [batch, obs_dim] to action values [batch, num_actions] with the
run's observation normalisation folded in; the greedy action is their arg-max (docs/export.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from trl_cartpole.config.help import parse_args
from trl_cartpole.errors import ConfigError
from trl_cartpole.policy.formats import FORMATS, check_onnx_installed
from trl_cartpole.report.console import command
from trl_cartpole.store.files import check_checkpoint_exists


@dataclass
class ExportArgs:
    checkpoint: str = "???"  # a run directory (its checkpoints/best) or a checkpoint directory
    output: str = "???"  # the file to write: .onnx (ONNX) or .pt2 (torch.export program)


def main(argv: list[str]) -> None:
    args = parse_args(ExportArgs, argv, __doc__, command("export"), positional="checkpoint")
    check_checkpoint_exists(args.checkpoint)  # every check before the heavy imports below
    output = Path(args.output)
    if output.suffix not in FORMATS:
        raise ConfigError(
            f"output={args.output!r} has suffix {output.suffix!r}; end it in .onnx (ONNX) or "
            ".pt2 (torch.export program)"
        )
    if not output.parent.is_dir():
        raise ConfigError(
            f"output={args.output!r}: directory {str(output.parent)!r} does not exist"
        )
    kind, exporter = FORMATS[output.suffix]
    if output.suffix == ".onnx":
        check_onnx_installed()
    # imported after the arguments are checked: a refusal comes before torch is loaded
    from trl_cartpole.policy import export
    from trl_cartpole.report.progress_bar import clear_status, show_status

    try:
        show_status(f"loading the policy of {args.checkpoint}")
        module = export.greedy_q_network(args.checkpoint)
        show_status(f"exporting it as {kind}")
        getattr(export, exporter)(module, module.obs_dim, output)
    finally:
        clear_status()
    shape = ", ".join(str(size) for size in module.input_shape)
    dtype = str(module.input_dtype).removeprefix("torch.")
    print(
        f"wrote the {kind} {output}: {module.input_name} [batch, {shape}] {dtype} -> "
        f"action_values [batch, {module.num_actions}] (greedy action: their arg-max); "
        "how to run it: docs/export.md"
    )
