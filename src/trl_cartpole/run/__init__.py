"""A training run: the builder (the one reader of the config), the loop, the learner, evaluation,
progress, history, the checkpointer, the summary, preflight checks and stop signals.
"""
