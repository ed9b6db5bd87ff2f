"""The example scenes (TOML configs and their painted maps), installed as ``forest.examples``.

Copy one out with ``forest examples copy NAME DIR``.
"""
