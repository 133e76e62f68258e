"""The configuration: the typed schema, its validation, the presets and their composition, the
fields' help (no torch).
"""
