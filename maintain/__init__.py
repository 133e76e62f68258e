"""The maintainer's tools of trl_cartpole, run from the repository root: ``python -m maintain``.

The docs' generated blocks, the README's recorded run and the install lock; not installed
with the package, not benchmarks (those are ``python -m benchmarks``).
"""
