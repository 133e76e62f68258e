"""The environments' own code: what an env is and how it is seen, apart from the factories.

- :mod:`~trl_cartpole.envs.ids`: Gymnasium ids, solve thresholds, whether DQN fits an env
  (torch-free, so a command line is checked before torch is imported);
- :mod:`~trl_cartpole.envs.atari`: an ALE game preprocessed as in Mnih et al. (2015), as
  TorchRL transforms;
- :mod:`~trl_cartpole.envs.pixels`: the transforms of an env seen through its frames;
- :mod:`~trl_cartpole.envs.cartpole_drawing`: CartPole's picture drawn from its state in torch;
- :mod:`~trl_cartpole.envs.episode_log`: a Gymnasium wrapper that records each episode's
  return and length;
- :mod:`~trl_cartpole.envs.faults`: an env's exception turned into one line that names it.
"""
