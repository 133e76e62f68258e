"""The named choices the configuration checks before torch is imported and the factories build.

It imports nothing, so the schema's validation (``config/``) and the factories (``parts/``)
read the same names. The defaults live where they belong: a factory's in its signature (the
TorchRL class's own), the default run's in the schema (``config/schema.py``).
"""

HEADS = ("dueling", "plain")  # network heads, built by trl_cartpole.parts.models.HEADS
ACTIVATIONS = ("elu", "gelu", "relu", "tanh")  # torch.nn activations by name
SCHEDULES = ("exponential", "linear", "none")  # epsilon schedules (none: noisy networks)
GRAD_CLIPS = ("value", "norm", "none")
COLLECTOR_BACKENDS = ("local", "ray")
TARGET_UPDATERS = ("hard", "soft")  # HardUpdate | SoftUpdate
