"""What a run keeps on disk: the checkpoint format and its integrity, the envs' state as data, the
pickle guard, the run directory's lock, atomic file writes.
"""
