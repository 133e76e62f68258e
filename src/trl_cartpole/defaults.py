"""Every default and named choice that the configuration and the factories share, stated once.

It imports nothing: the schema (``config/schema.py``, which ``--help`` and the presets' docs
read) and the factories' signatures (``parts/``, which the reference's defaults table reads)
take their values from here, so the two cannot drift. ``configs/algo/dqn.yaml`` restates the
schema for readers; ``tests/test_defaults.py`` holds it equal.
"""

from __future__ import annotations

# --- named choices (the config checks them before torch is imported; the parts build them) ---
HEADS = ("dueling", "plain")  # network heads, built by trl_cartpole.parts.models.HEADS
ACTIVATIONS = ("elu", "gelu", "relu", "tanh")  # torch.nn activations by name
SCHEDULES = ("exponential", "linear", "none")  # epsilon schedules (none: noisy networks)
GRAD_CLIPS = ("value", "norm", "none")
COLLECTOR_BACKENDS = ("local", "ray")

# --- defaults: the default run (CartPole-v1, DQN with 3-step returns) ---------------------------
ENV_ID = "CartPole-v1"
HIDDEN_SIZES = (128, 128)  # the MLP's hidden widths
ACTIVATION = "relu"
NOISY_STD = 0.5  # sigma_0 of NoisyLinear's factorised noise (Fortunato et al. 2018)
# the CNN torso: the PyTorch DQN tutorial's first, pixel version (three 5x5, stride-2 convolutions)
CNN_CHANNELS, CNN_KERNELS, CNN_STRIDES = (16, 32, 32), (5, 5, 5), (2, 2, 2)
EPS_START, EPS_END, DECAY_FRAMES = 1.0, 0.05, 3000  # epsilon-greedy, linear
BUFFER_SIZE, BATCH_SIZE = 50_000, 512
ALPHA, BETA, PRIORITY_EPS = 0.6, 0.4, 1e-6  # prioritized replay; ALPHA is on |delta|
N_STEPS = 3  # the default run's n-step returns (a factory's buffer: 1 unless asked)
GAMMA = 0.995
LOSS_FUNCTION = "smooth_l1"  # Huber, as the PyTorch DQN tutorial
TAU = 0.02  # a soft target update's step
HARD_UPDATE_INTERVAL = 50  # gradient updates between hard target copies
LR, AMSGRAD, WEIGHT_DECAY = 4e-3, True, 0.0  # AdamW
ADAM_EPS = 1e-8  # AdamW's own: the floor under its denominator
GRAD_CLIP, MAX_GRAD = "norm", 10.0
TOTAL_FRAMES, FRAMES_PER_BATCH, INIT_RANDOM_FRAMES = 50_000, 32, 1000
